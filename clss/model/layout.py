"""The channel-blocked layout between layers: which tensors of a graph stay blocked.

conv2d_blocked (kernels/conv.cl) reads its input as [N][C/V][H][W][V] (V channels of a
pixel contiguous, V = the device's float vector width). Converted per layer, every conv
pays a layout transform on the way in (to_blocked) and a transposing NCHW store on the
way out; on NSRR's reconstruction U-Net the transforms alone were 13 % of the network.
oneDNN and onnxruntime's MLAS instead keep NCHWc between layers and convert at the
chain's edges. This pass does that: a tensor stays blocked when its producer can write
the blocked layout and every consumer reads it, so transforms remain only where a
blocked chain meets an NCHW op (its first conv converts, as before; its last producer
writes NCHW).

Ops that take and give the blocked layout, with the same arithmetic as on NCHW:
- clss.Conv on the conv2d_blocked path (dense, spatial, >= 8 channels): blocked in;
  blocked out where it has no fused residual.
- clss.MaxPool 2x2 / 2 (kernels/pool.cl max_pool_2x2_blocked; bit-identical).
- Resize, nearest modes (kernels/resize.cl resize_nearest_blocked; bit-identical).
- Concat over channels of tensors whose channel counts are whole blocks: the blocked
  tensors are then concatenated along their block axis.
- clss.LSTMCell (passes.fuse_lstm_cell) reads its gates blocked (kernels/lstm.cl
  -DGATE_BLOCK) and writes NCHW: the gate convolution stores its tile whole.
- clss.Conv with fewer than 8 outputs (a network's RGB or weight head; conv2d_thin, fast
  path conv.thin) reads a blocked input in blocks of 8 or 16 and writes NCHW: the conv
  before it stores its tile whole instead of transposing it into NCHW planes.

A conv's blocked output comes in blocks of V; a clss.ConcatBlocked (a concat of NCHW
tensors that only blocked convs read) writes its own block size (conv.input_block), which
only its convs read. A blocked tensor's channels past C (where C is not a whole number of blocks) hold
finite values that no consumer reads (their weights are zero); a tensor with such
padding is never concatenated. The graph records each blocked tensor's device shape in
``Graph.blocked``; the executor accepts those shapes for them. It is a fast path
(model.blocked_layout, clss/ops/conv.py) with the per-layer transforms as its reference.
"""
from __future__ import annotations

import numpy as np

from .graph import Graph, Node


def _conv_ok(g: Graph, n: Node, blocked_eligible) -> bool:
    if n.op != "clss.Conv" or n.attrs.get("transpose") or len(n.inputs) < 2:
        return False
    w = g.consts.get(n.inputs[1])
    return w is not None and w.ndim == 4 and blocked_eligible(None, w, int(n.attrs.get("group", 1)))


def _thin_ok(g: Graph, n: Node) -> bool:
    """A conv that conv2d_thin runs on a blocked input (few outputs: clss/ops/conv.py
    thin_eligible)."""
    from ..ops.conv import thin_eligible
    if n.op != "clss.Conv" or n.attrs.get("transpose") or len(n.inputs) < 2:
        return False
    w = g.consts.get(n.inputs[1])
    return w is not None and w.ndim == 4 and thin_eligible(
        w, int(n.attrs.get("group", 1)), tuple(n.attrs.get("strides", (1, 1))), tuple(n.attrs.get("dilations", (1, 1))))


def _pool_ok(g: Graph, n: Node) -> bool:
    from ..ops import pool
    # the attributes read as the pool's own handler reads them (pool._pool_attrs)
    return n.op == "clss.MaxPool" and "kernel_shape" in n.attrs and pool.blocked_2x2(**pool._pool_attrs(n.attrs, 2))


def _resize_ok(g: Graph, n: Node) -> bool:
    if n.op != "Resize" or len(n.inputs) < 3:
        return False

    def s(k, d):
        v = n.attrs.get(k, d)
        return v.decode() if isinstance(v, bytes) else v
    if s("mode", "nearest") != "nearest" or s("coordinate_transformation_mode", "half_pixel") == \
            "tf_crop_and_resize" or n.attrs.get("antialias", 0):
        return False
    if any(t and t not in g.consts for t in n.inputs[1:]):
        return False
    x, y = g.shapes.get(n.inputs[0]), g.shapes.get(n.outputs[0])
    return x is not None and y is not None and len(x) == 4 and tuple(x[:2]) == tuple(y[:2])


