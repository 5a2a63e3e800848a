"""python -m weights_tools build --out DIR [...] | inspect FILE"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import onnx

from . import networks, weights

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


def _add_train(sub):
    """`train` (weights_tools/train.py) needs torch, the [train] extra; without it the
    subcommand says so instead of breaking the others."""
    try:
        from .train import add_parser
    except ModuleNotFoundError as e:
        missing = e.name

        def no_torch(args):
            print(f"error: train needs {missing} (pip install -e '.[train]')", file=sys.stderr)
            return 1
        t = sub.add_parser("train", help="train the networks (needs the [train] extra)")
        t.add_argument("rest", nargs=argparse.REMAINDER)
        t.set_defaults(fn=no_torch)
        return
    add_parser(sub)


def main(argv=None):
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
    _add_train(sub)
    args = p.parse_args(argv)
    try:
        return args.fn(args)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
