"""Static device-memory planning: which intermediate buffers share storage.

The load-time dry run (model.execute.trace) records every allocation each node
makes, in call order, and which of them back the node's outputs. An
allocation lives from its node to the last node reading any tensor stored in
it (views included); scratch lives for its node only. Allocations whose
lifetimes do not overlap share one buffer ("slot"); a slot is as large as its
largest tenant. Graph outputs are not pooled: each run gets fresh arrays (or
the caller's), so results stay valid after the next run. An input of a channel
concat may live inside the concat's own allocation, at its offset (Alloc.parent):
its producer writes it in place and the concat copies nothing for it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Alloc:
    node: int
    call: int
    shape: tuple
    dtype: np.dtype
    nbytes: int
    start: int
    end: int                 # last node index that reads it (inclusive)
    fresh: bool = False      # backs a graph output: allocated per run, not pooled
    slot: int | None = None
    # A concat input written in place: (the concat output's allocation key, byte offset);
    # it has no slot of its own but a sub-buffer of its parent's (execute.concat_in_place)
    parent: tuple | None = None
    offset: int = 0


@dataclass
class Plan:
    allocs: dict[tuple[int, int], Alloc] = field(default_factory=dict)
    slots: list[int] = field(default_factory=list)   # bytes per shared buffer
    unplanned_bytes: int = 0   # arrays handlers made without dev.empty (not pooled)

    @property
    def peak_bytes(self) -> int:
        """Device memory for intermediates: the sum of the shared buffers."""
        return int(sum(self.slots))

    @property
    def unshared_bytes(self) -> int:
        """What the pooled intermediates would take with one buffer each."""
        return int(sum(a.nbytes for a in self.allocs.values() if not a.fresh))

    @property
    def output_bytes(self) -> int:
        return int(sum(a.nbytes for a in self.allocs.values() if a.fresh))

    def summary(self) -> dict:
        return {"peak_bytes": self.peak_bytes, "buffers": len(self.slots),
                "unshared_bytes": self.unshared_bytes, "output_bytes": self.output_bytes,
                "unplanned_bytes": self.unplanned_bytes, "allocations": len(self.allocs)}


def assign_slots(allocs: list[Alloc]) -> list[int]:
    """Greedy in start order: reuse the smallest free slot that fits, else grow
    the largest free one, else open a new slot. Returns slot sizes."""
    slots: list[int] = []
    busy_until: list[int] = []     # per slot, the last step its current tenant is live
    for a in sorted((a for a in allocs if not a.fresh and a.parent is None),
                    key=lambda a: (a.start, a.node, a.call)):
        free = [s for s in range(len(slots)) if busy_until[s] < a.start]
        fits = [s for s in free if slots[s] >= a.nbytes]
        if fits:
            s = min(fits, key=lambda s: slots[s])
        elif free:
            s = max(free, key=lambda s: slots[s])
            slots[s] = a.nbytes
        else:
            s = len(slots)
            slots.append(a.nbytes)
            busy_until.append(-1)
        busy_until[s] = a.end
        a.slot = s
    return slots


def check_plan(allocs: list[Alloc]) -> None:
    """No two tenants of a slot overlap in time (a guard on assign_slots)."""
    by_slot: dict[int, list[Alloc]] = {}
    for a in allocs:
        if a.slot is not None:
            by_slot.setdefault(a.slot, []).append(a)
    for s, xs in by_slot.items():
        xs.sort(key=lambda a: a.start)
        for p, q in zip(xs, xs[1:]):
            if q.start <= p.end:
                raise AssertionError(f"slot {s}: allocations at nodes {p.node} and {q.node} overlap")
