"""`clss upscale --method mlp --online`: the shader MLP learns on the device while it
upscales (online.py), from the sequence's reference frames. The mlp specs name this
module (MethodSpec.cli), so that the shared clss/cli/upscale.py asks the specs for the
options methods add and calls these functions, knowing no method."""
from __future__ import annotations

import sys

METHODS = ("mlp", "mlp-nofeature")


def add_arguments(p):
    g = p.add_argument_group("online training (--method mlp / mlp-nofeature)")
    g.add_argument("--online", action="store_true",
                   help="train the shader MLP on the device while it upscales: every frame "
                        "with a reference (reference.NNNN.exr, or --channels reference=...) "
                        "trains it (patches accepted by gradient; forward, backward, Adam), "
                        "then is upscaled with the updated weights. Starts from --weights (a "
                        ".safetensors; 'scratch' for none), else the shipped weights")
    g.add_argument("--train-every", type=int, default=1, metavar="N",
                   help="with --online: train on every Nth frame's reference only (default 1)")
    g.add_argument("--online-steps", type=int, default=None, metavar="K",
                   help="with --online: optimiser steps per training frame (default 1)")
    g.add_argument("--online-batch", type=int, default=None, metavar="P",
                   help="with --online: patches per step (default 32)")
    g.add_argument("--online-lr", type=float, default=None, metavar="LR",
                   help="with --online: Adam's learning rate (default 1e-3)")
    g.add_argument("--save-weights", default=None, metavar="FILE",
                   help="with --online: write the learnt weights (.safetensors) at the end")


def check(a, name, usage_error):
    """Refuse the online options where they mean nothing; the Upscaler's keywords."""
    given = [o for o, v in (("--train-every", a.train_every != 1), ("--online-steps", a.online_steps),
                            ("--online-batch", a.online_batch), ("--online-lr", a.online_lr),
                            ("--save-weights", a.save_weights)) if v]
    if not a.online:
        if given:
            raise usage_error(f"{given[0]}: needs --online")
        return {}
    if name not in METHODS:
        raise usage_error(f"--online: the method {name} does not train online (the shader MLP "
                          f"does: --method {' or '.join(METHODS)})")
    for opt, v in (("--train-every", a.train_every), ("--online-steps", a.online_steps),
                   ("--online-batch", a.online_batch)):
        if v is not None and v < 1:
            raise usage_error(f"{opt}: at least 1, got {v}")
    if a.online_lr is not None and not a.online_lr > 0:
        raise usage_error(f"--online-lr: a positive number, got {a.online_lr}")
    return dict(online=True, online_steps=a.online_steps, online_batch=a.online_batch,
                online_lr=a.online_lr)


def step_kwargs(a, i, frame) -> dict:
    """What the step at position i takes besides the frame: the reference it trains on."""
    if not getattr(a, "online", False) or i % a.train_every:
        return {}
    ref = getattr(frame, "reference", None)
    return {} if ref is None else {"reference": ref}


def report(a, up, number):
    if getattr(a, "online", False) and up.last_loss is not None:
        tr = up.online
        print(f"online: frame {number}: L1 {up.last_loss:.5f} (PQ), {tr.t} steps, patches "
              f"accepted {tr.accepted}/{tr.tried}", file=sys.stderr)
        up.last_loss = None


def finish(a, up):
    if not getattr(a, "online", False):
        return
    tr = up.online
    if not tr.history:
        print("online: no frame carried a reference: nothing was learnt (reference.NNNN.exr "
              "beside the frames, or --channels reference=...)", file=sys.stderr)
    else:
        first, last = tr.history[0][1], tr.history[-1][1]
        print(f"online: {len(tr.history)} training frames, {tr.t} steps; L1 {first:.5f} -> "
              f"{last:.5f} (PQ)")
    if a.save_weights:
        up.save_weights(a.save_weights, {"source": "clss upscale --online"})
        print(f"online: wrote the learnt weights to {a.save_weights}")
