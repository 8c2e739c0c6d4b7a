"""`vislam nees` (not yet implemented)."""

from ekf.errors import InputError


def add_arguments(parser):
    pass


def run(args):
    raise InputError("vislam nees is not implemented yet")
