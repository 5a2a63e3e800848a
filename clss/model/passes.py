"""Load-time graph rewrites on the static Graph (clss/model/graph.py).

Each pass keeps the graph's meaning exactly (up to float rounding where
weights are refolded) and every tensor's recorded shape. Order matters and is
fixed in ``run_passes``: opset normalisation, Identity removal, pattern
matching on Reshape/Transpose, then views, BatchNorm folding, MatMul/Gemm
lowering, Conv canonicalisation and fusion, MLP chains, dead-node removal.
Fused nodes keep the nodes they replace (``Node.unfused``) so the load-time
dry run can fall back when a kernel refuses the fused form.
"""
from __future__ import annotations

import numpy as np

from .graph import FLOAT_TYPES, Graph, Node
from .patterns import float_exponents, fuse_layer_norm, layer_norm_stats

ACT_OPS = {"Relu": "relu", "LeakyRelu": "leaky_relu", "Sigmoid": "sigmoid", "Tanh": "tanh"}

def run_passes(g: Graph, conv_fusion: bool = True, mlp_fusion: bool = True) -> list[str]:
    """Apply every pass; returns a log of what each changed (for `clss info`)."""
    log = []
    for name, fn in PASSES:
        if name.startswith("conv") and not conv_fusion:
            continue
        if name == "mlp" and not mlp_fusion:
            continue
        n = fn(g)
        if n:
            log.append(f"{name}: {n}")
    return log


# --- helpers ------------------------------------------------------------------------

def _replace_uses(g: Graph, old: str, new: str) -> None:
    for n in g.nodes:
        n.inputs = [new if t == old else t for t in n.inputs]


def _single_use(g: Graph, t: str, uses: dict) -> bool:
    return len(uses.get(t, ())) == 1 and t not in g.outputs


def _const(g: Graph, t: str):
    return g.consts.get(t) if t else None


def _view(g: Graph, x: str, shape, out: str | None = None, name: str = "", sources=None) -> tuple[Node, str]:
    shape = tuple(int(s) for s in shape)
    out = out or g.fresh(x)
    g.shapes[out] = shape
    g.dtypes[out] = g.dtypes[x]
    return Node("clss.View", [x], [out], {"shape": shape}, name or f"view {x}", g.opset,
                sources=sources or [(name or f"view {x}", "Reshape")]), out


# --- opset normalisation ------------------------------------------------------------

def normalise_opsets(g: Graph) -> int:
    """Handlers implement the current (opset 13+) semantics; older forms are
    rewritten: Softmax/LogSoftmax/Hardmax < 13 flatten to 2-D at ``axis``;
    Split < 13 takes its sizes as an attribute."""
    changed = 0
    new_nodes = []
    for n in g.nodes:
        if n.op in ("Softmax", "LogSoftmax", "Hardmax") and n.opset < 13:
            shape = g.shapes[n.inputs[0]]
            r = len(shape)
            axis = int(n.attrs.get("axis", 1))
            axis = axis + r if axis < 0 else axis
            n.attrs = {**n.attrs, "axis": -1}
            if axis != r - 1 and r > 0:
                rows = int(np.prod(shape[:axis], dtype=np.int64))
                cols = int(np.prod(shape[axis:], dtype=np.int64))
                v1, t1 = _view(g, n.inputs[0], (rows, cols), name=f"{n.name} (2-D)", sources=n.sources)
                y = n.outputs[0]
                t2 = g.fresh(y)
                g.shapes[t2] = (rows, cols)
                g.dtypes[t2] = g.dtypes[y]
                v2, _ = _view(g, t2, shape, out=y, name=f"{n.name} (back)", sources=n.sources)
                n.inputs = [t1]
                n.outputs = [t2]
                new_nodes += [v1, n, v2]
                changed += 1
                continue
            changed += 1
        elif n.op == "Split" and (len(n.inputs) < 2 or not n.inputs[1]):
            # Sizes explicit from the resolved output shapes: the attribute form
            # (< 13), and the equal split whose count is only the output count.
            r = len(g.shapes[n.inputs[0]])
            axis = int(n.attrs.get("axis", 0))
            axis = axis + r if axis < 0 else axis
            sizes = np.array(n.attrs.get("split", [g.shapes[t][axis] for t in n.outputs]), np.int64)
            n.attrs = {k: v for k, v in n.attrs.items() if k not in ("split", "num_outputs")}
            n.inputs = [n.inputs[0], g.add_const(f"{n.name}.split", sizes)]
            changed += 1
        new_nodes.append(n)
    g.nodes = new_nodes
    return changed


# --- Identity, Dropout, float casts ---------------------------------------------------

def _cast_to_float(g: Graph, n: Node) -> bool:
    """A Cast/CastLike whose target is float or float16 (one type here: clss
    stores every float tensor in the precision's storage type; the model's
    ``precision`` decides, not the graph). Constant ones were folded at load."""
    if n.op == "Cast":
        return int(n.attrs.get("to", 0)) in FLOAT_TYPES
    if n.op == "CastLike":
        return g.dtypes.get(n.inputs[1]) == np.float32   # float16 tensors are float32 here
    return False


def _float_cast(g: Graph, n: Node) -> bool:
    """Float to float casts are identities."""
    return _cast_to_float(g, n) and g.dtypes.get(n.inputs[0]) == np.float32


def bool_casts(g: Graph) -> int:
    """Cast of a bool tensor (a comparison's result) to float, as exporters
    write ``mask.float()``: Where(mask, 1, 0), a kernel clss has."""
    changed = 0
    for k, n in enumerate(g.nodes):
        if _cast_to_float(g, n) and g.dtypes.get(n.inputs[0]) == np.bool_:
            one = g.add_const(f"{n.name}.one", np.ones((), np.float32))
            zero = g.add_const(f"{n.name}.zero", np.zeros((), np.float32))
            g.nodes[k] = Node("Where", [n.inputs[0], one, zero], n.outputs[:1], {}, n.name, n.opset,
                              sources=n.sources)
            changed += 1
    return changed


def remove_identities(g: Graph) -> int:
    """Identity, Dropout (inference, or training with ratio 0: no randomness) and
    float-to-float casts cost nothing: their consumers read the input. A graph
    output that would be left without a producer of its own gets a clss.Copy."""
    changed = 0
    inputs = set(g.inputs)
    outputs = set(g.outputs)
    for n in list(g.nodes):
        if _float_cast(g, n):
            n.inputs = n.inputs[:1]
        elif n.op == "Dropout":
            tm = n.inputs[2] if len(n.inputs) > 2 else ""
            ratio = n.inputs[1] if len(n.inputs) > 1 else ""
            if (tm and (tm not in g.consts or bool(g.consts[tm]))
                    and not (ratio in g.consts and not np.any(g.consts[ratio]))):
                continue  # training mode, random: left for the unsupported list
            if len(n.outputs) > 1 and n.outputs[1]:
                g.consts[n.outputs[1]] = np.ones(g.shapes[n.outputs[1]], bool)
            n.outputs = n.outputs[:1]
            n.inputs = n.inputs[:1]
        elif n.op != "Identity":
            continue
        x, y = n.inputs[0], n.outputs[0]
        changed += 1
        if x in g.consts and y not in g.consts:
            g.consts[y] = g.consts[x]
            g.nodes.remove(n)
        elif y not in outputs:
            g.nodes.remove(n)
            _replace_uses(g, y, x)
        elif x not in inputs and x not in outputs and x not in g.consts:
            # The producer writes the output name directly.
            g.nodes.remove(n)
            for m in g.nodes:
                m.outputs = [y if t == x else t for t in m.outputs]
            _replace_uses(g, x, y)
        else:
            n.op = "clss.Copy"
            n.attrs = {}
    return changed


# --- Reshape/Transpose patterns ------------------------------------------------------

