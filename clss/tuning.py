"""The tuning database: the best kernel tunables found by `clss tune`, per device.

A JSON file ($CLSS_TUNING_DB, else tuning.json in clss's cache directory,
`clss.cachedir`: $CLSS_CACHE_DIR, else $XDG_CACHE_HOME/clss, default ~/.cache/clss, on Linux):

    {"version": 1,
     "devices": {"<device name> | <driver version>": {
         "<op>": {"<shape key>": {"params": {...}, "ms": 1.2, "default_ms": 1.5,
                                  "tuned": "2025-01-01T00:00:00"}}}}}

Ops ask with ``lookup(dev, op, key, defaults)`` and get the defaults with the
stored values laid over them (only for names the defaults have, so a stale entry
can never inject an option a kernel no longer knows). No file, no entry, or an
unreadable file: the defaults. A family makes its tunables searchable by
declaring ``TUNABLES = {op: {param: (candidate, ...)}}`` in its module; the
tuner tries them through ``override``.

Work-group sizes are kept as op ``local_size:<kernel name>``, keyed by the global
size; ``local_size(dev, kernel_name, global_size)`` reads them back.
"""
from __future__ import annotations

import datetime
import json
import os
import threading
from contextlib import contextmanager
from pathlib import Path

from .cachedir import cache_dir, update_json

VERSION = 1
_lock = threading.Lock()
_cache: dict = {"path": None, "mtime": None, "data": None}
_overrides: dict = {}                 # op -> params, while the tuner tries a candidate
_seen: list | None = None             # (op, key, defaults) looked up, while recording


def db_path() -> Path:
    p = os.environ.get("CLSS_TUNING_DB")
    return Path(p).expanduser() if p else cache_dir() / "tuning.json"


def device_key(dev) -> str:
    """'<device name> | <driver version>' for a Device, DeviceInfo or string."""
    if isinstance(dev, str):
        return dev
    info = getattr(dev, "info", dev)
    return f"{info.name} | {info.driver}"


def shape_key(*parts) -> str:
    """A readable key from shapes and scalars: shape_key((1, 16, 8, 8), 3) -> '1x16x8x8/3'."""
    out = []
    for p in parts:
        if isinstance(p, (tuple, list)):
            out.append("x".join(str(int(v)) for v in p))
        else:
            out.append(str(p))
    return "/".join(out)


def load(path: Path | None = None) -> dict:
    """The whole database (cached; re-read when the file changes)."""
    path = Path(path) if path else db_path()
    try:
        mtime = path.stat().st_mtime_ns
    except OSError:
        return {"version": VERSION, "devices": {}}
    with _lock:
        if _cache["path"] == path and _cache["mtime"] == mtime:
            return _cache["data"]
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict) or not isinstance(data.get("devices"), dict):
                raise ValueError("no 'devices' table")
        except (OSError, ValueError) as e:
            import warnings
            warnings.warn(f"tuning database {path} unreadable ({e}); using defaults")
            data = {"version": VERSION, "devices": {}}
        _cache.update(path=path, mtime=mtime, data=data)
        return data


_ignore_entries = False      # ignoring_entries(): the defaults, as on an untuned device


def entry(dev, op: str, key: str) -> dict | None:
    if _ignore_entries:
        return None
    return load().get("devices", {}).get(device_key(dev), {}).get(op, {}).get(key)


def lookup(dev, op: str, key: str, defaults: dict, explicit: dict | None = None,
           allowed: dict | None = None) -> dict:
    """The parameters to use for (op, key) on dev, as CLBlast does: the defaults,
    overlaid with the database entry's values for the same names, then with the
    caller's `explicit` ones; while the tuner runs a candidate, the defaults
    overlaid with the candidate. `allowed` ({name: candidates}, a family's
    TUNABLES) drops stored values outside the candidates, so a hand-edited or
    stale entry cannot ask a kernel for a block size it does not build with."""
    if _seen is not None:
        _seen.append((op, key, dict(defaults)))
    out = dict(defaults)
    if op in _overrides:
        out.update({k: v for k, v in _overrides[op].items() if k in defaults})
        return out
    e = entry(dev, op, key)
    if e:
        out.update({k: v for k, v in e.get("params", {}).items()
                    if k in defaults and (allowed is None or k not in allowed or v in allowed[k])})
    out.update(explicit or {})
    return out


@contextmanager
def ignoring_entries():
    """Inside the block the database is not read (clss tune: what an untuned device runs)."""
    global _ignore_entries
    old, _ignore_entries = _ignore_entries, True
    try:
        yield
    finally:
        _ignore_entries = old


