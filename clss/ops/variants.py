"""Kernel variants as table rows, and the one chooser that picks a row per (device, layer).

A family with several kernels for one op (conv2d: thin, Winograd, channel-blocked, NCHW
direct, implicit GEMM with and without local memory, tensor cores) lists them as
`Variant` rows in the order it prefers them; the op wrapper asks `choose` for a row and
launches it, and knows no variant by name. A row says which layers it takes
(`eligible`), which fast path must pass its self-check on the device first
(`fast_paths`, clss/selfcheck.py) and what `clss tune` may search in it (`tunables`).

The row chosen for a layer, first that is eligible and whose fast paths pass:
  1. the caller's `tuning={"VARIANT": name}` (tests, the tuner trying a candidate);
  2. the tuning database's entry for (device, driver, op, layer key), written by
     `clss tune` after it checked and timed every eligible row on this device;
  3. the shipped table of the device's class (clss/tuning_tables/<class>.json, see
     clss.tuning.shipped): an entry for this layer key, then the class's preference order;
  4. the family's own order.
Rows marked `probe` (the GPU rows on GPUs) are first timed on the layer itself where none of
1-3 names a row for it (clss/ops/conv_probe.py), and the result is stored as in 2.
So a device nobody tuned runs what was measured on its kind, and a row that fails its
self-check on a device is never launched there, whatever any table says.
Like MNN's ConvBufExecution and ComputeLibrary's get_convolution_method, but measured per
device rather than fixed per GPU generation.
"""
from __future__ import annotations

import hashlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

from .. import selfcheck, tuning
from ..device import Device


@dataclass(frozen=True)
class Variant:
    """One kernel variant of an op. eligible(dev, prec, layer) -> bool: the layers (and
    precisions, devices) it computes; run(dev, prec, layer, args) launches it;
    fast_paths: the self-checked fast paths (clss.selfcheck names) it needs enabled;
    tunables: {param: candidates} that `clss tune --level full` searches within it."""
    name: str
    what: str
    eligible: Callable = field(compare=False)
    run: Callable = field(compare=False)
    fast_paths: tuple = ()
    tunables: dict = field(default_factory=dict, compare=False)
    # probe(dev): timed against the default row at a layer's first use on dev, where no table
    # names a row for the layer (clss/ops/conv_probe.py); the GPU rows, never a CPU's
    probe: Callable = field(default=lambda dev: False, compare=False)

    def enabled(self, dev, prec: str) -> bool:
        return all(selfcheck.enabled(dev, prec, fp) for fp in self.fast_paths)


_recorded: list | None = None     # (op, layer) of each choice, while recording()
_probed: dict = {}                # (device, op, layer key) -> the row its probe chose, this process


@contextmanager
def recording():
    """Collects (op, layer) for every choice made inside the block (clss tune: which
    layers a network runs)."""
    global _recorded
    old, _recorded = _recorded, []
    try:
        yield _recorded
    finally:
        _recorded = old


_SOURCE_HASH: dict = {}


def source_hash(*stems: str) -> str:
    """8 hex digits over the kernel sources of a family, their headers inlined: part of every
    tuned layer key, so a choice measured on older kernels is never applied to new ones."""
    key = tuple(stems)
    if key not in _SOURCE_HASH:
        h = hashlib.sha256()
        for s in stems:
            h.update(Device.source(s).encode())
        _SOURCE_HASH[key] = h.hexdigest()[:8]
    return _SOURCE_HASH[key]


def candidates(dev, prec: str, rows, layer, exclude=()) -> list:
    """The rows that compute this layer on this device and precision (self-checks not run)."""
    return [r for r in rows if r.name not in exclude and r.eligible(dev, prec, layer)]


def order(dev, op: str, key: str, rows, explicit: dict | None = None) -> list[str]:
    """Variant names in the order the chooser tries them (see the module's docstring)."""
    names = []
    forced = (explicit or {}).get("VARIANT") or tuning.overridden(op).get("VARIANT")
    if forced:
        names.append(forced)
    tuned = tuning.entry(dev, op, key)
    if tuned and tuned.get("params", {}).get("VARIANT"):
        names.append(tuned["params"]["VARIANT"])
    names += tuning.shipped_order(dev, op, key)
    names += [r.name for r in rows]
    return list(dict.fromkeys(names))


def _named(dev, op: str, key: str, explicit) -> bool:
    """Does the caller, the tuner, the database or the shipped table name a row for this layer?"""
    return bool((explicit or {}).get("VARIANT") or tuning.overridden(op).get("VARIANT")
                or tuning.entry(dev, op, key) or tuning.shipped_layer(dev, op, key))


def choose(dev, prec: str, op: str, key: str, rows, layer, explicit: dict | None = None,
           exclude=(), probe=None) -> Variant:
    """The row to launch for `layer` (module docstring); ValueError when no row takes it.
    probe(dev, prec, key, layer, rows, default): measures the rows whose `probe(dev)` holds
    against the default row and stores the winner, where nothing names a row for the layer."""
    if _recorded is not None:
        _recorded.append((op, layer))
    by_name = {r.name: r for r in candidates(dev, prec, rows, layer, exclude)}
    memo = (tuning.device_key(dev), op, key)
    if probe is not None and memo not in _probed and not _named(dev, op, key, explicit):
        probed = [r for r in by_name.values() if r.probe(dev) and r.enabled(dev, prec)]
        default = next((by_name[n] for n in order(dev, op, key, rows, explicit)
                        if n in by_name and by_name[n] not in probed and by_name[n].enabled(dev, prec)), None)
        if probed and default is not None:
            # once per process and layer, whatever happens: a cache that cannot be written (or
            # a probe that fails) must not make every later call probe again
            _probed[memo] = default.name
            try:
                _probed[memo] = probe(dev, prec, key, layer, probed, default.name) or default.name
            except Exception as e:      # the probe is an optimisation: the default row runs
                import warnings
                warnings.warn(f"{op}: probing the variants of {layer} failed ({type(e).__name__}: {e}); "
                              f"using {default.name}")
    names = order(dev, op, key, rows, explicit)
    if memo in _probed and not (explicit or {}).get("VARIANT") and not tuning.overridden(op).get("VARIANT"):
        names.insert(0, _probed[memo])
    for name in names:
        r = by_name.get(name)
        if r is not None and r.enabled(dev, prec):
            return r
    raise ValueError(f"{op}: no kernel variant computes {layer} on {dev.info.name} in {prec} "
                     f"(eligible: {', '.join(by_name) or 'none'}; their self-checks decide the rest)")


def params(dev, op: str, key: str, variant: str, defaults: dict, explicit: dict | None = None) -> dict:
    """A chosen variant's tunables: its defaults < the shipped table's < the database's
    entry (when it is for this variant) < the tuner's candidate < the caller's."""
    out = dict(defaults)
    out.update({k: v for k, v in tuning.shipped_params(dev, op, key, variant).items() if k in defaults})
    e = tuning.entry(dev, op, key)
    if e and e.get("params", {}).get("VARIANT") == variant:
        out.update({k: v for k, v in e["params"].items() if k in defaults})
    ov = tuning.overridden(op)
    if ov.get("VARIANT", variant) == variant:
        out.update({k: v for k, v in ov.items() if k in defaults})
    out.update({k: v for k, v in (explicit or {}).items() if k in defaults})
    return out
