"""`InputError`, the one error every reader of clss.io raises (a `clss.errors.UserError`,
so the CLI prints it as a one-line message)."""
from __future__ import annotations

from ..errors import UserError


class InputError(UserError):
    """An input file is missing, unreadable, lacks a channel or has the wrong size."""
