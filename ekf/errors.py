"""Errors that the command line turns into one line and exit code 2."""


class InputError(ValueError):
    """Bad input: the message names the file, key, shape or value at fault."""


class EstimationError(RuntimeError):
    """An estimator could not produce a result; the message names the variable involved."""
