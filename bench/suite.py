"""The bench suite: every family's cases (bench/cases.py) plus the two networks and the
whole frame step (bench/netcases.py), per level and shape tier."""
from __future__ import annotations

import os

from clss.methods.clss.networks import CLASSIFIER_CHANNELS, COMPOSITION_CHANNELS, pad16
from clss.pipeline.contract import output_size

from . import netcases
from .cases import FAMILY_CASES, LEVEL_TIERS, TIERS, BenchCase, _has


# --- networks and the frame step (optional) -------------------------------------------

def network_cases(tier):
    """The two CLSS networks through clss.Model, once clss/model/__init__.py exists."""
    if not _has("clss.model"):
        return []
    from clss.methods.clss.networks import build_classifier, build_composition, count_flops
    (h, w), scale = TIERS[tier]
    H, W = output_size(h, w, scale)
    Hp, Wp = pad16(H), pad16(W)
    cls = build_classifier(height=Hp, width=Wp)
    comp = build_composition(height=H, width=W)
    return [netcases.model_case("network classifier", cls, {"x": (1, CLASSIFIER_CHANNELS, Hp, Wp)}, tier,
                                count_flops(cls, Hp, Wp), quick=False),
            netcases.model_case("network composition", comp, {"x": (1, COMPOSITION_CHANNELS, H, W)}, tier,
                                count_flops(comp, H, W), quick=False)]


def frame_cases(tier):
    """The whole frame step (net and rule modes) against the oracle graph, once the
    OpenCL pipeline exists."""
    if not _has("clss.methods.clss.frame"):
        return []
    (h, w), scale = TIERS[tier]
    return [netcases.frame_case(mode, (h, w), scale, tier) for mode in ("net", "rule")]


def _method_cases(module, fn):
    """The frame-step cases of a method with its own case module (bench/<method>cases.py),
    for one tier: imported when asked for, as the method itself is."""
    def cases(tier):
        import importlib
        return getattr(importlib.import_module(f"bench.{module}"), fn)((tier,))
    return cases


# --- the suite ------------------------------------------------------------------------

def all_cases(level: str = "default", tiers=None) -> tuple[list[BenchCase], list[tuple[str, str]]]:
    """(cases, unavailable): the suite for a level ("quick", "default", "full"), and
    (what, why) for the parts that cannot be built yet (a family not landed, an API
    that failed). `tiers` replaces the level's shape tiers (e.g. ("tiny",))."""
    if level not in LEVEL_TIERS:
        raise ValueError(f"level must be one of {', '.join(LEVEL_TIERS)}")
    tiers = tuple(tiers or LEVEL_TIERS[level])
    from clss.ops import load_all
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mods = load_all()
    cases, missing = [], []
    for tier in tiers:
        for fam, fn in FAMILY_CASES.items():
            if fam not in mods:
                if tier == tiers[0]:
                    missing.append((fam, f"clss/ops/{fam}.py not present yet"))
                continue
            try:
                cases += fn(tier)
            except Exception as e:   # a family whose API moved: report, keep benchmarking the rest
                missing.append((f"{fam} [{tier}]", f"{type(e).__name__}: {e}"))
        for what, fn, mod in (("networks", network_cases, "clss/model/__init__.py"),
                              ("frame step", frame_cases, "clss/methods/clss/frame.py"),
                              ("mlp frame step", _method_cases("mlpcases", "mlp_cases"),
                               "clss/methods/mlp/upscaler.py"),
                              ("nsrr frame step", _method_cases("nsrrcases", "nsrr_cases"),
                               "clss/methods/nsrr/upscaler.py"),
                              ("nsrd frame step", _method_cases("nsrdcases", "nsrd_cases"),
                               "clss/methods/nsrd/upscaler.py")):
            try:
                got = fn(tier)
            except Exception as e:
                missing.append((f"{what} [{tier}]", f"{type(e).__name__}: {e}"))
                continue
            if not got and tier == tiers[0]:
                here = os.path.exists(os.path.join(os.path.dirname(__file__), "..", mod))
                missing.append((what, f"no case at the {tier} tier (see --full)" if here
                                else f"{mod} not present yet"))
            cases += got
    if level == "quick":
        cases = [c for c in cases if c.quick]
    return cases, missing
