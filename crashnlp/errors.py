"""Errors that are the user's input, not a bug: the CLI prints the message alone and exits 2."""


class InputError(ValueError):
    """Bad input (problem file, data file, study file): one line naming where and what."""
