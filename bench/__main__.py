"""`python -m bench [args]` is `clss bench [args]`; `python -m bench tune [args]` is `clss tune`."""
import sys

from .cli import bench_main, tune_main

argv = sys.argv[1:]
if argv[:1] == ["tune"]:
    sys.exit(tune_main(argv[1:]))
sys.exit(bench_main(argv))