# (6-D intermediate layout, perm) -> (op, mode). Block size r, channels C, H, W:
#   DepthToSpace CRD (pixel_shuffle):   [N,C,r,r,H,W] perm (0,1,4,2,5,3)
#   DepthToSpace DCR (ONNX default):    [N,r,r,C,H,W] perm (0,3,4,1,5,2)
#   SpaceToDepth CRD (pixel_unshuffle): [N,C,H,r,W,r] perm (0,1,3,5,2,4)
#   SpaceToDepth DCR (ONNX):            [N,C,H,r,W,r] perm (0,3,5,1,2,4)
_SHUFFLES = {(0, 1, 4, 2, 5, 3): ("DepthToSpace", "CRD"), (0, 3, 4, 1, 5, 2): ("DepthToSpace", "DCR"),
             (0, 1, 3, 5, 2, 4): ("clss.SpaceToDepth", "CRD"), (0, 3, 5, 1, 2, 4): ("SpaceToDepth", "DCR")}


def _shuffle_block(op, mode, x_shape, t1_shape, y_shape):
    """The block size if the shapes are exactly that shuffle, else None."""
    if len(x_shape) != 4 or len(t1_shape) != 6 or len(y_shape) != 4:
        return None
    n, c0, h0, w0 = x_shape
    if op == "DepthToSpace":
        r = t1_shape[2] if mode == "CRD" else t1_shape[1]
        want_t1 = (n, c0 // (r * r), r, r, h0, w0) if mode == "CRD" else (n, r, r, c0 // (r * r), h0, w0)
        want_y = (n, c0 // (r * r), h0 * r, w0 * r)
        ok = r > 0 and c0 % (r * r) == 0
    else:
        r = t1_shape[3]
        want_t1 = (n, c0, h0 // r, r, w0 // r, r) if r > 0 else None
        want_y = (n, c0 * r * r, h0 // r, w0 // r) if r > 0 else None
        ok = r > 0 and h0 % r == 0 and w0 % r == 0
    if ok and tuple(t1_shape) == want_t1 and tuple(y_shape) == want_y:
        return int(r)
    return None


def pixel_shuffle(g: Graph) -> int:
    """Reshape -> Transpose -> Reshape spelling PixelShuffle/PixelUnshuffle
    (either channel order) becomes one DepthToSpace/SpaceToDepth."""
    changed = 0
    while True:
        uses = g.consumers()
        prod = g.producer()
        hit = None
        for i, t in enumerate(g.nodes):
            if t.op != "Transpose":
                continue
            perm = tuple(int(p) for p in t.attrs.get("perm", ()))
            if perm not in _SHUFFLES:
                continue
            a, b = t.inputs[0], t.outputs[0]
            if a not in prod or not _single_use(g, a, uses) or not _single_use(g, b, uses):
                continue
            r1 = g.nodes[prod[a]]
            r2 = g.nodes[uses[b][0]]
            if r1.op != "Reshape" or r2.op != "Reshape" or r1.inputs[0] in g.consts:
                continue
            op, mode = _SHUFFLES[perm]
            x, y = r1.inputs[0], r2.outputs[0]
            r = _shuffle_block(op, mode, g.shapes[x], g.shapes[a], g.shapes[y])
            if r is None:
                continue
            hit = (r1, t, r2, op, mode, r, x, y)
            break
        if hit is None:
            return changed
        r1, t, r2, op, mode, r, x, y = hit
        attrs = {"blocksize": r}
        if op != "SpaceToDepth":
            attrs["mode"] = mode
        node = Node(op, [x], [y], attrs, r2.name, r2.opset,
                    sources=r1.sources + t.sources + r2.sources)
        k = g.nodes.index(r2)
        g.nodes[k] = node
        g.nodes.remove(r1)
        g.nodes.remove(t)
        changed += 1


def lower_views(g: Graph) -> int:
    """Reshape, Flatten, Squeeze, Unsqueeze (static shapes: the output shape is
    known) and Transposes that only move size-1 axes are views of their input."""
    changed = 0
    for k, n in enumerate(g.nodes):
        if n.op in ("Reshape", "Flatten", "Squeeze", "Unsqueeze"):
            pass
        elif n.op == "Transpose":
            shape = g.shapes[n.inputs[0]]
            perm = n.attrs.get("perm", list(range(len(shape)))[::-1])
            moved = [p for p in perm if shape[p] != 1]
            if moved != sorted(moved):
                continue
        else:
            continue
        x, y = n.inputs[0], n.outputs[0]
        if x in g.consts:
            continue
        g.nodes[k] = Node("clss.View", [x], [y], {"shape": tuple(g.shapes[y])}, n.name, n.opset,
                          sources=n.sources)
        changed += 1
    return changed


# --- BatchNormalization ---------------------------------------------------------------

def _bn_params(g: Graph, n: Node):
    if len(n.outputs) > 1 and any(n.outputs[1:]):
        return None
    if n.attrs.get("training_mode", 0):
        return None
    vals = [_const(g, t) for t in n.inputs[1:5]]
    if any(v is None for v in vals):
        return None
    scale, bias, mean, var = (v.astype(np.float64) for v in vals)
    s = scale / np.sqrt(var + float(n.attrs.get("epsilon", 1e-5)))
    return s, bias - mean * s


def training_batchnorm(g: Graph) -> int:
    """BatchNormalization with training_mode=1 (constant scale, bias and running
    statistics): the batch statistics per channel as GlobalAveragePools of the
    channel-major layout, y = (x - mean) * scale / sqrt(var + eps) + bias, and
    the running statistics r * momentum + batch * (1 - momentum) (var: the
    population variance, as the ONNX reference and onnxruntime)."""
    changed = 0
    for n in list(g.nodes):
        if (n.op != "BatchNormalization" or not n.attrs.get("training_mode", 0)
                or any(_const(g, t) is None for t in n.inputs[1:5])):
            continue
        x = n.inputs[0]
        shape = tuple(g.shapes[x])
        if len(shape) < 2:
            continue
        c, length = shape[1], int(np.prod(shape, dtype=np.int64)) // shape[1]
        eps, mom = float(n.attrs.get("epsilon", 1e-5)), float(n.attrs.get("momentum", 0.9))
        scale, bias, r_mean, r_var = (g.consts[t].astype(np.float32) for t in n.inputs[1:5])
        per_channel = (1, c) + (1,) * (len(shape) - 2)
        new: list[Node] = []

        def node(op, inputs, out_shape, attrs=None, out=None):
            t = out or g.fresh(f"{n.outputs[0]}.{op.lower()}")
            g.shapes[t], g.dtypes[t] = tuple(out_shape), g.dtypes[x]
            new.append(Node(op, list(inputs), [t], attrs or {}, f"{n.name} ({op})", n.opset, sources=n.sources))
            return t

        def channel_mean(t):   # [N, C, ...] -> [1, C, 1, ...], the mean over all but C
            cm = node("Transpose", [t], (c, shape[0]) + shape[2:], {"perm": [1, 0] + list(range(2, len(shape)))})
            v, flat = _view(g, cm, (1, c, length), name=f"{n.name} (channel rows)", sources=n.sources)
            new.append(v)
            m = node("GlobalAveragePool", [flat], (1, c, 1))
            v, back = _view(g, m, per_channel, name=f"{n.name} (per channel)", sources=n.sources)
            new.append(v)
            return back

        mean = channel_mean(x)
        d = node("Sub", [x, mean], shape)
        var = channel_mean(node("Mul", [d, d], shape))
        std = node("Sqrt", [node("Add", [var, g.add_const(f"{n.name}.eps", np.float32(eps))], per_channel)],
                   per_channel)
        k = node("Div", [g.add_const(f"{n.name}.scale", scale.reshape(per_channel)), std], per_channel)
        node("Add", [node("Mul", [d, k], shape), g.add_const(f"{n.name}.bias", bias.reshape(per_channel))],
             shape, out=n.outputs[0])
        for out, batch, running in zip(n.outputs[1:3], (mean, var), (r_mean, r_var)):
            if not out:
                continue
            v, flat = _view(g, batch, (c,), name=f"{n.name} (statistic)", sources=n.sources)
            new.append(v)
            weighted = node("Mul", [flat, g.add_const(f"{n.name}.1-momentum", np.float32(1 - mom))], (c,))
            node("Add", [weighted, g.add_const(f"{n.name}.running", (running * mom).astype(np.float32))], (c,),
                 out=out)
        k_ = g.nodes.index(n)
        g.nodes[k_:k_ + 1] = new
        changed += 1
    return changed


def fold_batchnorm(g: Graph) -> int:
    """BatchNormalization (inference) after a Conv/ConvTranspose with constant
    weights is folded into them; elsewhere it becomes a depthwise 1x1 Conv."""
    changed = 0
    uses = g.consumers()
    prod = g.producer()
    for n in list(g.nodes):
        if n.op != "BatchNormalization":
            continue
        p = _bn_params(g, n)
        if p is None:
            continue
        s, sh = p
        x = n.inputs[0]
        c = prod.get(x)
        conv = g.nodes[c] if c is not None else None
        if (conv is not None and conv.op in ("Conv", "ConvTranspose") and _single_use(g, x, uses)
                and _const(g, conv.inputs[1]) is not None
                and (len(conv.inputs) < 3 or not conv.inputs[2] or _const(g, conv.inputs[2]) is not None)):
            w = g.consts[conv.inputs[1]].astype(np.float64)
            cout = s.shape[0]
            b = (g.consts[conv.inputs[2]].astype(np.float64) if len(conv.inputs) > 2 and conv.inputs[2]
                 else np.zeros(cout))
            if conv.op == "Conv":
                w2 = w * s.reshape((-1,) + (1,) * (w.ndim - 1))
            else:
                grp = int(conv.attrs.get("group", 1))
                cin, cog = w.shape[:2]
                w2 = (w.reshape((grp, cin // grp, cog) + w.shape[2:])
                      * s.reshape((grp, 1, cog) + (1,) * (w.ndim - 2))).reshape(w.shape)
            b2 = b * s + sh
            conv.inputs = [conv.inputs[0], g.add_const(f"{conv.name}.weight_bn", w2.astype(np.float32)),
                           g.add_const(f"{conv.name}.bias_bn", b2.astype(np.float32))]
            conv.outputs = [n.outputs[0]]
            conv.sources = conv.sources + n.sources
            g.nodes.remove(n)
            changed += 1
            uses = g.consumers()
            prod = g.producer()
            continue
        shape = g.shapes[x]
        if not 2 <= len(shape) <= 4:
            continue
        cch = shape[1]
        shape4 = tuple(shape) + (1,) * (4 - len(shape))
        w = s.astype(np.float32).reshape(cch, 1, 1, 1)
        b = sh.astype(np.float32)
        conv_attrs = {"group": cch, "kernel_shape": [1, 1], "strides": [1, 1], "pads": [0, 0, 0, 0],
                      "dilations": [1, 1]}
        k = g.nodes.index(n)
        wn, bn = g.add_const(f"{n.name}.weight", w), g.add_const(f"{n.name}.bias", b)
        if len(shape) == 4:
            g.nodes[k] = Node("Conv", [x, wn, bn], [n.outputs[0]], conv_attrs, n.name, n.opset,
                              sources=n.sources)
        else:
            v1, t1 = _view(g, x, shape4, name=f"{n.name} (4-D)", sources=n.sources)
            t2 = g.fresh(n.outputs[0])
            g.shapes[t2], g.dtypes[t2] = shape4, g.dtypes[x]
            conv = Node("Conv", [t1, wn, bn], [t2], conv_attrs, n.name, n.opset, sources=n.sources)
            v2, _ = _view(g, t2, shape, out=n.outputs[0], name=f"{n.name} (back)", sources=n.sources)
            g.nodes[k:k + 1] = [v1, conv, v2]
        changed += 1
        uses = g.consumers()
        prod = g.producer()
    return changed


# --- MatMul / Gemm -----------------------------------------------------------------

def _conv_node(g, name, opset, x, w, b, y, sources, group=1, residual=""):
    attrs = {"strides": (1, 1), "pads": (0, 0, 0, 0), "dilations": (1, 1), "group": int(group),
             "activation": "none", "alpha": 0.01}
    return Node("clss.Conv", [x, w, b or "", residual], [y], attrs, name, opset, sources=sources)


def lower_matmul(g: Graph) -> int:
    """MatMul and Gemm as 1x1 convolutions.

    With a constant right operand B [K,N] the rows of A are a batch of 1x1
    images: x = A viewed [R,K,1,1], w = B^T [N,K,1,1] (Gemm's bias C per
    column is the conv bias; a full [M,N] C is the fused residual). Otherwise
    B [K,N] is viewed as one image [1,K,1,N] and A [M,K] as the weights
    [M,K,1,1]: y[m,n] = sum_k A[m,k] B[k,n], batched over equal leading dims
    with a grouped conv."""
    changed = 0
    for n in list(g.nodes):
        if n.op not in ("MatMul", "Gemm"):
            continue
        rep = _lower_gemm(g, n) if n.op == "Gemm" else _lower_matmul(g, n)
        if rep is None:
            continue
        k = g.nodes.index(n)
        g.nodes[k:k + 1] = rep
        changed += 1
    return changed


def _lower_matmul(g: Graph, n: Node):
    a, b = n.inputs[:2]
    y = n.outputs[0]
    sa, sb, sy = g.shapes[a], g.shapes[b], g.shapes[y]
    if len(sa) < 1 or len(sb) < 1 or g.dtypes[y].kind != "f":
        return None
    a2 = sa if len(sa) > 1 else (1,) + tuple(sa)
    b2 = sb if len(sb) > 1 else tuple(sb) + (1,)
    m, kk = a2[-2:]
    k2, nn = b2[-2:]
    if kk != k2:
        return None
    batch_a, batch_b = a2[:-2], b2[:-2]
    ra = int(np.prod(batch_a, dtype=np.int64))
    rb = int(np.prod(batch_b, dtype=np.int64))
    out = []
    if ra > 1 and rb > 1 and tuple(batch_a) != tuple(batch_b):
        # Batch dims that broadcast against each other: both expanded to the common ones.
        try:
            batch = tuple(int(d) for d in np.broadcast_shapes(tuple(batch_a), tuple(batch_b)))
        except ValueError:
            return None
        a, b = (_expand(g, n, t, batch + tuple(s[-2:]), out) for t, s in ((a, a2), (b, b2)))
        batch_a = batch_b = batch
        ra = rb = int(np.prod(batch, dtype=np.int64))
    bc = _const(g, b)
    src = n.sources
    if bc is not None and rb == 1:
        wt = np.ascontiguousarray(bc.reshape(kk, nn).T.reshape(nn, kk, 1, 1)).astype(np.float32)
        v1, xa = _view(g, a, (ra * m, kk, 1, 1), name=f"{n.name} (rows)", sources=src)
        t = g.fresh(y)
        g.shapes[t], g.dtypes[t] = (ra * m, nn, 1, 1), g.dtypes[y]
        conv = _conv_node(g, n.name, n.opset, xa, g.add_const(f"{n.name}.weight", wt), "", t, src)
        v2, _ = _view(g, t, sy, out=y, name=f"{n.name} (back)", sources=src)
        return [v1, conv, v2]
    if rb == 1:
        # One image B [1,K,1,N]; all rows of A are output channels.
        v1, xb = _view(g, b, (1, kk, 1, nn), name=f"{n.name} (B)", sources=src)
        v2, wa = _view(g, a, (ra * m, kk, 1, 1), name=f"{n.name} (A)", sources=src)
        t = g.fresh(y)
        g.shapes[t], g.dtypes[t] = (1, ra * m, 1, nn), g.dtypes[y]
        conv = _conv_node(g, n.name, n.opset, xb, wa, "", t, src)
    elif ra == 1:
        v1, xb = _view(g, b, (rb, kk, 1, nn), name=f"{n.name} (B)", sources=src)
        v2, wa = _view(g, a, (m, kk, 1, 1), name=f"{n.name} (A)", sources=src)
        t = g.fresh(y)
        g.shapes[t], g.dtypes[t] = (rb, m, 1, nn), g.dtypes[y]
        conv = _conv_node(g, n.name, n.opset, xb, wa, "", t, src)
    elif tuple(batch_a) == tuple(batch_b):
        v1, xb = _view(g, b, (1, rb * kk, 1, nn), name=f"{n.name} (B)", sources=src)
        v2, wa = _view(g, a, (ra * m, kk, 1, 1), name=f"{n.name} (A)", sources=src)
        t = g.fresh(y)
        g.shapes[t], g.dtypes[t] = (1, ra * m, 1, nn), g.dtypes[y]
        conv = _conv_node(g, n.name, n.opset, xb, wa, "", t, src, group=ra)
    else:
        return None
    v3, _ = _view(g, t, sy, out=y, name=f"{n.name} (back)", sources=src)
    out += [v1, v2, conv, v3]
    return out


def _expand(g: Graph, n: Node, t: str, shape: tuple, out: list) -> str:
    """t broadcast to shape by an Expand node appended to out (t itself if it has that shape)."""
    if tuple(g.shapes[t]) == shape:
        return t
    e = g.fresh(t)
    g.shapes[e], g.dtypes[e] = shape, g.dtypes[t]
    out.append(Node("Expand", [t, g.add_const(f"{n.name}.shape", np.array(shape, np.int64))], [e], {},
                    f"{n.name} (expand {t})", n.opset, sources=n.sources))
    return e


def _lower_gemm(g: Graph, n: Node):
    a, b = n.inputs[:2]
    c = n.inputs[2] if len(n.inputs) > 2 else ""
    y = n.outputs[0]
    alpha = float(n.attrs.get("alpha", 1.0))
    beta = float(n.attrs.get("beta", 1.0))
    ta, tb = int(n.attrs.get("transA", 0)), int(n.attrs.get("transB", 0))
    bc = _const(g, b)
    if bc is None:
        return None   # left to a registered Gemm handler, if any
    src = n.sources
    out = []
    if ta:   # A^T: on the host when A is constant, else a Transpose kernel
        ac = _const(g, a)
        if ac is not None:
            a = g.add_const(f"{n.name}.a_t", np.ascontiguousarray(ac.T))
        else:
            at = g.fresh(a)
            g.shapes[at], g.dtypes[at] = tuple(g.shapes[a])[::-1], g.dtypes[a]
            out.append(Node("Transpose", [a], [at], {"perm": [1, 0]}, f"{n.name} (A^T)", n.opset,
                            sources=src))
            a = at
    w = (bc.T if tb else bc).astype(np.float64) * alpha      # [K, N]
    kk, nn = w.shape
    m = g.shapes[a][0]
    bias, residual = "", ""
    if c:
        cc = _const(g, c)
        if cc is not None:
            cc = np.broadcast_to(cc.astype(np.float64) * beta, (m, nn)) if cc.ndim else \
                np.full((m, nn), float(cc) * beta)
            if np.all(cc == cc[:1]):
                bias = g.add_const(f"{n.name}.bias", cc[0].astype(np.float32))
            else:
                residual = g.add_const(f"{n.name}.c", cc.reshape(m, nn, 1, 1).astype(np.float32))
        elif beta == 1.0 and tuple(g.shapes[c]) == (m, nn):
            rv, residual = _view(g, c, (m, nn, 1, 1), name=f"{n.name} (C)", sources=src)
        else:
            return None
    if residual and residual not in g.consts:
        out.append(rv)
    v1, xa = _view(g, a, (m, kk, 1, 1), name=f"{n.name} (rows)", sources=src)
    t = g.fresh(y)
    g.shapes[t], g.dtypes[t] = (m, nn, 1, 1), g.dtypes[y]
    wt = np.ascontiguousarray(w.T.reshape(nn, kk, 1, 1)).astype(np.float32)
    conv = _conv_node(g, n.name, n.opset, xa, g.add_const(f"{n.name}.weight", wt), bias, t, src,
                      residual=residual)
    v2, _ = _view(g, t, (m, nn), out=y, name=f"{n.name} (back)", sources=src)
    return out + [v1, conv, v2]


# --- Conv canonical form and fusion ---------------------------------------------------

def _same_pads(size, k, s, d, lower):
    out = -(-size // s)
    total = max(0, (out - 1) * s + (k - 1) * d + 1 - size)
    small = total // 2
    return (total - small, small) if lower else (small, total - small)


def _canonical_transpose(g: Graph, n: Node) -> bool:
    """1-D/2-D ConvTranspose with explicit pads -> clss.Conv(transpose=True)
    (1-D as [N,C,1,L]); auto_pad SAME_* and output_shape stay with the ONNX handler."""
    ap = n.attrs.get("auto_pad", b"NOTSET")
    ap = ap.decode() if isinstance(ap, bytes) else str(ap)
    x, w = n.inputs[0], n.inputs[1]
    nd = len(g.shapes[x]) - 2
    if nd not in (1, 2) or ap not in ("NOTSET", "VALID") or "output_shape" in n.attrs:
        return False
    pads = [0] * (2 * nd) if ap == "VALID" else list(n.attrs.get("pads", [0] * (2 * nd)))
    strides = list(n.attrs.get("strides", [1] * nd))
    dil = list(n.attrs.get("dilations", [1] * nd))
    opad = list(n.attrs.get("output_padding", [0] * nd))
    if nd == 1:
        pads, strides, dil, opad = [0, pads[0], 0, pads[1]], [1] + strides, [1] + dil, [0] + opad
    attrs = {"strides": tuple(strides), "pads": tuple(pads), "dilations": tuple(dil),
             "group": int(n.attrs.get("group", 1)), "output_padding": tuple(opad), "transpose": True,
             "activation": "none", "alpha": 0.01}
    b = n.inputs[2] if len(n.inputs) > 2 else ""
    idx = g.nodes.index(n)
    if nd == 2:
        g.nodes[idx] = Node("clss.Conv", [x, w, b, ""], list(n.outputs), attrs, n.name, n.opset,
                            sources=n.sources, unfused=[n])
        return True
    _lower_1d(g, n, idx, b, attrs, "ConvTranspose", {"output_padding": opad})
    return True


def _lower_1d(g: Graph, n: Node, idx: int, b: str, attrs: dict, op: str, extra: dict):
    """Replace the 1-D convolution `n` (at g.nodes[idx]) by a clss.Conv on [N,C,1,L] views
    of its input, weight and output; the fallback is ONNX `op` on the same 2-D views."""
    x, w, y = n.inputs[0], n.inputs[1], n.outputs[0]
    xs, ys = g.shapes[x], g.shapes[y]
    v1, x4 = _view(g, x, (xs[0], xs[1], 1, xs[2]), name=f"{n.name} (2-D)", sources=n.sources)
    vw, w4 = _weight_2d(g, n, w)
    t = g.fresh(y)
    g.shapes[t], g.dtypes[t] = (ys[0], ys[1], 1, ys[2]), g.dtypes[y]
    conv = Node("clss.Conv", [x4, w4, b, ""], [t], attrs, n.name, n.opset, sources=n.sources)
    conv.unfused = [Node(op, [x4, w4, b], [t],
                         {"strides": list(attrs["strides"]), "pads": list(attrs["pads"]),
                          "dilations": list(attrs["dilations"]), "group": attrs["group"], **extra},
                         n.name, n.opset, sources=n.sources)]
    v2, _ = _view(g, t, ys, out=y, name=f"{n.name} (back)", sources=n.sources)
    g.nodes[idx:idx + 1] = vw + [v1, conv, v2]


def _weight_2d(g: Graph, n: Node, w: str):
    """A 1-D convolution's weight [A, B, k] as [A, B, 1, k]: a constant, or a view."""
    ws = g.shapes[w]
    shape = (ws[0], ws[1], 1, ws[2])
    wc = _const(g, w)
    if wc is not None:
        return [], g.add_const(f"{n.name}.weight2d", wc.reshape(shape))
    v, w4 = _view(g, w, shape, name=f"{n.name} (weight 2-D)", sources=n.sources)
    return [v], w4


def canonical_convs(g: Graph) -> int:
    """ONNX Conv (1-D or 2-D) and ConvTranspose (2-D) -> clss.Conv with
    explicit pads (auto_pad resolved) and an activation/residual epilogue;
    1-D convolutions run as [N,C,1,L]."""
    changed = 0
    for n in list(g.nodes):
        if n.op == "ConvTranspose":
            changed += _canonical_transpose(g, n)
            continue
        if n.op != "Conv":
            continue
        x, w = n.inputs[0], n.inputs[1]
        b = n.inputs[2] if len(n.inputs) > 2 else ""
        xs, ws = g.shapes[x], g.shapes[w]
        nd = len(xs) - 2
        if nd not in (1, 2) or len(ws) != nd + 2:
            continue
        ks = list(ws[2:])
        strides = list(n.attrs.get("strides", [1] * nd))
        dil = list(n.attrs.get("dilations", [1] * nd))
        ap = n.attrs.get("auto_pad", b"NOTSET")
        ap = ap.decode() if isinstance(ap, bytes) else str(ap)
        if ap in ("SAME_UPPER", "SAME_LOWER"):
            pp = [_same_pads(xs[2 + i], ks[i], strides[i], dil[i], ap == "SAME_LOWER") for i in range(nd)]
            pads = [p[0] for p in pp] + [p[1] for p in pp]
        elif ap == "VALID":
            pads = [0] * (2 * nd)
        else:
            pads = list(n.attrs.get("pads", [0] * (2 * nd)))
        if nd == 1:
            strides, dil, pads = [1] + strides, [1] + dil, [0, pads[0], 0, pads[1]]
        attrs = {"strides": tuple(strides), "pads": tuple(pads), "dilations": tuple(dil),
                 "group": int(n.attrs.get("group", 1)), "activation": "none", "alpha": 0.01}
        idx = g.nodes.index(n)
        if nd == 2:
            g.nodes[idx] = Node("clss.Conv", [x, w, b, ""], list(n.outputs), attrs, n.name, n.opset,
                                sources=n.sources, unfused=[n])
        else:
            _lower_1d(g, n, idx, b, attrs, "Conv", {})
        changed += 1
    return changed


_LINEAR_RESIZE_MODES = ("nearest", "linear", "cubic")


def _linear_resize(g: Graph, n: Node) -> bool:
    """A Resize that is a linear map of each channel plane on its own, the same map
    for every channel (so it commutes with any channel mix): no crop-and-resize
    (its extrapolation value makes it affine), no aspect-ratio policy, N and C kept."""
    if n.op != "Resize" or len(n.inputs) < 3:
        return False
    attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in n.attrs.items()}
    if attrs.get("mode", "nearest") not in _LINEAR_RESIZE_MODES:
        return False
    if attrs.get("coordinate_transformation_mode", "half_pixel") == "tf_crop_and_resize":
        return False
    if attrs.get("keep_aspect_ratio_policy", "stretch") != "stretch":
        return False
    if any(t and t not in g.consts for t in n.inputs[1:]):
        return False
    xs, ys = g.shapes[n.inputs[0]], g.shapes[n.outputs[0]]
    return len(xs) == 4 and tuple(xs[:2]) == tuple(ys[:2])


def _resize_on(g: Graph, r: Node, x: str, out: str, channels: int) -> Node:
    """A copy of Resize r applied to x (same geometry, `channels` channels)."""
    shape = tuple(g.shapes[r.outputs[0]])
    shape = (shape[0], channels) + shape[2:]
    g.shapes[out], g.dtypes[out] = shape, g.dtypes[x]
    inputs = list(r.inputs)
    inputs[0] = x
    if len(inputs) > 3 and inputs[3]:           # sizes name the channel count too
        axes = r.attrs.get("axes")
        axes = [a % 4 for a in axes] if axes is not None else list(range(4))
        inputs[3] = g.add_const(f"{r.name}.sizes", np.array([shape[a] for a in axes], np.int64))
    return Node("Resize", inputs, [out], dict(r.attrs), f"{r.name} (after 1x1)", r.opset,
                sources=r.sources)


def conv_through_resize(g: Graph) -> int:
    """Conv1x1(Concat(Resize(e1), ..., e0)) -> Conv1x1_0(e0) + Sum_i Resize(Conv1x1_i(e_i)).

    A 1x1 convolution mixes channels and a linear Resize mixes pixels the same way
    in every channel, so the two commute, and a 1x1 convolution of a channel
    concatenation is the sum of 1x1 convolutions of the parts (its weight split by
    input channel). Exact up to float rounding. It pays where the Resize up-samples
    and the convolution has fewer outputs than the part has channels: the
    convolution then runs at the low resolution, and the Resize moves Cout
    channels instead of Cin (the CLSS decoder's 240->16 fuse: 224 channels no
    longer up-sampled to level 0). The bias, activation and the sum (as the fused
    residual, added before the activation) go to the convolution of the parts that
    are not resized, so at least one such part is required. Parts that would not
    pay stay in that convolution."""
    changed = 0
    uses = g.consumers()
    prod = g.producer()
    for n in list(g.nodes):
        if n.op != "clss.Conv" or n.inputs[3] or n.attrs.get("transpose") or n.attrs["group"] != 1:
            continue
        x, w, b = n.inputs[0], n.inputs[1], n.inputs[2]
        ws = g.shapes[w]
        if (tuple(ws[2:]) != (1, 1) or any(n.attrs["pads"]) or tuple(n.attrs["strides"]) != (1, 1)
                or w not in g.consts or (b and b not in g.consts)):
            continue
        if x not in prod or not _single_use(g, x, uses):
            continue
        cat = g.nodes[prod[x]]
        if cat.op != "Concat" or int(cat.attrs.get("axis", 0)) % 4 != 1 or len(g.shapes[x]) != 4:
            continue
        cout, out_hw = ws[0], tuple(g.shapes[x][2:])
        moved, kept, off = [], [], 0
        for t in cat.inputs:
            c = g.shapes[t][1]
            part = (t, slice(off, off + c))
            off += c
            r = g.nodes[prod[t]] if t in prod else None
            if (r is not None and _linear_resize(g, r) and _single_use(g, t, uses)
                    and cout <= c and np.prod(g.shapes[r.inputs[0]][2:]) <= np.prod(out_hw)):
                moved.append((r, part[1]))
            else:
                kept.append(part)
        if not moved or not kept:
            continue
        wc = g.consts[w]
        new, terms = [], []
        for r, sl in moved:
            e = r.inputs[0]
            t = g.fresh(f"{n.name}.part")
            g.shapes[t] = (g.shapes[e][0], cout) + tuple(g.shapes[e][2:])
            g.dtypes[t] = g.dtypes[e]
            wk = g.add_const(f"{n.name}.weight", np.ascontiguousarray(wc[:, sl]))
            new.append(Node("clss.Conv", [e, wk, "", ""], [t], dict(n.attrs, activation="none"),
                            f"{n.name} (part of {r.name})", n.opset, sources=n.sources))
            u = g.fresh(f"{n.name}.up")
            new.append(_resize_on(g, r, t, u, cout))
            terms.append(u)
        if len(terms) > 1:
            s = g.fresh(f"{n.name}.sum")
            g.shapes[s], g.dtypes[s] = g.shapes[terms[0]], g.dtypes[terms[0]]
            new.append(Node("Sum", terms, [s], {}, f"{n.name} (sum of parts)", n.opset,
                            sources=n.sources))
            terms = [s]
        if len(kept) == 1:
            x0 = kept[0][0]
        else:
            x0 = g.fresh(f"{n.name}.kept")
            g.shapes[x0] = (g.shapes[x][0], sum(sl.stop - sl.start for _, sl in kept)) + out_hw
            g.dtypes[x0] = g.dtypes[x]
            new.append(Node("Concat", [t for t, _ in kept], [x0], {"axis": 1}, f"{cat.name} (kept)",
                            cat.opset, sources=cat.sources))
        w0 = g.add_const(f"{n.name}.weight", np.ascontiguousarray(
            np.concatenate([wc[:, sl] for _, sl in kept], axis=1)))
        main = Node("clss.Conv", [x0, w0, b, terms[0]], list(n.outputs), dict(n.attrs), n.name,
                    n.opset, sources=n.sources + cat.sources)
        idx = g.nodes.index(n)
        g.nodes[idx:idx + 1] = new + [main]
        changed += 1
        uses = g.consumers()
        prod = g.producer()
    return changed


def _fuse_pairs(g: Graph, fuse) -> int:
    """Replace a node and the one consumer of its first output by fuse(n, nxt) (a
    Node, or None to leave the pair), until nothing more fuses. The fused node runs
    where the consumer ran: every input is ready there."""
    changed = 0
    again = True
    while again:
        again = False
        uses = g.consumers()
        for n in g.nodes:
            if not n.outputs or not _single_use(g, n.outputs[0], uses):
                continue
            nxt = g.nodes[uses[n.outputs[0]][0]]
            fused = fuse(n, nxt)
            if fused is None:
                continue
            g.nodes.remove(n)
            g.nodes[g.nodes.index(nxt)] = fused
            changed += 1
            again = True
            break
    return changed


def _conv_epilogue(g: Graph, n: Node, nxt: Node):
    """clss.Conv n and its one consumer nxt as one clss.Conv, where nxt is an activation
    (Relu, LeakyRelu, Sigmoid, Tanh) or an Add of a residual of the output's shape; else None."""
    if n.op != "clss.Conv":
        return None
    y = n.outputs[0]
    attrs, inputs = dict(n.attrs), list(n.inputs)
    if nxt.op in ACT_OPS and n.attrs["activation"] == "none":
        attrs["activation"] = ACT_OPS[nxt.op]
        attrs["alpha"] = float(nxt.attrs.get("alpha", 0.01))
    elif (nxt.op == "Add" and not n.inputs[3] and n.attrs["activation"] == "none"
          and len(nxt.inputs) == 2 and nxt.inputs[0] != nxt.inputs[1]):
        other = nxt.inputs[1] if nxt.inputs[0] == y else nxt.inputs[0]
        if tuple(g.shapes[other]) != tuple(g.shapes[y]) or g.dtypes[other].kind != "f":
            return None
        inputs[3] = other
    else:
        return None
    return Node("clss.Conv", inputs, list(nxt.outputs), attrs, n.name, n.opset,
                sources=n.sources + nxt.sources, unfused=[n, nxt])


def fuse_conv_epilogues(g: Graph) -> int:
    """clss.Conv followed by Add (a residual of the output's shape) and/or an
    activation (Relu, LeakyRelu, Sigmoid, Tanh) -> one clss.Conv."""
    return _activations_before_views(g) + _fuse_pairs(g, lambda n, nxt: _conv_epilogue(g, n, nxt))


def fuse_conv_depth_to_space(g: Graph) -> int:
    """clss.Conv followed by DepthToSpace (a pixel shuffle, once pixel_shuffle has named it)
    -> one clss.Conv that stores the shuffled output (attrs "d2s": [r, mode]; conv2d's
    depth_to_space, kernels/d2s_index.h), then an Add of a residual of the shuffled shape or
    an activation after it fused in as well. Run after the blocked layout (clss/model/layout.py):
    only convs whose input and output stay NCHW, the GPU's configuration. Where the row the
    device chooses for the layer stores no shuffle, the dry run runs the node's unfused parts."""
    def fuse(n, nxt):
        if (n.op != "clss.Conv" or nxt.op != "DepthToSpace" or n.inputs[3] or n.attrs.get("transpose")
                or n.attrs.get("d2s") or n.attrs.get("gated") or n.inputs[0] in g.blocked
                or n.outputs[0] in g.blocked or len(g.shapes.get(n.outputs[0], ())) != 4):
            return None
        mode = nxt.attrs.get("mode", "DCR")
        mode = mode.decode() if isinstance(mode, bytes) else str(mode)
        attrs = dict(n.attrs, d2s=[int(nxt.attrs["blocksize"]), mode.upper()])
        return Node("clss.Conv", list(n.inputs), list(nxt.outputs), attrs, n.name, n.opset,
                    sources=n.sources + nxt.sources, unfused=[n, nxt])
    changed = _fuse_pairs(g, fuse)
    if changed:
        changed += _fuse_pairs(g, lambda n, nxt: _conv_epilogue(g, n, nxt) if n.attrs.get("d2s") else None)
    return changed


_RELU_BINARY = {"Add": "add", "Sub": "sub", "Mul": "mul", "Div": "div"}


def fuse_binary_relu(g: Graph) -> int:
    """Add/Sub/Mul/Div whose float output only a Relu reads -> one clss.BinaryRelu:
    the sum (a residual not fused into a convolution, say) is not written and read
    back for the Relu. Runs after the convolution and MLP fusions, which take
    their own epilogues first."""
    def fuse(n, nxt):
        if (n.op not in _RELU_BINARY or len(n.inputs) != 2 or not all(n.inputs)
                or g.dtypes[n.outputs[0]].kind != "f" or nxt.op != "Relu"):
            return None
        return Node("clss.BinaryRelu", list(n.inputs), list(nxt.outputs), {"op": _RELU_BINARY[n.op]},
                    n.name, n.opset, sources=n.sources + nxt.sources, unfused=[n, nxt])
    return _fuse_pairs(g, fuse)


def _activations_before_views(g: Graph) -> int:
    """conv -> view -> activation becomes conv -> activation -> view (the
    activation is elementwise), so the activation can fuse into the conv."""
    changed = 0
    uses = g.consumers()
    prod = g.producer()
    for v in list(g.nodes):
        if v.op != "clss.View" or v.inputs[0] not in prod or g.nodes[prod[v.inputs[0]]].op != "clss.Conv":
            continue
        t, y = v.inputs[0], v.outputs[0]
        if not _single_use(g, t, uses) or not _single_use(g, y, uses):
            continue
        act = g.nodes[uses[y][0]]
        if act.op not in ACT_OPS:
            continue
        a_out = act.outputs[0]
        t2 = g.fresh(a_out)
        g.shapes[t2], g.dtypes[t2] = g.shapes[t], g.dtypes[t]
        act.inputs, act.outputs = [t], [t2]
        v.inputs, v.outputs = [t2], [a_out]
        v.attrs = {"shape": tuple(g.shapes[a_out])}
        i, j = g.nodes.index(v), g.nodes.index(act)
        g.nodes[i], g.nodes[j] = act, v
        changed += 1
        uses = g.consumers()
        prod = g.producer()
    return changed


def _lstm_cell_at(g: Graph, split: Node, uses: dict, prod: dict):
    """The nodes of a ConvLSTM cell's pointwise half hanging off `split`, or None:
    Split(gates, 4 equal channel parts) -> Sigmoid x 3, Tanh; c' = Add(Mul(sf, c),
    Mul(si, tanh(g))); h' = Mul(so, Tanh(c')). Returns (order, c, h', c', nodes): order
    is which Split output is i, f, o, g; the gate roles are read off the graph, not
    assumed from the Split's order."""
    if split.op != "Split" or len(split.outputs) != 4 or not all(split.outputs):
        return None
    shape = g.shapes.get(split.inputs[0])
    if shape is None or len(shape) != 4 or int(split.attrs.get("axis", 0)) % 4 != 1:
        return None
    part = (shape[0], shape[1] // 4, shape[2], shape[3])
    if shape[1] % 4 or any(tuple(g.shapes.get(t, ())) != part or g.dtypes[t].kind != "f"
                           for t in split.outputs):
        return None

    def only(t):
        return g.nodes[uses[t][0]] if _single_use(g, t, uses) else None

    acts = [only(t) for t in split.outputs]
    if any(a is None for a in acts) or sorted(a.op for a in acts) != ["Sigmoid"] * 3 + ["Tanh"]:
        return None
    kg = next(k for k, a in enumerate(acts) if a.op == "Tanh")
    m2 = only(acts[kg].outputs[0])
    if m2 is None or m2.op != "Mul":
        return None
    role = {}       # Split output index -> (its Mul, the Mul's other input)
    for k, a in enumerate(acts):
        if k != kg:
            m = only(a.outputs[0])
            if m is None or m.op != "Mul" or len(m.inputs) != 2 or m.inputs[0] == m.inputs[1]:
                return None
            role[k] = (m, m.inputs[1] if m.inputs[0] == a.outputs[0] else m.inputs[0])
    ki = next((k for k, (m, _) in role.items() if m is m2), None)
    if ki is None:
        return None
    add = only(m2.outputs[0])
    if add is None or add.op != "Add" or len(add.inputs) != 2:
        return None
    inner = set(split.outputs) | {a.outputs[0] for a in acts}
    kf = next((k for k, (m, other) in role.items() if k != ki and m.outputs[0] in add.inputs
               and other not in inner), None)
    if kf is None or add.inputs[0] == add.inputs[1]:
        return None
    m1, c = role[kf]
    c_new = add.outputs[0]
    tanh_c = next((g.nodes[j] for j in uses.get(c_new, ()) if g.nodes[j].op == "Tanh"), None)
    if tanh_c is None:
        return None
    ko = next(k for k in role if k not in (ki, kf))
    m3, tc = role[ko]
    if tc != tanh_c.outputs[0] or not _single_use(g, tc, uses):
        return None
    if tuple(g.shapes.get(c, ())) != part or g.dtypes[c].kind != "f" or c in split.outputs:
        return None
    # c must exist where the fused node runs (where c' was made): a graph input, a
    # constant, or a tensor made before the Split
    pc = prod.get(c)
    if pc is not None and pc > g.nodes.index(split):
        return None
    nodes = [split, *acts, m1, m2, add, tanh_c, m3]
    return (ki, kf, ko, kg), c, m3.outputs[0], c_new, nodes


def fuse_lstm_cell(g: Graph) -> int:
    """The pointwise half of a ConvLSTM cell (ten nodes: a Split of the gates, three
    Sigmoid, two Tanh, three Mul, an Add) -> one clss.LSTMCell (kernels/lstm.cl), with
    the same arithmetic. It runs where c' was made. Not in PASSES: clss.Model applies
    it where its fast path (model.lstm_cell) holds."""
    def rewrite(split, m):
        order, c, h_new, c_new, nodes = m
        fused = Node("clss.LSTMCell", [split.inputs[0], c], [h_new, c_new], {"order": order},
                     split.name, split.opset, sources=[s for n in nodes for s in n.sources],
                     unfused=list(nodes))
        at = nodes[8]           # the Add that made c'
        g.nodes[g.nodes.index(at)] = fused
        drop = {id(n) for n in nodes if n is not at}
        g.nodes = [n for n in g.nodes if id(n) not in drop]
    return _rewrite_until_fixed(g, lambda n, uses, prod: _lstm_cell_at(g, n, uses, prod), rewrite)


def _rewrite_until_fixed(g: Graph, match, rewrite) -> int:
    """rewrite(node, m) at the first node where m = match(node, consumers, producers) is not
    None, again on the changed graph, until nothing matches; returns the rewrites."""
    changed = 0
    while True:
        uses, prod = g.consumers(), g.producer()
        hit = next(((n, m) for n in g.nodes for m in (match(n, uses, prod),) if m is not None), None)
        if hit is None:
            return changed
        rewrite(*hit)
        changed += 1


def lstm_cell_graph(x_shape, channels: int, *, conv: bool = False, order=(0, 1, 2, 3)):
    """A ConvLSTM cell's pointwise half as the ONNX nodes fuse_lstm_cell fuses (the
    fast path's self-check graph; the twin of clss/verify/cases/lstm.py): inputs x (the
    gates [N, 4C, H, W], or with conv=True the input of a seeded 3x3 convolution that
    makes them) and c [N, C, H, W]; outputs h and c_out. order: the Split output that
    holds i, f, o and g."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from ..ops.base import rng
    n, cx, h, w = (int(v) for v in x_shape)
    nodes, inits = [], []
    gates = "x"
    if conv:
        g = rng("lstm cell graph weights", tuple(x_shape), channels)
        inits = [numpy_helper.from_array((g.standard_normal((4 * channels, cx, 3, 3)) * 0.3).astype(np.float32),
                                         "w"),
                 numpy_helper.from_array((g.standard_normal(4 * channels) * 0.1).astype(np.float32), "b")]
        nodes.append(helper.make_node("Conv", ["x", "w", "b"], ["gates"], kernel_shape=[3, 3], pads=[1, 1, 1, 1]))
        gates = "gates"
    inits.append(numpy_helper.from_array(np.full(4, channels, np.int64), "split"))
    roles = "ifog"
    parts = [f"gate_{roles[list(order).index(k)]}" for k in range(4)]
    nodes += [helper.make_node("Split", [gates, "split"], parts, axis=1),
              helper.make_node("Sigmoid", ["gate_i"], ["si"]),
              helper.make_node("Sigmoid", ["gate_f"], ["sf"]),
              helper.make_node("Sigmoid", ["gate_o"], ["so"]),
              helper.make_node("Tanh", ["gate_g"], ["tg"]),
              helper.make_node("Mul", ["sf", "c"], ["fc"]),
              helper.make_node("Mul", ["tg", "si"], ["ig"]),
              helper.make_node("Add", ["fc", "ig"], ["c_out"]),
              helper.make_node("Tanh", ["c_out"], ["tc"]),
              helper.make_node("Mul", ["so", "tc"], ["h"])]
    vi = helper.make_tensor_value_info
    graph = helper.make_graph(nodes, "lstm_cell", [vi("x", TensorProto.FLOAT, [n, cx, h, w]),
                                                   vi("c", TensorProto.FLOAT, [n, channels, h, w])],
                              [vi("h", TensorProto.FLOAT, [n, channels, h, w]),
                               vi("c_out", TensorProto.FLOAT, [n, channels, h, w])], inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    return m


def _is_pointwise(g: Graph, n: Node) -> bool:
    if n.op != "clss.Conv" or n.inputs[3] or n.attrs["group"] != 1 or n.attrs.get("transpose"):
        return False
    ws = g.shapes[n.inputs[1]]
    return (tuple(ws[2:]) == (1, 1) and tuple(n.attrs["strides"]) == (1, 1)
            and not any(n.attrs["pads"]) and n.inputs[1] in g.consts
            and (not n.inputs[2] or n.inputs[2] in g.consts))


def fuse_mlp(g: Graph) -> int:
    """Chains of pointwise (1x1, stride 1, no padding) convolutions, each with
    its activation, feeding only the next: one clss.MLP, the intermediate
    activations never leave registers."""
    changed = 0
    uses = g.consumers()
    prod = g.producer()
    i = 0
    while i < len(g.nodes):
        n = g.nodes[i]
        if not _is_pointwise(g, n) or (n.inputs[0] in prod and _chain_link(g, g.nodes[prod[n.inputs[0]]],
                                                                           n.inputs[0], uses)):
            i += 1
            continue
        chain = [n]
        while True:
            y = chain[-1].outputs[0]
            if not _single_use(g, y, uses):
                break
            nxt = g.nodes[uses[y][0]]
            if not _is_pointwise(g, nxt) or nxt.inputs[0] != y:
                break
            chain.append(nxt)
        if len(chain) < 2:
            i += 1
            continue
        layers = []
        for c in chain:
            w = g.consts[c.inputs[1]]
            b = g.consts[c.inputs[2]] if c.inputs[2] else None
            layers.append((w.reshape(w.shape[0], w.shape[1]), b, c.attrs["activation"],
                           float(c.attrs.get("alpha", 0.01))))
        node = Node("clss.MLP", [chain[0].inputs[0]], list(chain[-1].outputs), {"layers": layers},
                    chain[-1].name, chain[-1].opset,
                    sources=[s for c in chain for s in c.sources], unfused=list(chain))
        last = g.nodes.index(chain[-1])
        g.nodes[last] = node
        for c in chain[:-1]:
            g.nodes.remove(c)
        changed += 1
        uses = g.consumers()
        prod = g.producer()
        i = 0
    return changed


def _chain_link(g, p, t, uses):
    """p would have continued a chain into t (so t's consumer is not a chain head)."""
    return _is_pointwise(g, p) and _single_use(g, t, uses)


def maxpool_values_only(g: Graph) -> int:
    """MaxPool's Indices output, when unread, is not computed."""
    changed = 0
    uses = g.consumers()
    for k, n in enumerate(g.nodes):
        if n.op != "MaxPool" or int(n.attrs.get("storage_order", 0)):
            continue
        if len(n.outputs) > 1 and n.outputs[1] and (n.outputs[1] in uses or n.outputs[1] in g.outputs):
            continue
        g.nodes[k] = Node("clss.MaxPool", n.inputs[:1], n.outputs[:1], n.attrs, n.name, n.opset,
                          sources=n.sources, unfused=[n])
        changed += 1
    return changed


# --- cleanup -----------------------------------------------------------------------

def remove_dead(g: Graph) -> int:
    """Nodes none of whose outputs is read or is a graph output."""
    changed = 0
    while True:
        uses = g.consumers()
        live = [n for n in g.nodes if any(t and (t in uses or t in g.outputs) for t in n.outputs)]
        if len(live) == len(g.nodes):
            return changed
        changed += len(g.nodes) - len(live)
        g.nodes = live


PASSES = [
    ("opsets", normalise_opsets),
    ("identity", remove_identities),
    ("bool_casts", bool_casts),
    ("pixel_shuffle", pixel_shuffle),
    ("views", lower_views),
    ("batchnorm", fold_batchnorm),
    ("batchnorm_training", training_batchnorm),
    ("float_exponents", float_exponents),
    ("layer_norm", fuse_layer_norm),
    ("layer_norm_stats", layer_norm_stats),
    ("matmul", lower_matmul),
    ("conv_canonical", canonical_convs),
    ("conv_resize", conv_through_resize),
    ("conv_epilogue", fuse_conv_epilogues),
    ("mlp", fuse_mlp),
    ("binary_relu", fuse_binary_relu),
    ("maxpool", maxpool_values_only),
    ("dead", remove_dead),
]


# --- gated convolutions (NSRD's gated conv: act(conv_f(x)) * sigmoid(conv_g(x))) ----------

def _gated_at(g: Graph, m: Node, uses: dict, prod: dict, block: int):
    """(feature conv, gate conv) where Mul m multiplies two clss.Conv outputs of one input
    x with the same geometry, the gate's activation a sigmoid, both read only by m, C
    (each conv's outputs) a whole number of blocks; else None."""
    if m.op != "Mul" or len(m.inputs) != 2 or m.inputs[0] == m.inputs[1] or g.dtypes[m.outputs[0]].kind != "f":
        return None
    convs = [g.nodes[prod[t]] if t in prod else None for t in m.inputs]
    if any(c is None or c.op != "clss.Conv" or c.attrs.get("transpose") or c.inputs[3] or c.attrs["group"] != 1
           or c.inputs[1] not in g.consts or (c.inputs[2] and c.inputs[2] not in g.consts)
           or not _single_use(g, c.outputs[0], uses) for c in convs):
        return None
    a, b = convs
    if b.attrs["activation"] != "sigmoid":
        a, b = b, a
    if b.attrs["activation"] != "sigmoid" or a.inputs[0] != b.inputs[0] or bool(a.inputs[2]) != bool(b.inputs[2]):
        return None
    if any(tuple(a.attrs[k]) != tuple(b.attrs[k]) for k in ("strides", "pads", "dilations")):
        return None
    wa, wb = g.consts[a.inputs[1]], g.consts[b.inputs[1]]
    if wa.shape != wb.shape or wa.ndim != 4 or wa.shape[0] % block or wa.shape[2] * wa.shape[3] < 2 \
            or wa.shape[1] < 8:
        return None
    return a, b


def fuse_gated_conv(g: Graph, block: int) -> int:
    """Mul(act(conv_f(x)), sigmoid(conv_g(x))) -> one clss.Conv with attrs gated: its
    weights are conv_f's and conv_g's output channels interleaved in blocks of `block`
    (the blocked conv's output vector), so a work-item holds a feature vector and its
    gate and writes their product (kernels/conv.cl -DGATED): one pass over x instead of
    two, and no Mul kernel. Not in PASSES: clss.Model applies it where its fast path
    (model.gated_conv) and the blocked conv hold."""
    def rewrite(m, pair):
        a, b = pair
        c = g.consts[a.inputs[1]].shape[0]
        order = np.concatenate([np.r_[j:j + block, c + j:c + j + block] for j in range(0, c, block)])
        w = np.concatenate([g.consts[a.inputs[1]], g.consts[b.inputs[1]]])[order]
        wn = g.fresh(f"{a.name}_gated_w")
        g.consts[wn], g.shapes[wn], g.dtypes[wn] = w, w.shape, w.dtype
        bn = ""
        if a.inputs[2]:
            bias = np.concatenate([g.consts[a.inputs[2]], g.consts[b.inputs[2]]])[order]
            bn = g.fresh(f"{a.name}_gated_b")
            g.consts[bn], g.shapes[bn], g.dtypes[bn] = bias, bias.shape, bias.dtype
        fused = Node("clss.Conv", [a.inputs[0], wn, bn, ""], list(m.outputs), dict(a.attrs, gated=True), a.name,
                     a.opset, sources=a.sources + b.sources + m.sources, unfused=[a, b, m])
        g.nodes[g.nodes.index(m)] = fused
        g.nodes = [n for n in g.nodes if n is not a and n is not b]
    return _rewrite_until_fixed(g, lambda m, uses, prod: _gated_at(g, m, uses, prod, block), rewrite)