def overridden(op: str) -> dict:
    """The candidate the tuner is trying for op (inside override()), else {}."""
    return dict(_overrides.get(op, {}))


# --- shipped tables: what was measured on a kind of device, for a device nobody tuned -----

SHIPPED_DIR = Path(__file__).parent / "tuning_tables"
_shipped: dict = {}


def device_class(dev) -> str:
    """The shipped table a device reads (clss/tuning_tables/<class>.json): nvidia, amd,
    intel-gpu, cpu-avx512 (16 float lanes), cpu-avx2 (8), else default. A CPU's class comes
    from the lanes its compiler emits (Device.simd_lanes), else from the vector width its
    driver prefers: the register tile's unit."""
    info = getattr(dev, "info", dev)
    text = f"{getattr(info, 'platform', '')} {getattr(info, 'vendor', '')} {getattr(info, 'name', '')}".lower()
    cl_device = getattr(dev, "cl_device", None)
    if getattr(dev, "is_cpu", False):
        # the lanes its compiler emits (Device.simd_lanes), else what the driver prefers
        width = getattr(dev, "simd_lanes", None)
        if width:
            return "cpu-avx512" if width >= 16 else "cpu-avx2" if width >= 8 else "default"
        try:
            width = int(cl_device.preferred_vector_width_float)
        except Exception:
            width = 0
        # PoCL reports its lanes in the device name too (pthread-skylake-avx512-...)
        if width >= 16 or "avx512" in text:
            return "cpu-avx512"
        return "cpu-avx2" if width >= 8 or "avx2" in text or "znver" in text or "haswell" in text else "default"
    if "nvidia" in text:
        return "nvidia"
    if "amd" in text or "advanced micro devices" in text:
        return "amd"
    if "intel" in text:
        return "intel-gpu"
    return "default"


def shipped(dev) -> dict:
    """The shipped table of dev's class ({} where none ships):
    {"class": ..., "measured": "where and when", "ops": {op: {"order": [variant, ...],
     "params": {variant: {param: value}}, "layers": {layer key: {"VARIANT": ..., params}}}}}"""
    cls = device_class(dev)
    if cls not in _shipped:
        path = SHIPPED_DIR / f"{cls}.json"
        try:
            _shipped[cls] = json.loads(path.read_text())
        except (OSError, ValueError):
            _shipped[cls] = {}
    return _shipped[cls]


def _shipped_op(dev, op: str) -> dict:
    return shipped(dev).get("ops", {}).get(op, {})


def shipped_layer(dev, op: str, key: str) -> dict:
    """The shipped table's entry for this layer key ({} where it has none)."""
    return dict(_shipped_op(dev, op).get("layers", {}).get(key, {}))


def shipped_order(dev, op: str, key: str) -> list:
    """The shipped table's variant for this layer key (if it lists one), then its order."""
    layer = shipped_layer(dev, op, key)
    return ([layer["VARIANT"]] if "VARIANT" in layer else []) + list(_shipped_op(dev, op).get("order", []))


def shipped_params(dev, op: str, key: str, variant: str) -> dict:
    """The shipped tunables of a variant: its class-wide ones, then this layer's (when the
    layer's entry is for this variant)."""
    t = _shipped_op(dev, op)
    out = dict(t.get("params", {}).get(variant, {}))
    layer = t.get("layers", {}).get(key, {})
    if layer.get("VARIANT") == variant:
        out.update({k: v for k, v in layer.items() if k != "VARIANT"})
    return out


# Choices measured per device as yes / no (clss tune --level's frame-step phase,
# bench/tune_fastpaths.py): whether a fused frame-step fast path is used (op "fast_path", key
# the path's name), and whether precision="auto" may pick fp16 for a method (op "fp16", key the
# method's name; it must also verify, clss/pipeline/precision.py).
FAST_PATH_OP = "fast_path"
FP16_OP = "fp16"
MEASURED_OPS = (FAST_PATH_OP, FP16_OP)


def measured_choice(dev, op: str, name: str) -> bool | None:
    """Yes / no for `name` under a MEASURED_OPS op on dev: the tuning database's entry (params
    {"use": bool}), else the device class's shipped table ({op: {name: bool}}), else None:
    not measured on this device or its class."""
    e = entry(dev, op, name)
    if e and isinstance(e.get("params", {}).get("use"), bool):
        return e["params"]["use"]
    use = shipped(dev).get(op, {}).get(name)
    return use if isinstance(use, bool) else None


