"""The methods' bench rooms: bench/methods/<room>.py holds the bench cases of the method
room clss/methods/<room>/ (its networks and its frame step against onnxruntime on the same
graphs). Nothing here is a hand-kept list: the suite asks the method registry for the
rooms (clss.methods.ROOMS) and imports the bench room of the same name where one exists.

A bench room exports
    cases(tier) -> list[BenchCase]      its cases at one shape tier of bench/cases.py
                                        (an empty list at a tier it has no shape for)
and optionally
    FULL_ONLY                           why its cases run only with --full (their cost); at
                                        the tiny tier they run at every level
and, for the host-wait bench (bench/hostwait.py),
    HOST_WAITS                          the room's method names that get a row
    synthetic_gbuffers(h, w, scale)     the G-buffers its methods need, as numpy arrays
    enqueue_frame(up, color, depth, motion, jitter, out) -> (event, then)
                                        enqueue one frame without waiting (the enqueue
                                        column); `then()` after the event completes.
"""
from __future__ import annotations

import importlib
import importlib.util


def rooms() -> list[str]:
    """The method rooms in registry order."""
    from clss.methods import ROOMS
    return list(ROOMS)


def room(name: str):
    """The bench room module of method room `name`, or None where the method has none."""
    mod = f"{__name__}.{name}"
    if importlib.util.find_spec(mod) is None:
        return None
    return importlib.import_module(mod)


def bench_rooms() -> list[tuple[str, object]]:
    """(room name, module) of every method room that has a bench room, in registry order."""
    return [(r, m) for r in rooms() if (m := room(r)) is not None]


def host_wait_methods() -> dict[str, object]:
    """{method name: its bench room} for every method whose bench room asks for host-wait
    rows (HOST_WAITS), in registry order."""
    out = {}
    for _, m in bench_rooms():
        for name in getattr(m, "HOST_WAITS", ()):
            out[name] = m
    return out
