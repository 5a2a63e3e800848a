"""Graph patterns that exporters write out op by op, matched back into one kernel each
(run by clss/model/passes.py's PASSES):

* layer_norm: a LayerNorm written as ReduceMean, Sub, Pow (or Mul), ReduceMean, Add,
  Sqrt, Div (or Reciprocal and Mul), then a Mul by a weight and an Add of a bias: the
  TorchScript exporter below opset 17, hand-written LayerNorms, and the channel
  LayerNorm of NCHW models (NAFNet's, ConvNeXt's LayerNorm2d), whose mean and variance
  run over C at each pixel. Over the trailing axes it becomes LayerNormalization; over a
  block of axes that is not the last, clss.NormBlock (kernels/norm.cl norm_strided).
* layer_norm_stats: a LayerNormalization whose Mean and InvStdDev nobody reads writes only Y.
* float_exponents: Pow by a constant exponent of 2, 1, 0.5 or -1 as Mul(x, x), the input,
  Sqrt or Reciprocal (pow() is a library call per element on PoCL); another integer
  exponent (the dynamo exporter writes ``x ** 3`` with an int64 scalar) as a float
  constant, as the kernel takes it.

Each fused node keeps the nodes it replaces (``unfused``): where its kernel refuses a
case, the dry run falls back to them.
"""
from __future__ import annotations

import numpy as np

from .execute import internal_op
from .graph import Graph, Node


@internal_op("clss.NormBlock")
def _norm_block(dev, prec, attrs, inputs):
    """x viewed [outer, length, inner], normalised along length (clss/ops/norm.py)."""
    from ..ops.norm import norm_block
    x, scale, bias = (list(inputs) + [None] * 3)[:3]
    return [norm_block(dev, prec, x, scale, bias, attrs["outer"], attrs["length"], attrs["inner"],
                       attrs["epsilon"])]


def _reduce_axes(g: Graph, n: Node):
    """The axes of a ReduceMean with keepdims (normalised, sorted), or None."""
    if n.op != "ReduceMean" or not int(n.attrs.get("keepdims", 1)):
        return None
    axes = n.attrs.get("axes")
    if len(n.inputs) > 1 and n.inputs[1]:
        v = g.consts.get(n.inputs[1])
        if v is None:
            return None
        axes = v.ravel().tolist()
    if not axes:
        return None
    r = len(g.shapes[n.inputs[0]])
    return sorted(int(a) % r for a in axes)


def _scalar(g: Graph, t: str):
    v = g.consts.get(t)
    return float(v.ravel()[0]) if v is not None and v.size == 1 else None


def _other(n: Node, t: str):
    """The other input of a binary node n, one of whose inputs is t."""
    if len(n.inputs) != 2:
        return None
    a, b = n.inputs
    return b if a == t else a if b == t else None


def fuse_layer_norm(g: Graph) -> int:
    changed = 0
    while True:
        m = _match_layer_norm(g)
        if m is None:
            return changed
        nodes, new = m
        idx = [g.nodes.index(n) for n in nodes]
        first = min(idx)
        keep = [n for k, n in enumerate(g.nodes) if k not in set(idx)]
        keep.insert(first - sum(1 for k in idx if k < first), new)
        g.nodes = keep
        changed += 1


