"""Exceptions shared by the package and its command line."""


class UserError(Exception):
    """Bad input from the user: reported as one line, exit status 2, no output written."""