def local_size(dev, kernel_name: str, global_size) -> tuple | None:
    """The tuned work-group size for a kernel at a global size; else, on a CPU device,
    balanced_local_size; else None (the driver's choice). Only sizes that divide the
    global size are returned."""
    gs = tuple(int(g) for g in global_size)
    p = lookup(dev, f"local_size:{kernel_name}", shape_key(gs), {"local": None})["local"]
    if p:
        loc = tuple(int(v) for v in p)
        if len(loc) == len(gs) and not any(g % l for g, l in zip(gs, loc)):
            return loc
    if not (BALANCE and getattr(dev, "is_cpu", False)):
        return None
    limits = getattr(dev, "_wg_limits", None)
    if limits is None:      # the device's work-group limits (oclgrind's are 1024 work-items)
        d = dev.cl_device
        limits = dev._wg_limits = (int(d.max_work_group_size), tuple(int(v) for v in d.max_work_item_sizes))
    return balanced_local_size(gs, dev.info.compute_units, *limits)


BALANCE = True


def _divisor_at_most(g: int, cap: int) -> int:
    """The largest divisor of g that is <= cap (>= 1)."""
    cap = max(1, min(g, cap))
    for d in range(cap, 0, -1):
        if g % d == 0:
            return d
    return 1


def balanced_local_size(gs: tuple, units: int, max_items: int = 4096, max_sizes: tuple = ()) -> tuple:
    """A work-group size for a CPU device that leaves every thread work: at least 8 groups
    per compute unit where the global size allows. A CPU driver runs a work-group on one
    thread, and left to itself PoCL makes the groups as large as it can (up to 4096
    work-items): NSRD's LSTM cell (8100 work-items) ran as 3 groups of 2700 on 2 threads,
    one thread doing two thirds of the work. Dimension 0 keeps the longest run it can (PoCL
    vectorises a work-group's loop along it); the outer dimensions are split first. Only
    divisors of the global size (OpenCL 1.2 has no partial groups), within the device's
    max_items work-items a group and max_sizes per dimension."""
    loc, room = [], max_items
    for d, g in enumerate(gs):
        loc.append(_divisor_at_most(g, min(room, max_sizes[d]) if d < len(max_sizes) else room))
        room = max(1, room // loc[-1])
    want = 8 * max(1, units)

    def groups():
        n = 1
        for g, l in zip(gs, loc):
            n *= g // l
        return n
    for d in range(len(gs) - 1, -1, -1):
        floor = 16 if d == 0 else 1       # dimension 0: a vector's worth of work-items where it can
        while groups() < want and loc[d] > 1:
            smaller = _divisor_at_most(gs[d], loc[d] - 1)
            if d == 0 and smaller < floor and loc[d] <= gs[d] // 2 and groups() * 2 >= units:
                break
            loc[d] = smaller
    return tuple(loc)


def store(dev, op: str, key: str, params: dict, path: Path | None = None, **meta) -> None:
    """Write one entry: read, merged and replaced whole behind the file's lock
    (clss.cachedir.update_json), so a crash leaves the old file intact and two tuners
    storing at once both keep their entries. An unreadable file is started afresh."""
    path = Path(path) if path else db_path()
    rec = {"params": dict(params), **meta,
           "tuned": datetime.datetime.now().isoformat(timespec="seconds")}

    def merge(data):
        if not isinstance(data, dict) or not isinstance(data.get("devices"), dict):
            data = {"devices": {}}
        data["version"] = VERSION
        data["devices"].setdefault(device_key(dev), {}).setdefault(op, {})[key] = rec
        return data
    update_json(path, merge, indent=1, sort_keys=True, default=_jsonable)
    with _lock:
        _cache.update(path=None, mtime=None, data=None)


def _jsonable(v):
    if hasattr(v, "item"):
        return v.item()
    if isinstance(v, tuple):
        return list(v)
    raise TypeError(f"not JSON serialisable: {v!r}")


@contextmanager
def override(op: str, params: dict):
    """lookup(…, op, …) returns `params` (over the defaults) inside the block."""
    old = _overrides.get(op)
    _overrides[op] = dict(params)
    try:
        yield
    finally:
        if old is None:
            _overrides.pop(op, None)
        else:
            _overrides[op] = old


@contextmanager
def recording():
    """Collects the (op, key, defaults) of every lookup inside the block."""
    global _seen
    old, _seen = _seen, []
    try:
        yield _seen
    finally:
        _seen = old
