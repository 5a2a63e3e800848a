"""The base of every "you gave something wrong" error in clss.

The same mistake reaches a Python caller (who passed `sanitize=True`, `channels={...}`)
and a command-line user (who typed `--sanitize`, `--channels`). A UserError carries
its message for each: `str(e)` speaks in Python arguments, `e.cli` in flags; the
command line prints `cli_message(e)`.
"""
from __future__ import annotations


class UserError(ValueError):
    """A mistake in the caller's input. `cli`: the message phrased in command-line
    flags, where it differs from the Python one."""

    def __init__(self, message: str, cli: str | None = None):
        super().__init__(message)
        self.cli = cli


def cli_message(e: BaseException) -> str:
    """The text of an error as the command line shows it (one line)."""
    text = getattr(e, "cli", None) or str(e) or type(e).__name__
    if isinstance(e, OSError) and e.filename is not None and e.strerror:
        # OSError's str() is "[Errno 2] No such file or directory: 'x'"; say it plainly.
        text = f"{e.filename}: {e.strerror.lower()}"
    return text


class ArgumentError(TypeError):
    """A keyword argument the callee does not take (a misspelt option): a TypeError, as
    Python's own for an unexpected keyword, that names it and the closest valid name.
    The command line reports it in one line like a UserError."""

    def __init__(self, message: str, cli: str | None = None):
        super().__init__(message)
        self.cli = cli
