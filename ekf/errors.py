"""Errors that the command line turns into one line and exit code 2."""


class InputError(ValueError):
    """Bad input: the message names the file, key, shape or value at fault."""


class EstimationError(RuntimeError):
    """An estimator could not produce a result; the message names the variable involved."""


def time_text(seconds: float) -> str:
    """A time stamp for an error message: ``1317386534.28``, or ``1e+160`` for a stamp too large
    to print in full (absurd input still gets a one-line message of readable length)."""
    return f"{seconds:.2f}" if abs(seconds) < 1e15 else f"{seconds:.6g}"
