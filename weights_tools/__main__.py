"""python -m weights_tools build --out DIR [...] | inspect FILE | gen --out DIR [...] |
eval SEQ.npz [--methods a,b,c] | blender --out DIR [...] | train METHOD --data DIR --out DIR [...] | seeds METHOD [...] |
export-suite --out DIR"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import onnx

from clss.methods.clss import networks
from clss.networks import weights

from . import evaluate, jitter_mix

RESOLUTIONS = (("540p", 540, 960), ("1080p", 1080, 1920), ("2160p", 2160, 3840))


def _save_onnx(model, path):
    tmp = path + ".tmp"
    onnx.save(model, tmp)
    os.replace(tmp, path)


def _flops_table(cls, comp):
    print("output   classifier  composition  total GFLOP (conv, MAC = 2 FLOP)")
    for label, h, w in RESOLUTIONS:
        a, b = networks.frame_flops(cls, comp, h, w)
        print(f"{label:7s} {a / 1e9:10.2f} {b / 1e9:12.2f} {(a + b) / 1e9:12.2f}")


def cmd_build(args):
    widths = tuple(int(v) for v in args.widths.split(","))
    os.makedirs(args.out, exist_ok=True)
    cls = networks.build_classifier(widths, seed=args.seed, height=args.height, width=args.width)
    comp = networks.build_composition(args.mlp_hidden, seed=args.seed,
                                      height=args.height, width=args.width)
    for m in (cls, comp):
        onnx.checker.check_model(m)
    _save_onnx(cls, os.path.join(args.out, "classifier.onnx"))
    _save_onnx(comp, os.path.join(args.out, "composition.onnx"))
    weights.save_weights([cls, comp], os.path.join(args.out, "weights.safetensors"),
                         half=args.fp16)
    print(f"wrote classifier.onnx ({networks.count_params(cls)} params), composition.onnx "
          f"({networks.count_params(comp)} params), weights.safetensors "
          f"({'fp16' if args.fp16 else 'fp32'}) to {args.out}")
    _flops_table(cls, comp)
    return 0


def _inspect_onnx(path):
    m = onnx.load(path)
    g = m.graph

    def shape(v):
        return [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
    print(f"{path}: ir_version {m.ir_version}, opset "
          + ", ".join(f"{o.domain or 'ai.onnx'}:{o.version}" for o in m.opset_import))
    for v in g.input:
        print(f"  input  {v.name} {shape(v)}")
    for v in g.output:
        print(f"  output {v.name} {shape(v)}")
    ops = {}
    for n in g.node:
        ops[n.op_type] = ops.get(n.op_type, 0) + 1
    print("  nodes  " + ", ".join(f"{k} x{v}" for k, v in sorted(ops.items())))
    print(f"  params {networks.count_params(m)}")
    if g.input and g.input[0].name == "x":
        for label, h, w in RESOLUTIONS:
            hp, wp = (-(-h // 16) * 16, -(-w // 16) * 16) if "SpaceToDepth" in ops else (h, w)
            print(f"  {label}: {networks.count_flops(m, hp, wp) / 1e9:.2f} GFLOP")
    if m.doc_string:
        print("  " + m.doc_string)


def _inspect_safetensors(path):
    t = weights.load_weights(path)
    total = 0
    print(f"{path}: {len(t)} tensors")
    for k in sorted(t):
        a = t[k]
        total += a.size
        af = a.astype(np.float64)
        print(f"  {k:28s} {str(a.dtype):8s} {str(list(a.shape)):18s} "
              f"mean {af.mean():+.4f} std {af.std():.4f}")
    print(f"  {total} values")


def cmd_inspect(args):
    if args.file.endswith(".onnx"):
        _inspect_onnx(args.file)
    elif args.file.endswith(".safetensors"):
        _inspect_safetensors(args.file)
    else:
        print(f"{args.file}: expected a .onnx or .safetensors file", file=sys.stderr)
        return 2
    return 0


def _size(text):
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW (e.g. 72x128), got {text!r}") from None
    if h < 4 or w < 4:
        raise argparse.ArgumentTypeError(f"sizes must be at least 4x4, got {text!r}")
    return h, w


def cmd_gen(args):
    """Generated sequences go to OUT.partial/, which becomes OUT/ (with a READY file)
    once complete, so a reader never sees half a data set."""
    import json
    import shutil
    from . import scenegen
    out = os.path.normpath(args.out)
    if os.path.exists(out):
        print(f"error: --out {out} already exists (choose a new directory)", file=sys.stderr)
        return 2
    for name, v in (("--sequences", args.sequences), ("--frames", args.frames),
                    ("--spp", args.spp), ("--workers", args.workers)):
        if v < 1:
            print(f"error: {name} must be at least 1, got {v}", file=sys.stderr)
            return 2
    if not 1.0 <= args.scale <= 4.0:
        print(f"error: --scale must be in [1, 4], got {args.scale}", file=sys.stderr)
        return 2
    try:
        jitter_mix.check_arg("--jitter-mix", args.jitter_mix)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    tmp = out + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    stats = scenegen.generate(tmp, args.sequences, args.frames, args.seed, args.size,
                              args.scale, args.spp, args.workers,
                              log=(lambda m: None) if args.quiet else print,
                              mix=args.jitter_mix)
    with open(os.path.join(tmp, "READY"), "w") as fh:
        fh.write(json.dumps({k: stats[k] for k in ("sequences", "frames", "seed", "jitter_mix")})
                 + "\n")
    os.replace(tmp, out)
    print(f"wrote {args.sequences} sequences of {args.frames} frames to {out} "
          f"in {stats['seconds']:.1f} s")
    for key, names in stats["class_names"].items():
        print(f"  {key:5s} " + ", ".join(f"{n} {f:6.2%}" for n, f
                                         in zip(names, stats["frequencies"][key])))
    return 0
def _add_train(sub):
    """`train` and `seeds` (the recipes, weights_tools/recipes.py), `export-suite` (the
    exported-model fixtures, weights_tools/export_suite.py) and the rooms' own sub-commands
    (weights_tools.methods.commands(): CLSS's `classifier`) need torch, the [train] extra;
    without it each says so instead of breaking the others."""
    import importlib
    from . import methods
    commands = methods.commands()
    try:
        import torch  # noqa: F401
    except ModuleNotFoundError as e:
        missing = e.name

        def no_torch(args):
            print(f"error: {args.cmd} needs {missing} (pip install -e '.[train]')",
                  file=sys.stderr)
            return 1
        for name in ("train", "seeds", "export-suite", *commands):
            t = sub.add_parser(name, help=f"{name} (needs the [train] extra)")
            t.add_argument("rest", nargs=argparse.REMAINDER)
            t.set_defaults(fn=no_torch)
        return
    from .recipes import add_train_parser
    add_train_parser(sub)
    from .seeds import add_parser as add_seeds
    add_seeds(sub)
    from .export_suite import add_parser as add_export_suite
    add_export_suite(sub)
    for module in commands.values():
        importlib.import_module(module).add_parser(sub)


def parser():
    """Every sub-command's parser (the training ones need torch: without it each says so)."""
    p = argparse.ArgumentParser(prog="python -m weights_tools", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="write classifier.onnx, composition.onnx, weights.safetensors")
    b.add_argument("--out", required=True)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--widths", default=",".join(map(str, networks.DEFAULT_WIDTHS)),
                   help="classifier encoder widths c0,c1,c2,c3")
    b.add_argument("--mlp-hidden", type=int, default=networks.DEFAULT_MLP_HIDDEN)
    b.add_argument("--height", type=int,
                   help="fixed output height (multiple of 16); default symbolic")
    b.add_argument("--width", type=int, help="fixed output width (multiple of 16)")
    b.add_argument("--fp16", action="store_true", help="store the weights as float16")
    b.set_defaults(fn=cmd_build)
    i = sub.add_parser("inspect", help="describe a .onnx or .safetensors file")
    i.add_argument("file")
    i.set_defaults(fn=cmd_inspect)
    e = sub.add_parser("eval", help="score any set of methods on sequences (PSNR, SSIM, tPSNR, "
                       "FLIP) and write pictures and JSON (the scoring of `clss eval`)")
    evaluate.add_arguments(e)
    e.set_defaults(fn=lambda a: evaluate.main_args(a, e))
    g = sub.add_parser("gen", help="generate labelled training sequences (DATA.md .npz)")
    g.add_argument("--out", required=True, help="new directory to write")
    g.add_argument("--sequences", type=int, default=8)
    g.add_argument("--frames", type=int, default=8)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--size", type=_size, default=(72, 128), help="render size HxW")
    g.add_argument("--scale", type=float, default=2.0)
    g.add_argument("--spp", type=int, default=16, help="reference samples per pixel")
    g.add_argument("--workers", type=int, default=2, help="processes")
    g.add_argument("--jitter-mix", default=jitter_mix.DEFAULT_MIX,
                   help="each sequence's jitter pattern drawn from NAME[:WEIGHT],... (zero, "
                   "2x2, halton8, halton16, halton, r2; 'legacy': before issue 53; one name: "
                   f"every sequence that pattern; default {jitter_mix.DEFAULT_MIX})")
    g.add_argument("--quiet", action="store_true")
    g.set_defaults(fn=cmd_gen)
    from .blender import shards
    shards.add_parser(sub, _size)
    _add_train(sub)
    return p


def spelled_out(argv):
    """The command line with the default methods of `train` and `seeds` written in."""
    from .recipes import with_default_method
    return with_default_method(with_default_method(argv, "train"), "seeds")


def main(argv=None):
    args = parser().parse_args(spelled_out(sys.argv[1:] if argv is None else argv))
    try:
        return args.fn(args)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    from clss.exiting import leave   # past pip's PoCL 3.0 teardown abort (clss/cli/__init__.py)
    leave(main())