def _concat_ok(g: Graph, n: Node) -> bool:
    if n.op != "Concat":
        return False
    shapes = [g.shapes.get(t) for t in n.inputs if t]
    return all(s is not None and len(s) == 4 for s in shapes) and int(n.attrs.get("axis", 0)) % 4 == 1


def blocked_tensors(g: Graph, block: int, thin: bool = False) -> dict[str, tuple]:
    """{tensor: blocked device shape} for the tensors of g that can stay blocked in
    blocks of `block` channels (the rules at the top of this file; a fixpoint). thin:
    convs with few outputs read blocked inputs (conv2d_thin, fast path conv.thin)."""
    from ..ops.conv import blocked_eligible, blocked_shape

    kind = {}
    for i, n in enumerate(g.nodes):
        if _conv_ok(g, n, blocked_eligible):
            kind[i] = "conv"
        elif thin and block in (8, 16) and _thin_ok(g, n):
            kind[i] = "thin"        # reads its input blocked, writes NCHW
        elif _pool_ok(g, n):
            kind[i] = "pool"
        elif _resize_ok(g, n):
            kind[i] = "resize"
        elif _concat_ok(g, n):
            kind[i] = "concat"
        elif n.op == "clss.LSTMCell":
            kind[i] = "cell"        # reads its gates blocked, writes NCHW
    uses = g.consumers()
    prod = g.producer()
    outputs = set(g.outputs)

    def candidate(t):
        i = prod.get(t)
        if i is None or t in outputs or kind.get(i) in (None, "cell", "thin") or g.nodes[i].outputs[0] != t:
            return False
        s = g.shapes.get(t)
        if s is None or len(s) != 4 or g.dtypes.get(t, np.dtype("f4")).kind != "f":
            return False
        n = g.nodes[i]
        return not (kind[i] == "conv" and len(n.inputs) > 3 and n.inputs[3])

    blocked = {t for t in prod if candidate(t)}

    def consumer_ok(t, j):
        n = g.nodes[j]
        k = kind.get(j)
        if k == "conv":
            return [q for q, u in enumerate(n.inputs) if u == t] == [0]
        if k in ("pool", "resize"):
            return n.inputs[0] == t and t not in n.inputs[1:] and n.outputs[0] in blocked
        if k == "concat":
            return g.shapes[t][1] % block == 0 and n.outputs[0] in blocked
        if k in ("cell", "thin"):
            return n.inputs[0] == t and t not in n.inputs[1:]
        return False

    changed = True
    while changed:
        changed = False
        for t in sorted(blocked):
            i = prod[t]
            ins_ok = kind[i] == "conv" or all(u in blocked for u in g.nodes[i].inputs[:1 if kind[i] != "concat"
                                                                                     else None] if u)
            if not ins_ok or not all(consumer_ok(t, j) for j in uses.get(t, ())) or not uses.get(t):
                blocked.discard(t)
                changed = True
    return {t: blocked_shape(*g.shapes[t], block) for t in blocked}


def _channel_range(g: Graph, n: Node):
    """(source tensor, first channel, count) of a Slice that takes a contiguous channel
    range of a 4-D tensor and nothing else, or None."""
    if n.op != "Slice" or len(n.inputs) < 3 or any(t and t not in g.consts for t in n.inputs[1:]):
        return None
    shape = g.shapes.get(n.inputs[0])
    if shape is None or len(shape) != 4:
        return None
    from ..ops.elementwise import slice_params
    c = [None if not t else g.consts[t].ravel().tolist() for t in (list(n.inputs[1:]) + [""] * 4)[:4]]
    try:
        sel = slice_params(shape, c[0], c[1], c[2], c[3])
    except ValueError:
        return None
    if any(sel[d] != (0, 1, int(shape[d])) for d in (0, 2, 3)) or sel[1][1] != 1 or sel[1][2] <= 0:
        return None
    return n.inputs[0], sel[1][0], sel[1][2]


