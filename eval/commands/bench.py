"""`vislam bench` (not yet implemented)."""

from ekf.errors import InputError


def add_arguments(parser):
    pass


def run(args):
    raise InputError("vislam bench is not implemented yet")
