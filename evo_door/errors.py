"""Errors a user can cause and fix: the CLI prints them on one line and exits 2.

The one-line form (:func:`error_line`) lives here, at the bottom of the layers, so that
any layer that reports a user error in its own output (a batch's summary table) writes
it exactly as the command line does, without importing the command line.
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input from the user (file, option, parameter value...).

    The message must say what is wrong and where (file, line, key, parameter),
    in one line, without a traceback.
    """


class ParameterError(UserError, ValueError):
    """A parameter name or value that does not fit its declaration."""


#: the longest error line printed (a message quoting a file must not flood the terminal)
MAX_ERROR = 400

#: what every error line starts with
PREFIX = "evo-door: error: "


def error_line(message) -> str:
    """``evo-door: error: MESSAGE`` on one line, at most :data:`MAX_ERROR` characters.

    >>> error_line("a.yaml:3: unknown key 'modle'\\n  (did you mean 'model'?)")
    "evo-door: error: a.yaml:3: unknown key 'modle' (did you mean 'model'?)"
    >>> len(error_line("x" * 1000)) <= len(PREFIX) + MAX_ERROR
    True
    """
    text = " ".join(str(message).split())
    if len(text) > MAX_ERROR:
        text = text[: MAX_ERROR - 5] + " ..."
    return f"{PREFIX}{text}"


class NotResultsFileError(UserError):
    """An HDF5 file that is not an evo-door results file (trials, a render log...).

    A folder listing (``evo-door runs``) skips such files by this type, where a damaged
    results file gets a row that says so.
    """


class WriteError(UserError):
    """The file system refused to write ``path`` (full, read-only, no permission...).

    ``reason`` is what it said, in a few words ("no space left on device"); ``left``
    what is on the disk after it, from the writer's point of view: by default "nothing
    was written" (the target, if any, is as it was), or what a caller that knows more
    says through :meth:`leaving` (a run: its last checkpoint, kept to resume from).
    """

    def __init__(self, path, reason: str, left: str = "nothing was written"):
        self.path = path
        self.reason = reason
        self.left = left
        super().__init__(f"{path}: cannot write ({reason}); {left}")

    def leaving(self, left: str) -> WriteError:
        """The same failure, with what is left said otherwise."""
        return WriteError(self.path, self.reason, left)


class MissingChannelError(UserError):
    """A trial lacks the channel that the objective's derivative compares.

    ``where`` is the objective's place (``FILE:LINE``) and ``reason`` which trial lacks
    which channel, and where it comes from; the message is ``WHERE:
    objective.derivative: REASON``. Comparing objectives reads the fields to say which
    derivatives the trials serve without the file's line.
    """

    def __init__(self, where: str, reason: str):
        self.where = where
        self.reason = reason
        super().__init__(f"{where}: objective.derivative: {reason}")


def plain_text(text: str, what: str, error=None) -> str:
    """``text`` if it is Unicode a file can hold (UTF-8 encodable: no lone surrogate;
    no NUL character); else ``error`` (a UserError by default) naming ``what``.

    >>> plain_text("Ana", "--participant")
    'Ana'
    >>> plain_text("\\ud800", "--participant")
    Traceback (most recent call last):
    ...
    evo_door.errors.UserError: --participant: not Unicode text (a lone surrogate, U+D800); refused
    """
    error = error or UserError
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        code = ord(text[exc.start])
        raise error(f"{what}: not Unicode text (a lone surrogate, U+{code:04X}); refused") from None
    if "\x00" in text:
        raise error(f"{what}: holds a NUL character; refused")
    return text
