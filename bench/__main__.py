"""`python -m bench [args]` is `clss bench [args]`; `python -m bench tune [args]` is `clss tune`."""
import sys

from clss.cli import run_command
from clss.exiting import leave

from .cli import bench_main, tune_main

argv = sys.argv[1:]
if argv[:1] == ["tune"]:
    leave(run_command("clss tune", tune_main, argv[1:]))
leave(run_command("clss bench", bench_main, argv))
