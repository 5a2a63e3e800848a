"""`python -m weights_tools train METHOD` and `seeds METHOD`: one command for every method's
training. The recipes are found, not listed: each room weights_tools/methods/<name>/ with
a recipe.py (weights_tools.methods) is a METHOD here; what recipes share (resume,
optimiser, checkpoints, logging, seeding, data loading, losses) is
weights_tools/trainloop.py. `train --data ...` without a method is CLSS's recipe, as
before."""
from __future__ import annotations

import argparse
import sys

from . import methods as rooms

DEFAULT = "clss"


def _no_recipe(name, why):
    def fn(args):
        print(f"error: train {name}: {why}", file=sys.stderr)
        return 2
    return fn


def add_train_parser(sub):
    """`train METHOD [options]`: one sub-command per method of clss.methods (and per room
    with a recipe that clss.methods does not list, should there be one)."""
    from clss import methods
    t = sub.add_parser("train", help="train a method's networks (needs the [train] extra)",
                       description="Train a method's networks: `train METHOD --data DIR --out DIR "
                                   "[recipe options]` (`train METHOD --help` lists a recipe's "
                                   "options). Without METHOD, CLSS's recipe.")
    per = t.add_subparsers(dest="method", metavar="METHOD", required=True)
    trained = rooms.names()
    listed = methods.names() + list(methods.PLANNED)
    for name in listed + [n for n in trained if n not in listed]:
        if name in trained:
            recipe = rooms.recipe(name)
            p = per.add_parser(name, help=f"the {name} recipe ({rooms.recipe_module(name)})",
                               formatter_class=argparse.RawDescriptionHelpFormatter,
                               description=recipe.doc.split("\n\n")[0])
            recipe.add_arguments(p)
            p.set_defaults(fn=recipe.train)
        else:
            why = (f"not built yet ({methods.PLANNED[name]})" if name in methods.PLANNED
                   else "a method without trained weights: nothing to train")
            p = per.add_parser(name, help=why)
            p.set_defaults(fn=_no_recipe(name, why))
    return t


def with_default_method(argv, command="train"):
    """`train --data X` (no method) -> `train clss --data X`: the older spelling."""
    argv = list(argv)
    if len(argv) >= 2 and argv[0] == command and argv[1].startswith("-") \
            and argv[1] not in ("-h", "--help"):
        argv.insert(1, DEFAULT)
    if command == "train" == argv[0] and len(argv) > 2 and argv[1] not in rooms.names() \
            and not argv[1].startswith("-"):
        argv = argv[:2]     # a method without a recipe: its one-line answer, whatever follows
    return argv
