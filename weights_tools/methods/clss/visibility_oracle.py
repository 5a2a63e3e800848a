"""python -m weights_tools.methods.clss.visibility_oracle SEQ.npz ...: what CLSS's history
decision could gain, with the answer known (issue 23).

Runs the torch twin of the frame step (rule or net mode) over labelled sequences with its
history decision (reject: drop the history and restart the counter, reference.md s7)
replaced by an oracle, and prints `eval`'s PSNR / tPSNR / disocclusion PSNR of each:

  as-is       the mode's own decision (rules: the depth test; net: the classifier at the
              margin, with the depth test as a floor)
  generator   reject exactly where the generator labels visibility ghosting (the exact
              previous geometry, 1 % depth tolerance: DATA.md `label_ghost` 0)
  useful R    reject where the warped history, clipped as the blend uses it, is further
              from the reference than the current upsample: its squared PQ error above
              R x the upsample's plus --floor (what `train --ghost-labels useful/cost`
              labels)

The oracles see the reference, so they are bounds, not methods: "generator" says what a
perfect classifier of the generator's labels would do to the picture, "useful" how much a
perfect decision of the pipeline's own choice is worth.

example:
  python -m weights_tools.methods.clss.visibility_oracle out/data/heldout/seq_000[0-7].npz \
      --mode net
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def generator_hook(state):
    """Reject where the current frame's generator label is visibility ghosting."""
    import torch

    def hook(reject, ctx):
        lab = torch.from_numpy(state["seq"]["label_ghost"][state["t"]] == 0)
        return lab.to(reject.device).view(1, 1, *lab.shape)
    return hook


def useful_hook(state, ratio, floor):
    """Reject where the clipped history's squared PQ error exceeds ratio x the upsample's
    plus floor (the clip on; without it the warped history itself)."""
    import torch

    from .twin import pq_encode
    from .recipe import history_worse

    def hook(reject, ctx):
        ref = state["seq"]["reference"][state["t"]]
        ref = pq_encode(torch.from_numpy(np.ascontiguousarray(ref.transpose(2, 0, 1)))[None]
                        .to(reject.device), state["nits"])
        hist = ctx["hist_clipped"] if ctx["hist_clipped"] is not None else ctx["hist"]
        return history_worse(hist, ctx["up"], ref, ratio, floor)[0].unsqueeze(1)
    return hook


def _tracking(state):
    """Wrap evaluate's Pipeline so that the hook knows which frame it is on."""
    def wrap(pipe):
        def run(seq, t):
            state["t"] = t
            return pipe(seq, t)
        return run
    return wrap


def score(seqs, mode, weights, oracle, warmup=2, ratio=2.0, floor=1e-3, device="cpu"):
    """Mean PSNR, tPSNR and disocclusion PSNR (dB) over `seqs` (evaluate.load_sequence's
    dicts, with `label_ghost` for the generator oracle) of `mode` ("rules"/"net") under
    `oracle` (None = as-is, "generator", "useful")."""
    from weights_tools.seeds import twin_record
    from .twin import PQ_NITS
    rows = []
    for seq in seqs:
        state = {"seq": seq, "t": 0, "nits": PQ_NITS}
        hook = {None: lambda: None, "generator": lambda: generator_hook(state),
                "useful": lambda: useful_hook(state, ratio, floor)}[oracle]()
        m = twin_record(seq, mode, weights, device, warmup, wrap=_tracking(state),
                        reject_hook=hook)
        rows.append((m["psnr"], m["tpsnr"], m["disocclusion_psnr"]))
    return [float(v) for v in np.nanmean(np.array(rows, np.float64), 0)]


