"""Errors of the acquisition side that the command line reports without a traceback."""


class UserError(Exception):
    """A problem the user can fix (bad option, missing or wrong directory); printed plainly."""