def _scaled(g: Graph, j, out_shape) -> tuple | None:
    """(x, m) where node j is Mul(x, m) (either order) of a 4-D float x by a one-channel
    map m of x's N, H and W, broadcast over x's channels (NSRR's reweighted history), so
    that a clss.ConcatBlocked can write x * m itself (kernels/conv.cl to_blocked_table); else None."""
    if j is None or g.nodes[j].op != "Mul" or len(g.nodes[j].inputs) != 2:
        return None
    a, b = g.nodes[j].inputs
    sa, sb = g.shapes.get(a), g.shapes.get(b)
    if sa is None or sb is None or len(sa) != 4 or len(sb) != 4 or a in g.consts or b in g.consts:
        return None
    if any(g.dtypes.get(t, np.dtype("f4")) != g.dtypes.get(g.nodes[j].outputs[0], np.dtype("f4")) for t in (a, b)):
        return None
    for x, m, sx, sm in ((a, b, sa, sb), (b, a, sb, sa)):
        if sm[1] == 1 and sm[0] == sx[0] and tuple(sm[2:]) == tuple(sx[2:]) and \
                tuple(sx[2:]) == tuple(out_shape[2:4]) and sx[0] == out_shape[0]:
            return x, m
    return None


def _gathers(g: Graph, blocked: dict, block: int) -> list:
    """Concats of NCHW tensors whose output only blocked convs read: (node index, output
    blocked shape). They write the blocked layout directly (clss.ConcatBlocked), in the
    blocks a conv's NCHW input is converted to (conv.input_block: 60 channels as 4 x 15,
    not 4 x 16 with 4 zero channels that every tap would multiply)."""
    from ..ops.conv import blocked_eligible, blocked_shape, input_block
    uses = g.consumers()
    out = []
    for i, n in enumerate(g.nodes):
        t = n.outputs[0] if n.outputs else None
        if (not _concat_ok(g, n) or t in blocked or t in g.outputs or not uses.get(t)
                or any(u in blocked for u in n.inputs)):
            continue
        if all(_conv_ok(g, g.nodes[j], blocked_eligible) and [q for q, u in enumerate(g.nodes[j].inputs) if u == t]
               == [0] for j in uses[t]):
            out.append((i, blocked_shape(*g.shapes[t], input_block(int(g.shapes[t][1])))))
    return out


def apply(g: Graph, block: int, thin: bool = False) -> int:
    """Mark g's blocked tensors (Graph.blocked) and tell their producers: convs write
    the blocked layout (attrs blocked_out), concats join along the block axis, concats
    of NCHW tensors that feed blocked convs become clss.ConcatBlocked (reading the
    channel ranges of the Slices that only they read in place, and computing the Muls
    by a one-channel map that only they read: _scaled). Returns how many tensors are
    blocked."""
    g.blocked = blocked_tensors(g, block, thin)
    for n in g.nodes:
        if n.outputs and n.outputs[0] in g.blocked:
            if n.op == "clss.Conv":
                n.attrs["blocked_out"] = True
            elif n.op == "Concat":
                n.attrs["axis"] = 1
            else:   # MaxPool, Resize: a blocked input, a blocked output
                n.attrs["blocked"] = True
    uses = g.consumers()
    prod = g.producer()
    dropped = set()

    def only_here(t):       # a tensor that one node reads and the graph does not return
        return len(uses.get(t, ())) == 1 and t not in g.outputs

    def source(t):
        """(tensor, first channel, count, absorbed node or None) that t reads: a Slice's
        channel range read in place where only the consumer at hand reads the Slice."""
        j = prod.get(t)
        r = _channel_range(g, g.nodes[j]) if j is not None else None
        if r is not None and only_here(t):
            return r[0], r[1], r[2], j
        return t, 0, int(g.shapes[t][1]), None

    for i, shape in _gathers(g, g.blocked, block):
        n = g.nodes[i]
        ins, ranges, scales, extra, sources = [], [], [], [], list(n.sources)

        def absorb(j):
            dropped.add(j)
            sources.extend(g.nodes[j].sources)
        for t in n.inputs:
            if not t:
                continue
            mul = _scaled(g, prod.get(t), shape) if only_here(t) else None
            if mul is not None:         # x * a one-channel map: the scaled transform
                absorb(prod[t])
                x, c0, count, jx = source(mul[0])
                m, ch, _, jm = source(mul[1])
                for j in (jx, jm):
                    if j is not None:
                        absorb(j)
                scales.append((len(extra), ch))
                extra.append(m)
            else:
                x, c0, count, jx = source(t)
                if jx is not None:
                    absorb(jx)
                scales.append(None)
            ins.append(x)
            ranges.append((c0, count))
        attrs = {"block": shape[4], "ranges": ranges}
        if extra:
            attrs["scales"] = scales
        g.nodes[i] = Node("clss.ConcatBlocked", ins + extra, list(n.outputs), attrs, n.name, n.opset,
                          sources=sources)
        g.blocked[n.outputs[0]] = shape
    g.nodes = [n for j, n in enumerate(g.nodes) if j not in dropped]
    return len(g.blocked)


