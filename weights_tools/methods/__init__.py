"""The training side of each method, one folder per method: weights_tools/methods/<name>/,
named as its room in clss/methods/. Every room holds the same two modules:

    twin.py     the method's torch twin: its frame step in PyTorch, held to the OpenCL step
                by a parity test, so that training optimises what the engine runs
    recipe.py   its training recipe, exporting RECIPE (a Recipe below): the options of
                `python -m weights_tools train <name>`, and the run, which gives its model,
                data and loss to weights_tools/trainloop.py (resume, optimiser, checkpoint,
                logging and seeding)

and whatever tools only that method has (CLSS's classifier report, the MLP's online
learning curve). A room's __init__.py may name sub-commands of `python -m weights_tools`
that one of its modules adds: COMMANDS = {"name": "module"} (the module has
add_parser(sub)).

Nothing here is a hand-kept list: the rooms are found by walking this package, so a
method's training is added by adding its folder. Finding them imports no torch (only the
rooms' light __init__.py files); a recipe is imported when it is asked for."""
from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Recipe:
    """What a room's recipe.py exports as RECIPE: `add_arguments(parser)` adds its options
    to `train <name>`; `train(args)` runs it and returns the exit status; `doc` (the
    module's docstring) describes it, its first paragraph being the sub-command's help."""
    add_arguments: Callable[[argparse.ArgumentParser], None]
    train: Callable[[argparse.Namespace], int]
    doc: str = ""


def _rooms():
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if m.ispkg)


def _has(room, module):
    return any(m.name == module for m in pkgutil.iter_modules([os.path.join(__path__[0], room)]))


def names() -> list[str]:
    """The methods with a training recipe (a room with recipe.py), sorted."""
    return [r for r in _rooms() if _has(r, "recipe")]


def recipe(name) -> Recipe:
    """The RECIPE of weights_tools/methods/<name>/recipe.py (imports it, and torch)."""
    if name not in names():
        raise KeyError(f"no training recipe for {name!r} (rooms with one: {', '.join(names())})")
    r = importlib.import_module(f"{__name__}.{name}.recipe").RECIPE
    if not isinstance(r, Recipe):
        raise TypeError(f"{__name__}.{name}.recipe.RECIPE is not a weights_tools.methods.Recipe")
    return r


def recipe_module(name) -> str:
    """The path of a room's recipe, for messages: weights_tools/methods/<name>/recipe.py."""
    return f"{__name__.replace('.', '/')}/{name}/recipe.py"


def commands() -> dict[str, str]:
    """Sub-command -> module (weights_tools.methods.<room>.<module>) of every room's
    COMMANDS; a name claimed twice is an error."""
    out: dict[str, str] = {}
    for room in _rooms():
        for cmd, module in getattr(importlib.import_module(f"{__name__}.{room}"),
                                   "COMMANDS", {}).items():
            if cmd in out:
                raise ValueError(f"sub-command {cmd!r} is named by two rooms ({out[cmd]}, {room})")
            out[cmd] = f"{__name__}.{room}.{module}"
    return out
