"""The jitter of training sequences (issue 53): each sequence draws one of the patterns
engines send (clss.io.jitter.PATTERNS: zero, 2x2, Halton 8 / 16 / 32 phases, R2), a start
phase and a mirror, so that a method learns every pattern rather than one. The generator
(`gen --jitter-mix`) and the Blender shards (`blender --jitter-mix`) draw from a mix
`NAME[:WEIGHT],...` and record the draw in each sequence's metadata (`meta["jitter"]`).

A single name is every sequence with that pattern, unmirrored, from phase 0 (held-out
sets of one pattern: `gen --jitter-mix 2x2`). "legacy" is the generator's jitter before
issue 53, exactly (Halton 32 phases, or none in about a fifth of the sequences, drawn with
the content: the sets on disk before 2026-11-29); elsewhere it reads as LEGACY_MIX.
"""
from __future__ import annotations

import numpy as np

from clss.io.jitter import pattern_jitter, pattern_name

# zero jitter included (a capture whose jitter is unknown is fed zero); every length
DEFAULT_MIX = "zero:0.2,2x2:0.15,halton8:0.15,halton16:0.2,halton:0.15,r2:0.15"
LEGACY_MIX = "halton:0.8,zero:0.2"


def is_legacy(text) -> bool:
    return str(text).strip().lower() == "legacy"


def parse_mix(text) -> list[tuple[str, float]]:
    """[(pattern, weight)] summing to 1 from "NAME[:WEIGHT],..." (weights default 1);
    ValueError naming what is wrong."""
    text = LEGACY_MIX if is_legacy(text) else str(text)
    out = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, _, w = part.partition(":")
        try:
            weight = float(w) if w else 1.0
        except ValueError:
            raise ValueError(f"{part!r}: the weight must be a number") from None
        if not weight > 0:
            raise ValueError(f"{part!r}: the weight must be positive")
        out.append((pattern_name(name.strip()), weight))
    if not out:
        raise ValueError(f"{text!r}: no pattern (e.g. {DEFAULT_MIX})")
    total = sum(w for _, w in out)
    return [(n, w / total) for n, w in out]


def draw(mix, rng) -> dict:
    """One sequence's jitter: {"pattern", "flip": [sx, sy], "phase"}. A mix of one
    pattern is that pattern as it stands (no mirror, phase 0)."""
    mix = parse_mix(mix) if isinstance(mix, str) else mix
    if len(mix) == 1:
        return {"pattern": mix[0][0], "flip": [1, 1], "phase": 0}
    k = int(rng.choice(len(mix), p=[w for _, w in mix]))
    flip = [int(v) for v in rng.choice([-1, 1], 2)]
    return {"pattern": mix[k][0], "flip": flip, "phase": int(rng.integers(0, 64))}


def sequence_jitter(drawn, frames, scale) -> np.ndarray:
    """[frames, 2] float64, the contract's render pixels, of a `draw`."""
    return pattern_jitter(drawn["pattern"], frames, scale, flip=drawn["flip"],
                          phase=drawn["phase"])


def check_arg(flag, text):
    """The mix of `flag`, or the one-line error (ValueError) naming the flag."""
    try:
        parse_mix(text)
    except ValueError as e:
        raise ValueError(f"{flag}: {e}") from None
    return text
