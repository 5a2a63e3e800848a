"""The `clss` command line (main.py) and its subcommands."""
from .main import COMMANDS, DEVICE_HELP, main, register, run_command

__all__ = ["COMMANDS", "DEVICE_HELP", "main", "register", "run_command"]
