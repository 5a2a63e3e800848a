"""The bench suite: every operator family's cases (bench/cases.py), then every method's
(its networks and frame step: the bench room bench/methods/<room>.py of each room in the
method registry), per level and shape tier."""
from __future__ import annotations

from . import methods
from .cases import FAMILY_CASES, LEVEL_TIERS, BenchCase

# --- the suite ------------------------------------------------------------------------

def all_cases(level: str = "default", tiers=None) -> tuple[list[BenchCase], list[tuple[str, str]]]:
    """(cases, unavailable): the suite for a level ("quick", "default", "full"), and
    (what, why) for the parts that cannot be built yet (a family not landed, an API
    that failed) or that the level leaves out (a room's FULL_ONLY). `tiers` replaces the
    level's shape tiers (e.g. ("tiny",))."""
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
        for name, room in methods.bench_rooms():
            what = f"{name} (bench/methods/{name}.py)"
            why = getattr(room, "FULL_ONLY", "")
            # (the tiny tier is a smoke test of every case: there they cost nothing)
            if why and level != "full" and tier != "tiny":
                missing.append((f"{what} [{tier}]", f"only with --full: {why}"))
                continue
            try:
                got = room.cases(tier)
            except Exception as e:      # a method whose API moved: report, bench the rest
                missing.append((f"{what} [{tier}]", f"{type(e).__name__}: {e}"))
                continue
            if not got and tier == tiers[0]:
                missing.append((what, f"no case at the {tier} tier"))
            cases += got
    if level == "quick":
        cases = [c for c in cases if c.quick]
    return cases, missing