def picture(seq, mode, weights, t, path, ratio=2.0, floor=1e-3, device="cpu"):
    """One frame `t` of `seq` run as-is: the reference (tone-mapped, dimmed) with, in
    colour, the pixels the mode drops the history on, the generator's visibility labels
    (where the sequence has them) and the useful decision, side by side -> `path`."""
    import torch

    from clss import io as cio
    from clss.metrics import save_side_by_side
    from .twin import PQ_NITS, TorchUpscaler
    state = {"seq": seq, "t": 0, "nits": PQ_NITS}
    useful = useful_hook(state, ratio, floor)
    seen = {}

    def hook(reject, ctx):
        if state["t"] == t:
            v = ctx["valid"][0, 0].cpu().numpy()
            seen["mode"] = reject[0, 0].cpu().numpy() & v
            seen["useful"] = useful(reject, ctx)[0, 0].cpu().numpy() & v
            seen["valid"] = v
        return reject
    from weights_tools.evaluate import Pipeline
    up = TorchUpscaler(seq["scale"], mode, weights if mode == "net" else None,
                       device=device, reject_hook=hook)
    step = _tracking(state)(Pipeline(up))
    for k in range(t + 1):
        step(seq, k)
    if "mode" not in seen:
        raise ValueError(f"frame {t}: not reached")
    base = 0.35 * cio.tonemap(seq["reference"][t]).mean(-1, keepdims=True).repeat(3, -1)

    def paint(mask, rgb):
        out = base.copy()
        out[mask] = rgb
        out[~seen["valid"]] = (0.0, 0.0, 0.3)
        return out
    panels = [cio.tonemap(seq["reference"][t]), paint(seen["mode"], (1.0, 0.3, 0.2))]
    labels = ["reference", f"{mode}: history dropped ({seen['mode'].mean():.1%})"]
    if "label_ghost" in seq:
        lab = seq["label_ghost"][t] == 0
        panels.append(paint(lab & seen["valid"], (1.0, 0.8, 0.1)))
        labels.append(f"generator's visibility ({(lab & seen['valid']).mean():.1%})")
    panels.append(paint(seen["useful"], (0.2, 1.0, 0.4)))
    labels.append(f"useful: history worse ({seen['useful'].mean():.1%})")
    save_side_by_side(path, panels, labels, tonemapped=True)
    return path


def load(paths):
    from weights_tools.evaluate import load_sequence
    seqs = []
    for p in paths:
        seq = load_sequence(p)
        with np.load(p) as z:
            if "label_ghost" in z.files:
                seq["label_ghost"] = z["label_ghost"]
        seqs.append(seq)
    return seqs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m weights_tools.methods.clss.visibility_oracle",
                                description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("example:")[1].join(("example:", "")),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sequences", nargs="+", metavar="SEQ.npz")
    p.add_argument("--mode", choices=("rules", "net"), default="net")
    p.add_argument("--weights", default=None,
                   help="net: a .safetensors file (default: the package's trained weights)")
    p.add_argument("--ratio", type=float, nargs="+", default=[2.0],
                   help="useful oracle: squared-error ratios to run (default 2)")
    p.add_argument("--floor", type=float, default=1e-3,
                   help="useful oracle: squared PQ error the history may exceed the "
                        "upsample's by in any case (default 1e-3)")
    p.add_argument("--warmup", type=int, default=2, help="frames left unscored after a reset")
    p.add_argument("--json", default=None, help="also write the rows here")
    p.add_argument("--picture", default=None, metavar="PNG",
                   help="also draw frame --frame of the first sequence: the reference and, "
                        "in colour, where the mode drops the history, the generator's "
                        "visibility and the useful decision (dark blue: no valid history)")
    p.add_argument("--frame", type=int, default=6, help="--picture's frame (default 6)")
    a = p.parse_args(argv)
    import torch
    torch.set_num_threads(2)
    weights = a.weights
    if a.mode == "net" and weights is None:
        from clss.methods.clss.upscaler import SHIPPED_WEIGHTS
        weights = SHIPPED_WEIGHTS
    if a.mode == "net":
        from clss.networks import load_weights
        weights = load_weights(weights)
    try:
        seqs = load(a.sequences)
    except (OSError, ValueError) as e:
        print(f"visibility_oracle: {e}", file=sys.stderr)
        return 1
    if a.picture and not 0 <= a.frame < len(seqs[0]["reset"]):
        print(f"visibility_oracle: --frame {a.frame}: {a.sequences[0]} has frames 0-"
              f"{len(seqs[0]['reset']) - 1}", file=sys.stderr)
        return 1
    rows = []
    labelled = all("label_ghost" in q for q in seqs)
    if not labelled:
        print("(some sequences have no label_ghost: the generator oracle is left out)",
              file=sys.stderr)
    for name, oracle, r in ([("as-is", None, None)]
                            + ([("generator", "generator", None)] if labelled else [])
                            + [(f"useful {r:g}", "useful", r) for r in a.ratio]):
        v = score(seqs, a.mode, weights, oracle, a.warmup, r or 2.0, a.floor)
        rows.append({"decision": name, "psnr": v[0], "tpsnr": v[1], "disocclusion_psnr": v[2]})
        print(f"{a.mode} {name:12s} PSNR {v[0]:6.2f}  tPSNR {v[1]:6.2f}  disocc {v[2]:6.2f} dB",
              flush=True)
    if a.picture:
        print(f"wrote {picture(seqs[0], a.mode, weights, a.frame, a.picture, a.ratio[0], a.floor)}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"mode": a.mode, "sequences": a.sequences, "rows": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