def _match_layer_norm(g: Graph):
    uses = g.consumers()
    prod = g.producer()
    outs = set(g.outputs)

    def only(t):
        u = uses.get(t, [])
        return g.nodes[u[0]] if len(u) == 1 and t not in outs else None

    for m1 in g.nodes:
        axes = _reduce_axes(g, m1)
        if axes is None or m1.unfused or g.dtypes.get(m1.outputs[0], np.dtype("f4")).kind != "f":
            continue
        x, mean = m1.inputs[0], m1.outputs[0]
        shape = tuple(g.shapes[x])
        if axes != list(range(axes[0], axes[-1] + 1)):
            continue   # the normalised axes must be one block
        d = only(mean)
        if d is None or d.op != "Sub" or d.inputs != [x, mean]:
            continue
        du = [g.nodes[k] for k in dict.fromkeys(uses.get(d.outputs[0], []))]   # Mul(d, d) reads d twice
        if len(du) != 2 or d.outputs[0] in outs:
            continue
        sq = next((n for n in du if (n.op == "Pow" and n.inputs[0] == d.outputs[0]
                                     and _scalar(g, n.inputs[1]) == 2.0)
                   or (n.op == "Mul" and n.inputs == [d.outputs[0]] * 2)), None)
        if sq is None:
            continue
        div = next(n for n in du if n is not sq)
        m2 = only(sq.outputs[0])
        if m2 is None or _reduce_axes(g, m2) != axes:
            continue
        add = only(m2.outputs[0])
        if add is None or add.op != "Add":
            continue
        eps_t = _other(add, m2.outputs[0])
        eps = _scalar(g, eps_t) if eps_t else None
        if eps is None:
            continue
        sqrt = only(add.outputs[0])
        if sqrt is None or sqrt.op != "Sqrt":
            continue
        chain = [m1, d, sq, m2, add, sqrt]
        if div.op == "Div" and div.inputs == [d.outputs[0], sqrt.outputs[0]] and only(sqrt.outputs[0]) is div:
            chain.append(div)
        elif div.op == "Mul":
            rec = only(sqrt.outputs[0])
            if rec is None or rec.op != "Reciprocal" or _other(div, d.outputs[0]) != rec.outputs[0] \
                    or only(rec.outputs[0]) is not div:
                continue
            chain += [rec, div]
        else:
            continue
        y = div.outputs[0]
        block = shape[axes[0]:axes[-1] + 1]
        length = int(np.prod(block, dtype=np.int64))
        # the affine part: a constant weight and bias over the normalised block only
        weight = bias = None
        for op in ("Mul", "Add"):
            nxt = only(y)
            if nxt is None or nxt.op != op:
                break
            c = _other(nxt, y)
            v = g.consts.get(c) if c else None
            if v is None or (op == "Mul" and weight is not None):
                break
            flat = _block_vector(v, shape, axes)
            if flat is None or tuple(g.shapes[nxt.outputs[0]]) != shape:
                break
            if op == "Mul":
                weight = flat
            else:
                bias = flat
            chain.append(nxt)
            y = nxt.outputs[0]
        if weight is None:
            weight = np.ones(length, np.float32)
        w = g.add_const(f"{m1.name}.ln_scale", weight.astype(np.float32))
        b = g.add_const(f"{m1.name}.ln_bias", bias.astype(np.float32)) if bias is not None else ""
        sources = [s for n in chain for s in n.sources]
        if axes[-1] == len(shape) - 1:
            ws = g.add_const(f"{m1.name}.ln_scale_shaped", weight.reshape(block).astype(np.float32))
            bs = g.add_const(f"{m1.name}.ln_bias_shaped", bias.reshape(block).astype(np.float32)) \
                if bias is not None else ""
            node = Node("LayerNormalization", [x, ws, bs], [y], {"axis": axes[0], "epsilon": eps, "clss_stats": 0},
                        m1.name, m1.opset, sources=sources, unfused=list(chain))
        else:
            outer = int(np.prod(shape[:axes[0]], dtype=np.int64))
            inner = int(np.prod(shape[axes[-1] + 1:], dtype=np.int64))
            node = Node("clss.NormBlock", [x, w, b], [y],
                        {"outer": outer, "length": length, "inner": inner, "epsilon": eps},
                        m1.name, m1.opset, sources=sources, unfused=list(chain))
        return chain, node
    return None


def _block_vector(v: np.ndarray, shape, axes):
    """A constant that varies only along the normalised axes (broadcast over the others),
    flattened over them; None where it varies elsewhere or does not broadcast."""
    r = len(shape)
    v = np.asarray(v, np.float32)
    if v.ndim > r:
        return None
    full = (1,) * (r - v.ndim) + v.shape
    for k, n in enumerate(full):
        if n != 1 and (n != shape[k] or not axes[0] <= k <= axes[-1]):
            return None
    v = v.reshape(full)
    block = tuple(shape[axes[0]:axes[-1] + 1])
    sel = v[tuple(0 if not axes[0] <= k <= axes[-1] else slice(None) for k in range(r))]
    return np.ascontiguousarray(np.broadcast_to(sel, block)).ravel()


def layer_norm_stats(g: Graph) -> int:
    """A LayerNormalization whose Mean and InvStdDev nobody reads writes only Y (clss_stats=0):
    the exporters' LayerNorms list no statistics, or list them unread."""
    uses = g.consumers()
    changed = 0
    for n in g.nodes:
        if n.op == "LayerNormalization" and int(n.attrs.get("clss_stats", 1)):
            if not any(t and (t in uses or t in g.outputs) for t in n.outputs[1:]):
                n.attrs = {**n.attrs, "clss_stats": 0}
                n.outputs = n.outputs[:1]
                changed += 1
    return changed


# Pow by these constant exponents is an op clss runs without pow() (a library call per
# element on PoCL: 40x slower than a multiply at 540x960): x ** 2 is Mul(x, x), and so on.
_POW_AS = {2.0: "Mul", 1.0: "Identity", 0.5: "Sqrt", -1.0: "Reciprocal"}


def float_exponents(g: Graph) -> int:
    """Pow(x, k) with a constant k: x * x for 2, sqrt for 0.5, 1 / x for -1, x for 1; other
    integer k as a float constant (the kernel's operands are float; the dynamo exporter
    writes x ** 2 with an int64 scalar)."""
    changed = 0
    for k, n in enumerate(g.nodes):
        if n.op != "Pow" or len(n.inputs) != 2:
            continue
        v = g.consts.get(n.inputs[1])
        if v is None:
            continue
        x = n.inputs[0]
        if v.size == 1 and float(v.ravel()[0]) in _POW_AS and tuple(g.shapes[n.outputs[0]]) == tuple(g.shapes[x]) \
                and g.dtypes.get(x, np.dtype("f4")).kind == "f":
            op = _POW_AS[float(v.ravel()[0])]
            g.nodes[k] = Node(op, [x, x] if op == "Mul" else [x], list(n.outputs), {}, n.name, n.opset,
                              sources=n.sources)
            changed += 1
        elif v.dtype.kind in "iub":
            n.inputs = [x, g.add_const(f"{n.name}.exponent", v.astype(np.float32))]
            changed += 1
    return changed
