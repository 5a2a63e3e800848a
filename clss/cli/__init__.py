"""The `clss` command line: main.py holds the command table, one module per command group."""
from ..exiting import leave
from .main import COMMANDS, main, run_command


def entry() -> None:
    """The `clss` console script and `python -m clss`: main(), then leave()."""
    leave(main())


__all__ = ["COMMANDS", "main", "run_command", "leave", "entry"]
