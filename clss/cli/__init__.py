"""The `clss` command line: main.py holds the command table, one module per command group."""
from .main import COMMANDS, main, run_command

__all__ = ["COMMANDS", "main", "run_command"]