# --- the fast path ----------------------------------------------------------------------

def enabled(dev, prec: str) -> bool:
    """Whether a model on dev in prec keeps blocked chains: the blocked conv itself
    (conv.blocked, a CPU layout) and this pass (model.blocked_layout) both pass."""
    from .. import selfcheck
    return selfcheck.enabled(dev, prec, "conv.blocked") and selfcheck.enabled(dev, prec, "model.blocked_layout")


def check_graph():
    """A small U-Net-like graph (odd width, a padded 24-channel tensor, a pool, a nearest
    resize, a channel concat, a blocked chain's NCHW edges) as ONNX, beside a concat of
    NCHW channel ranges, one of them times a one-channel map (clss.ConcatBlocked with a
    Mul absorbed), read by a conv."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from ..ops.base import rng
    g = rng("blocked layout selfcheck")

    def w(name, co, ci):
        return numpy_helper.from_array((g.standard_normal((co, ci, 3, 3)) * 0.2).astype(np.float32), name)

    def b(name, co):
        return numpy_helper.from_array(g.standard_normal(co).astype(np.float32) * 0.1, name)
    inits = [w("w1", 16, 9), b("b1", 16), w("w2", 24, 16), b("b2", 24), w("w3", 32, 24), b("b3", 32),
             w("w4", 9, 48), b("b4", 9), w("w6", 8, 9),
             numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "sc")]
    inits += [numpy_helper.from_array(np.array(v, np.int64), n) for n, v in
              (("ax", [1]), ("k0", [0]), ("k1", [1]), ("k3", [3]), ("k9", [9]))]
    conv = dict(kernel_shape=[3, 3], pads=[1, 1, 1, 1])
    nodes = [helper.make_node("Conv", ["x", "w1", "b1"], ["c1"], **conv),
             helper.make_node("Relu", ["c1"], ["r1"]),
             helper.make_node("Conv", ["r1", "w2", "b2"], ["c2"], **conv),
             helper.make_node("Relu", ["c2"], ["r2"]),
             helper.make_node("MaxPool", ["r2"], ["p2"], kernel_shape=[2, 2], strides=[2, 2]),
             helper.make_node("Conv", ["p2", "w3", "b3"], ["c3"], **conv),
             helper.make_node("Sigmoid", ["c3"], ["r3"]),
             helper.make_node("Resize", ["r3", "", "sc"], ["u3"], mode="nearest",
                              coordinate_transformation_mode="asymmetric", nearest_mode="floor"),
             helper.make_node("Concat", ["u3", "r1"], ["cat"], axis=-3),
             helper.make_node("Conv", ["cat", "w4", "b4"], ["y"], **conv),
             helper.make_node("Slice", ["x", "k0", "k3", "ax"], ["xa"]),
             helper.make_node("Slice", ["x", "k3", "k9", "ax"], ["xb"]),
             helper.make_node("Slice", ["x", "k0", "k1", "ax"], ["xm"]),
             helper.make_node("Mul", ["xb", "xm"], ["xbm"]),
             helper.make_node("Concat", ["xa", "xbm"], ["cat2"], axis=1),
             helper.make_node("Conv", ["cat2", "w6"], ["y2"], **conv)]
    graph = helper.make_graph(nodes, "blocked_layout_check",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 9, 6, 22])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 9, 6, 22]),
                               helper.make_tensor_value_info("y2", TensorProto.FLOAT, [1, 8, 6, 22])], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m
