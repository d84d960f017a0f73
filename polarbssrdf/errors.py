"""Exceptions shared across the package."""


class CommandError(RuntimeError):
    """An error the user can fix; the command line prints it without a traceback."""
