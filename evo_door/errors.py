"""Errors a user can cause and fix: the CLI prints them on one line and exits 2."""


class UserError(Exception):
    """Bad input from the user (file, option, parameter value...).

    The message must say what is wrong and where (file, line, key, parameter),
    in one line, without a traceback.
    """


class ParameterError(UserError, ValueError):
    """A parameter name or value that does not fit its declaration."""


class NotResultsFileError(UserError):
    """An HDF5 file that is not an evo-door results file (trials, a render log...).

    A folder listing (``evo-door runs``) skips such files by this type, where a damaged
    results file gets a row that says so.
    """
