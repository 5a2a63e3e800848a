"""ONNX file -> a static graph: checked, opset-validated, every shape resolved,
constants folded. What clss.Model's passes and planner work on.

Everything here happens on the host before any device allocation, so bad models
(malformed, symbolic shapes without input_shapes, absurd tensor sizes) are
refused with a message before the device is touched.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import onnx
from onnx import helper, numpy_helper

from ..errors import UserError

# Opsets 22-25 only widened the type constraints of the ops clss runs (bfloat16,
# float8, float4, int2; checked with onnx.defs.get_schema), so their float32/float16
# semantics are those of 21. Past 25, a node is accepted while its op's schema
# is still one of these (see check_opset).
MIN_OPSET, MAX_OPSET = 11, 25
# Kernels index with 32-bit ints: a tensor past this many elements is refused.
MAX_ELEMENTS = 2**31 - 1
# Folding evaluates on the host; a folded constant past this is a model we refuse
# rather than fill host memory with.
MAX_FOLD_ELEMENTS = 2**26

FLOAT_TYPES = (onnx.TensorProto.FLOAT, onnx.TensorProto.FLOAT16)
# ONNX ops with no handler of their name that the passes (passes.py) rewrite into ones that
# have (some only in some forms: the dry run names the rest unsupported).
LOWERED_OPS = frozenset({"Identity", "Dropout", "Cast", "CastLike", "Reshape", "Flatten", "Squeeze",
                         "Unsqueeze", "BatchNormalization", "Gemm", "MatMul", "Constant"})


# How `clss info` / `clss run` users give input_shapes.
_FLAG_SHAPE = "the shape given (--input-shape, or the --input array) for"


class ModelError(UserError):
    """A model clss cannot load: malformed, unsupported opset, unresolved shapes."""


class InputError(UserError):
    """A run's inputs do not match the model: name, shape or dtype."""


class UnsupportedModelError(ModelError):
    """One or more nodes clss cannot run; ``nodes`` lists (name, op_type, opset, reason).
    ``note``: what else went wrong because of them (e.g. a shape they leave unknown)."""

    def __init__(self, nodes: list[tuple[str, str, int, str]], note: str = ""):
        self.nodes = nodes
        lines = [f"  - {n!r} ({op}, opset {ver}): {why}" for n, op, ver, why in nodes]
        super().__init__(f"{len(nodes)} node(s) of this model are not supported by clss:\n"
                         + "\n".join(lines) + (f"\n{note}" if note else ""))


@dataclass
class Node:
    """One operation. ``op`` is an ONNX op type (run by the registered handler)
    or an internal "clss.*" op. ``sources`` names the ONNX nodes it stands for
    ((name, op_type) pairs); ``unfused`` the nodes to fall back to when a fused
    op turns out to be unsupported."""
    op: str
    inputs: list[str]
    outputs: list[str]
    attrs: dict
    name: str
    opset: int
    domain: str = ""
    sources: list = field(default_factory=list)
    unfused: list | None = None

    def __post_init__(self):
        if not self.sources:
            self.sources = [(self.name, self.op)]

    @property
    def source_ops(self) -> str:
        return "+".join(op for _, op in self.sources)


@dataclass
class Graph:
    nodes: list[Node]
    inputs: list[str]           # runtime graph inputs, in model order
    outputs: list[str]
    shapes: dict[str, tuple]    # every tensor, static
    dtypes: dict[str, np.dtype]
    consts: dict[str, np.ndarray]
    opset: int
    elem_types: dict[str, int] = field(default_factory=dict)  # graph inputs/outputs, ONNX types
    # tensors kept in the channel-blocked layout, and their device shapes (clss/model/layout.py)
    blocked: dict[str, tuple] = field(default_factory=dict)
    _counter: int = 0

    def fresh(self, stem: str) -> str:
        """A tensor name not used anywhere yet."""
        while True:
            self._counter += 1
            name = f"{stem}__clss{self._counter}"
            if name not in self.shapes and name not in self.consts:
                return name

    def consumers(self) -> dict[str, list[int]]:
        use: dict[str, list[int]] = {}
        for i, n in enumerate(self.nodes):
            for t in n.inputs:
                if t:
                    use.setdefault(t, []).append(i)
        return use

    def producer(self) -> dict[str, int]:
        return {t: i for i, n in enumerate(self.nodes) for t in n.outputs if t}

    def add_const(self, stem: str, value: np.ndarray) -> str:
        name = self.fresh(stem)
        self.consts[name] = value
        self.shapes[name] = tuple(value.shape)
        self.dtypes[name] = value.dtype
        return name


# --- loading and validation -------------------------------------------------------

def load_proto(model) -> onnx.ModelProto:
    """A private copy of the model from a path, bytes or ModelProto."""
    if isinstance(model, onnx.ModelProto):
        m = onnx.ModelProto()
        m.CopyFrom(model)
        return m
    if isinstance(model, (bytes, bytearray, memoryview)):
        try:
            return onnx.load_from_string(bytes(model))
        except Exception as e:
            raise ModelError(f"not an ONNX model: {e}") from None
    if isinstance(model, (str, os.PathLike)):
        path = os.fspath(model)
        if not os.path.isfile(path):
            raise ModelError(f"no such model file: {path}")
        try:
            return onnx.load(path)
        except Exception as e:
            # protobuf's text-format parser explains over several lines; the first says it.
            raise ModelError(f"{path}: not an ONNX model: {str(e).splitlines()[0]}") from None
    raise TypeError(f"model must be a path, bytes or onnx.ModelProto, got {type(model).__name__}")


def sort_nodes(g: onnx.GraphProto) -> None:
    """Nodes in an order where each comes after the producers of its inputs.
    onnxruntime takes a graph in any order; the checker, the folding and the
    passes want it sorted. Stable (a sorted graph stays as it is); a node
    whose input nothing produces stays last, for the checker to name."""
    avail = {t.name for t in g.input} | {t.name for t in g.initializer} | {""}
    avail |= {t.values.name for t in g.sparse_initializer}
    order, pending = [], list(range(len(g.node)))
    while pending:
        rest = []
        for k in pending:
            if all(t in avail for t in g.node[k].input):
                order.append(k)
                avail.update(g.node[k].output)
            else:
                rest.append(k)
        if len(rest) == len(pending):
            break
        pending = rest
    order += pending
    if order != sorted(order):
        nodes = []
        for k in order:   # copies: deleting from a repeated field may free its elements
            nodes.append(onnx.NodeProto())
            nodes[-1].CopyFrom(g.node[k])
        del g.node[:]
        g.node.extend(nodes)


def check(m: onnx.ModelProto) -> int:
    """onnx's checker and the opset range; returns the default-domain opset."""
    try:
        onnx.checker.check_model(_checkable(m))
    except onnx.checker.ValidationError as e:
        raise ModelError(f"malformed model (onnx checker): {e}") from None
    opsets = {o.domain or "": o.version for o in m.opset_import}
    opset = opsets.get("", opsets.get("ai.onnx"))
    if opset is None:
        raise ModelError("model imports no default-domain (ai.onnx) opset")
    check_opset(m, opset)
    return opset


def _checkable(m: onnx.ModelProto) -> onnx.ModelProto:
    """The model as the checker wants it, where onnxruntime wants less:
    * the checker refuses IR versions past its own (onnx 1.22: 13; onnx >= 1.23
      writes 14, which onnxruntime 1.32 runs): it sees the model at its IR;
    * its main-graph rule requires a shape on every graph output; onnxruntime
      and exporters do not, and shape inference (at load, in _infer) gives the
      real one: it sees the shapeless outputs with the inferred shape."""
    kinds = [o.type.WhichOneof("value") for o in m.graph.output]
    fill = not any(k not in (None, "tensor_type") for k in kinds) and not all(
        k and o.type.tensor_type.HasField("shape") for k, o in zip(kinds, m.graph.output))
    if not fill and m.ir_version <= onnx.IR_VERSION:
        return m   # (non-tensor outputs are refused later, by name)
    probe = onnx.ModelProto()
    probe.CopyFrom(m)
    probe.ir_version = min(probe.ir_version, onnx.IR_VERSION)
    if not fill:
        return probe
    for o in probe.graph.output:
        o.type.tensor_type.SetInParent()   # an output with no type at all: inference fills it
    try:
        fill_output_shapes(probe)
    except Exception:   # inference itself fails: the checker, then _infer, say why
        pass
    return probe


def fill_output_shapes(model: onnx.ModelProto) -> None:
    """Graph outputs are declared without a shape; take the inferred one
    (the checker wants a shape field, and a wrong guess would be worse)."""
    inferred = onnx.shape_inference.infer_shapes(model)
    known = {v.name: v for v in list(inferred.graph.value_info) + list(inferred.graph.output)}
    for out in model.graph.output:
        v = known.get(out.name)
        if v is not None and v.type.tensor_type.HasField("shape"):
            out.type.CopyFrom(v.type)
        elif not out.type.tensor_type.HasField("shape"):
            out.type.tensor_type.shape.SetInParent()  # unknown rank would fail the checker


def check_opset(m: onnx.ModelProto, opset: int) -> None:
    """Opsets MIN_OPSET..MAX_OPSET; past MAX_OPSET, every default-domain node
    whose op's schema changed after MAX_OPSET is refused by name."""
    if opset < MIN_OPSET:
        raise ModelError(f"model uses ONNX opset {opset}; clss supports opsets {MIN_OPSET} to {MAX_OPSET} "
                         f"(onnx.version_converter.convert_version can move it into range)")
    if opset <= MAX_OPSET:
        return
    newer = []
    for k, n in enumerate(m.graph.node):
        if n.domain not in ("", "ai.onnx"):
            continue
        try:
            since = onnx.defs.get_schema(n.op_type, opset).since_version
        except Exception:   # an op onnx does not know: the dry run names it unsupported
            continue
        if since > MAX_OPSET:
            newer.append(f"{n.name or f'#{k}'!r} ({n.op_type}, changed at opset {since})")
    if newer:
        raise ModelError(f"model uses ONNX opset {opset}; clss knows opsets {MIN_OPSET} to {MAX_OPSET}, "
                         f"and these nodes' ops changed after {MAX_OPSET}: {', '.join(newer)} "
                         f"(onnx.version_converter.convert_version can move the model to {MAX_OPSET})")


def _dims(vi: onnx.ValueInfoProto):
    t = vi.type.tensor_type
    if not t.HasField("shape"):
        return None
    return [d.dim_value if d.HasField("dim_value") else (d.dim_param or "?") for d in t.shape.dim]


def parse_shape(spec) -> tuple[int, ...]:
    """(1, 3, 64, 64), [1, 3, 64, 64] or "1x3x64x64"."""
    if isinstance(spec, str):
        try:
            return tuple(int(s) for s in spec.lower().replace(",", "x").split("x") if s.strip())
        except ValueError:
            raise ModelError(f"cannot parse shape {spec!r}; write it like 1x3x64x64") from None
    return tuple(int(s) for s in spec)


def resolve_inputs(m: onnx.ModelProto, input_shapes: dict | None) -> dict[str, tuple]:
    """Concrete shape of every runtime input; writes them into the model."""
    g = m.graph
    inits = {t.name for t in g.initializer}
    runtime = [i for i in g.input if i.name not in inits]
    names = [i.name for i in runtime]
    given = {k: parse_shape(v) for k, v in (input_shapes or {}).items()}
    unknown = sorted(set(given) - set(names))
    if unknown:
        why = (f"names {', '.join(map(repr, unknown))}, which the model does not have; its inputs "
               f"are {', '.join(map(repr, names))}")
        raise ModelError(f"input_shapes {why}", cli=f"--input-shape / --input {why}")
    out = {}
    for vi in runtime:
        if vi.type.WhichOneof("value") != "tensor_type":
            raise ModelError(f"input {vi.name!r} is not a tensor; clss runs tensor inputs only")
        dims = _dims(vi)
        if vi.name in given:
            shape = given[vi.name]
            if dims is not None:
                if len(dims) != len(shape):
                    why = f"rank {len(shape)} {list(shape)}; the model declares rank {len(dims)} {dims}"
                    raise ModelError(f"input_shapes gives {vi.name!r} {why}", cli=f"{_FLAG_SHAPE} "
                                     f"{vi.name!r} has {why}")
                for ax, (d, s) in enumerate(zip(dims, shape)):
                    if isinstance(d, int) and d != s:
                        why = f"size {s} on axis {ax}; the model fixes it to {d} (shape {dims})"
                        raise ModelError(f"input_shapes gives {vi.name!r} {why}", cli=f"{_FLAG_SHAPE} "
                                         f"{vi.name!r} has {why}")
            if any(s < 0 for s in shape):
                raise ModelError(f"input_shapes gives {vi.name!r} a negative size: {list(shape)}",
                                 cli=f"{_FLAG_SHAPE} {vi.name!r} has a negative size: {list(shape)}")
        else:
            if dims is None:
                raise ModelError(f"input {vi.name!r} has no declared shape; pass "
                                 f"input_shapes={{{vi.name!r}: (...)}} at load",
                                 cli=f"input {vi.name!r} has no declared shape; give it with "
                                     f"--input-shape {vi.name}=1x3x64x64 (its real sizes)")
            sym = [(ax, d) for ax, d in enumerate(dims) if not isinstance(d, int)]
            if sym:
                ax, d = sym[0]
                what = f"input {vi.name!r} has symbolic dimension {d!r} (axis {ax}) in shape {dims}"
                example = tuple(x if isinstance(x, int) else 64 for x in dims)
                raise ModelError(
                    f"{what}; clss resolves shapes at load: pass input_shapes={{{vi.name!r}: (...)}}, "
                    f"e.g. clss.Model(path, input_shapes={{{vi.name!r}: {example}}})",
                    cli=f"{what}; give its sizes with --input-shape, e.g. --input-shape "
                        f"{vi.name}={'x'.join(map(str, example))}")
            shape = tuple(dims)
        out[vi.name] = tuple(int(s) for s in shape)
        tt = vi.type.tensor_type
        tt.shape.Clear()
        for s in shape:
            tt.shape.dim.add().dim_value = int(s)
    # A graph output that is an input is that input: a shapeless declaration of it
    # would otherwise hide the input's shape from shape inference downstream.
    for o in g.output:
        for vi in runtime:
            if o.name == vi.name:
                o.type.CopyFrom(vi.type)
    return out


# Ops whose output has their first input's shape and type, where onnx's shape inference
# leaves it unknown (GroupNormalization-21 is a function op that onnx 1.22 does not infer).
SAME_SHAPE_OPS = frozenset({"GroupNormalization"})


def _infer(m: onnx.ModelProto, opset: int) -> onnx.ModelProto:
    del m.graph.value_info[:]
    try:
        out = onnx.shape_inference.infer_shapes(m, check_type=True, strict_mode=True, data_prop=True)
        for _ in range(16):     # each round fills what the last one left unknown, then infers on
            if not _fill_same_shape(m, out):
                break
            out = onnx.shape_inference.infer_shapes(m, check_type=True, strict_mode=True, data_prop=True)
        del m.graph.value_info[:]
        return out
    except Exception as e:  # InferenceError and friends
        refuse_unknown_ops(m, opset, f"(also: shape inference failed: {e})")
        raise ModelError(f"shape inference failed: {e}") from None


def _fill_same_shape(m: onnx.ModelProto, inferred: onnx.ModelProto) -> bool:
    """Give the outputs of SAME_SHAPE_OPS nodes that inference left unknown (or that a graph
    output declares with another shape, e.g. rank 0 for "unknown") their input's type, in
    m (value infos, graph outputs). Whether anything changed."""
    g = inferred.graph
    known = {vi.name: vi for vi in list(g.input) + list(g.value_info) + list(g.output)
             if vi.type.tensor_type.HasField("shape")}
    outputs = {o.name: o for o in m.graph.output}
    changed = False
    for n in g.node:
        if n.op_type not in SAME_SHAPE_OPS or not n.output or n.input[0] not in known:
            continue
        src, y = known[n.input[0]], n.output[0]
        have = known.get(y)
        if have is not None and have.type.tensor_type.shape == src.type.tensor_type.shape:
            continue
        if y in outputs:
            outputs[y].type.CopyFrom(src.type)
        else:
            vi = onnx.ValueInfoProto()
            vi.CopyFrom(src)
            vi.name = y
            m.graph.value_info.append(vi)
        changed = True
    return changed


# --- ops clss has no kernel for ---------------------------------------------------

NO_KERNEL = "no clss kernel for this op type"


def custom_domain_reason(domain: str) -> str:
    return f"custom domain {domain!r}: clss runs the default ONNX domain only"


def refuse_unknown_ops(m: onnx.ModelProto, opset: int, note: str) -> None:
    """Raise UnsupportedModelError naming every node whose op clss can neither
    run nor rewrite, when there is any. Called where such a node shows up as
    something else (a shape inference cannot resolve, say), so that the user
    hears first what is unsupported; ``note`` tells what else went wrong."""
    bad = unknown_ops(m, opset)
    if bad:
        raise UnsupportedModelError(bad, note)


def unknown_ops(m: onnx.ModelProto, opset: int, known: set | None = None) -> list[tuple[str, str, int, str]]:
    """(name, op_type, opset, reason) of every node whose op clss can neither run nor rewrite.
    ``known``: graph inputs whose values will be known when the model is planned (value
    inputs): nodes computable from them and constants fold then and are not named."""
    from ..ops import ONNX_HANDLERS, load_all
    load_all()   # the handlers register when their family is imported
    opsets = {o.domain or "": o.version for o in m.opset_import}
    folds = _folding_nodes(m, known) if known is not None else set()
    bad = []
    for k, n in enumerate(m.graph.node):
        if k in folds:
            continue
        name = n.name or f"#{k} {n.op_type}"
        if n.domain not in ("", "ai.onnx"):
            bad.append((name, n.op_type, opsets.get(n.domain, opset), custom_domain_reason(n.domain)))
        elif n.op_type not in ONNX_HANDLERS and n.op_type not in LOWERED_OPS:
            bad.append((name, n.op_type, opset, NO_KERNEL))
    return bad


def _folding_nodes(m: onnx.ModelProto, known: set) -> set[int]:
    """Indices of the nodes constant folding will compute once the graph inputs ``known``
    have values (fold_constants' rule: Constant, Shape/Size, and default-domain nodes whose
    inputs are all known)."""
    g = m.graph
    have = set(known) | {t.name for t in g.initializer} | {t.values.name for t in g.sparse_initializer}
    out = set()
    for k, n in enumerate(g.node):
        if n.domain not in ("", "ai.onnx"):
            continue
        if (n.op_type in ("Constant", "Shape", "Size")
                or (n.op_type not in NO_FOLD and n.input and all(not t or t in have for t in n.input))):
            out.add(k)
            have.update(t for t in n.output if t)
    return out


def _collect(m: onnx.ModelProto):
    shapes, types = {}, {}
    g = m.graph
    for vi in list(g.input) + list(g.value_info) + list(g.output):
        if vi.type.WhichOneof("value") != "tensor_type":
            continue
        tt = vi.type.tensor_type
        if tt.elem_type:
            types[vi.name] = tt.elem_type
        dims = _dims(vi)
        if dims is not None and all(isinstance(d, int) for d in dims):
            shapes[vi.name] = tuple(dims)
    for t in g.initializer:
        shapes[t.name] = tuple(t.dims)
        types[t.name] = t.data_type
    return shapes, types


def _np_dtype(elem_type: int) -> np.dtype:
    return np.dtype(helper.tensor_dtype_to_np_dtype(elem_type))


def _nbytes_limit(shape, dtype, name, what, max_alloc):
    n = int(np.prod(shape, dtype=object)) if len(shape) else 1
    if n > MAX_ELEMENTS:
        raise ModelError(f"{what} {name!r} would have shape {list(shape)} = {n:,} elements; clss refuses "
                         f"tensors over 2^31-1 elements (no allocation was made)")
    size = n * dtype.itemsize
    if max_alloc and size > max_alloc:
        raise ModelError(f"{what} {name!r} of shape {list(shape)} needs {size / 2**20:,.1f} MiB, over the "
                         f"device's max allocation {max_alloc / 2**20:,.0f} MiB (no allocation was made)")


def check_sizes(shapes: dict, types: dict, max_alloc: int | None, storage_itemsize: int = 4,
                producers: dict | None = None) -> None:
    for name, shape in shapes.items():
        et = types.get(name)
        dt = np.dtype(np.float32) if et in FLOAT_TYPES or et is None else _np_dtype(et)
        if dt.kind == "f":
            dt = np.dtype(f"f{storage_itemsize}")
        what = "tensor" if not producers or name not in producers else \
            f"output of {producers[name]}; tensor"
        _nbytes_limit(shape, dt, name, what, max_alloc)


# --- constant folding -------------------------------------------------------------

# Ops never folded: no inputs to be constant, or randomness, or subgraphs.
NO_FOLD = {"RandomNormal", "RandomUniform", "RandomNormalLike", "RandomUniformLike", "Multinomial",
           "Bernoulli", "If", "Loop", "Scan", "SequenceConstruct", "SequenceEmpty"}


def _fold_guard(node, vals):
    """Refuse folds whose host result would be absurd, judged from the inputs."""
    op = node.op_type
    n = None
    if op == "ConstantOfShape":
        n = int(np.prod(vals[0].astype(object))) if vals[0].size else 1
    elif op == "Range":
        start, limit, delta = (float(v) for v in vals[:3])
        n = max(int(np.ceil((limit - start) / delta)), 0) if delta else MAX_ELEMENTS + 1
    elif op == "Expand":
        n = int(np.prod(np.broadcast_shapes(vals[0].shape, tuple(int(v) for v in vals[1])), dtype=object))
    elif op == "Tile":
        n = int(np.prod(np.array(vals[0].shape, dtype=object) * vals[1].astype(object)))
    if n is not None and n > MAX_FOLD_ELEMENTS:
        raise ModelError(f"node {node.name or op!r} ({op}) would fold to a constant of {n:,} elements; "
                         "clss refuses it (no allocation was made)")


def _evaluate(node: onnx.NodeProto, vals, opset: int) -> list[np.ndarray]:
    from onnx.reference import ReferenceEvaluator
    names = [f"i{k}" if t else "" for k, t in enumerate(node.input)]
    n2 = onnx.NodeProto()
    n2.CopyFrom(node)
    del n2.input[:]
    n2.input.extend(names)
    feeds = {nm: v for nm, v in zip(names, vals) if nm}
    try:
        outs = ReferenceEvaluator(n2, opsets={"": opset}).run(None, feeds)
    except Exception as e:
        raise ModelError(f"constant folding of node {node.name or node.op_type!r} ({node.op_type}) "
                         f"failed: {e}") from None
    return [np.asarray(o) for o in outs]


def fold_constants(m: onnx.ModelProto, shapes: dict, opset: int) -> bool:
    """Replace nodes computable at load by initializers: Constant, Shape/Size of
    static tensors, and any default-domain node whose inputs are all constant.
    Returns whether anything changed."""
    g = m.graph
    consts: dict[str, np.ndarray] = {}
    init_names = {t.name for t in g.initializer}
    runtime_inputs = {i.name for i in g.input if i.name not in init_names}

    def value(name):
        if name not in consts:
            t = next(t for t in g.initializer if t.name == name)
            consts[name] = numpy_helper.to_array(t)
        return consts[name]

    keep, new_inits, changed = [], [], False
    known = set(init_names)
    for node in g.node:
        outs = None
        dom = node.domain or ""
        if dom in ("", "ai.onnx"):
            if node.op_type == "Constant":
                outs = [_constant_value(node)]
            elif node.op_type in ("Shape", "Size") and node.input[0] in shapes:
                shape = shapes[node.input[0]]
                if node.op_type == "Size":
                    outs = [np.array(int(np.prod(shape)), np.int64)]
                else:
                    a = {x.name: helper.get_attribute_value(x) for x in node.attribute}
                    r = len(shape)
                    s = a.get("start", 0)
                    e = a.get("end", r)
                    s, e = (max(0, min(r, v + r if v < 0 else v)) for v in (s, e))
                    outs = [np.array(shape[s:e], np.int64)]
            elif (node.op_type not in NO_FOLD and len(node.input) > 0
                  and all((not t) or t in known for t in node.input)
                  and not any(t in runtime_inputs for t in node.input)):
                vals = [value(t) if t else None for t in node.input]
                _fold_guard(node, [v for v in vals if v is not None])
                outs = _evaluate(node, vals, opset)
        if outs is None:
            keep.append(node)
            continue
        changed = True
        for name, v in zip(node.output, outs):
            if name:
                consts[name] = v
                known.add(name)
                new_inits.append(numpy_helper.from_array(np.asarray(v), name))
    if changed:
        del g.node[:]
        g.node.extend(keep)
        g.initializer.extend(new_inits)
        # Folded values that are also graph outputs stay outputs (as constants).
    return changed


def _constant_value(node: onnx.NodeProto) -> np.ndarray:
    a = {x.name: x for x in node.attribute}
    if "value" in a:
        return numpy_helper.to_array(a["value"].t)
    if "value_float" in a:
        return np.array(a["value_float"].f, np.float32)
    if "value_floats" in a:
        return np.array(list(a["value_floats"].floats), np.float32)
    if "value_int" in a:
        return np.array(a["value_int"].i, np.int64)
    if "value_ints" in a:
        return np.array(list(a["value_ints"].ints), np.int64)
    if "sparse_value" in a:   # COO: indices linear [NNZ] or per axis [NNZ, rank]
        sp = a["sparse_value"].sparse_tensor
        vals, idx = numpy_helper.to_array(sp.values), numpy_helper.to_array(sp.indices)
        dense = np.zeros(tuple(sp.dims), vals.dtype)
        if idx.ndim == 1:
            dense.flat[idx] = vals
        else:
            dense[tuple(idx.T)] = vals
        return dense
    raise ModelError(f"Constant node {node.name!r}: unsupported value attribute {sorted(a)} "
                     "(clss runs numeric tensors)")


# --- the whole load ---------------------------------------------------------------

def prepare(model, input_shapes: dict | None = None) -> tuple[onnx.ModelProto, int, dict]:
    """Load, sort, check, inline local functions and resolve the runtime inputs' shapes.
    Returns the ModelProto (inputs' shapes written into it), its opset and the input
    shapes (in the model's input order). Nothing that needs the inputs' values."""
    m = load_proto(model)
    sort_nodes(m.graph)
    opset = check(m)
    if m.functions:
        try:
            from onnx import inliner
            m = inliner.inline_local_functions(m)
        except Exception as e:
            raise ModelError(f"could not inline the model's local functions: {e}") from None
    return m, opset, resolve_inputs(m, input_shapes)


def finish(m: onnx.ModelProto, opset: int, max_alloc: int | None = None,
           storage_itemsize: int = 4) -> tuple[Graph, onnx.ModelProto]:
    """Shapes resolved, sizes checked, constants folded: the static Graph, and the
    shape-resolved ModelProto before folding (FLOP counting, `clss info`). ``m`` is
    the model as prepare() gave it, with the values of any value inputs (see
    find_value_inputs) already made initializers (with_values); it is not kept."""
    resolved = _infer(m, opset)
    producers = {t: f"{n.op_type} node {n.name!r}" for n in m.graph.node for t in n.output}
    shapes, types = _collect(resolved)
    check_sizes(shapes, types, max_alloc, storage_itemsize, producers)
    original = resolved
    work = onnx.ModelProto()
    work.CopyFrom(resolved)
    for _ in range(16):
        if not fold_constants(work, shapes, opset):
            break
        work = _infer(work, opset)
        shapes, types = _collect(work)
        check_sizes(shapes, types, max_alloc, storage_itemsize, producers)
    return _to_graph(work, shapes, types, opset), original


def build(model, input_shapes: dict | None = None, max_alloc: int | None = None,
          storage_itemsize: int = 4, input_values: dict | None = None) -> tuple[Graph, onnx.ModelProto, dict]:
    """Load, check, resolve shapes and fold. Returns the static Graph, the
    shape-resolved ModelProto (before folding, for FLOP counting and `clss info`),
    and the resolved input shapes (the value inputs given in ``input_values``
    included: they are constants of the Graph)."""
    m, opset, in_shapes = prepare(model, input_shapes)
    if input_values:
        m = with_values(m, {k: np.asarray(v) for k, v in input_values.items()})
    graph, original = finish(m, opset, max_alloc, storage_itemsize)
    return graph, original, in_shapes


# --- inputs whose values clss needs when it plans ("value inputs") --------------------
#
# A graph input that reaches, through any chain of nodes, an input a handler takes as
# a host value (its const_inputs: Resize scales, Pad pads, Slice starts, ...), one the
# load-time passes need constant, or one whose value decides a shape (ONNX shape
# inference needs it: Reshape's shape, Expand's, ConstantOfShape's, Range's bounds) is
# a value input: clss.Model reads its value from the feeds and plans for it
# (with_values makes it an initializer; the graph is built, folded and planned again).

# Inputs whose values decide an output's shape, by op (the handlers' const_inputs add
# the ones a launch needs).
_REDUCE_OPS = ("ReduceMean", "ReduceSum", "ReduceMax", "ReduceMin", "ReduceL1", "ReduceL2",
               "ReduceLogSum", "ReduceLogSumExp", "ReduceSumSquare", "ReduceProd")
SHAPE_VALUE_INPUTS = {
    "Reshape": (1,), "Expand": (1,), "Tile": (1,), "ConstantOfShape": (0,), "Range": (0, 1, 2),
    "Slice": (1, 2, 3, 4), "Pad": (1, 3), "Resize": (2, 3), "Upsample": (1,), "Split": (1,),
    "Squeeze": (1,), "Unsqueeze": (1,), "TopK": (1,), "OneHot": (1,), "CenterCropPad": (1, 2),
    "Col2Im": (1, 2), "AffineGrid": (1,), "DFT": (1, 2), "STFT": (1, 3), "HannWindow": (0,),
    "HammingWindow": (0,), "BlackmanWindow": (0,), "MelWeightMatrix": (0, 1, 2, 3, 4),
    **{op: (1,) for op in _REDUCE_OPS}}
# Inputs the load-time passes (passes.py) need constant, for ops they lower with no
# handler of their name.
LOWERED_CONST_INPUTS = {"Dropout": (1, 2), "BatchNormalization": (1, 2, 3, 4), "Gemm": (1, 2)}
# Inputs of which only the shape or type counts, not the values.
_SHAPE_ONLY = {"Shape": None, "Size": None, "EyeLike": None, "RandomNormalLike": None,
               "RandomUniformLike": None, "CastLike": (1,)}
# A graph input past this many elements whose values would decide a shape is data (an
# image): such a model is refused by name rather than planned again for every frame.
MAX_VALUE_ELEMENTS = 4096


def load_time_positions(node: onnx.NodeProto) -> list[int]:
    """The input positions of ``node`` whose values clss needs when it plans."""
    from ..ops import ONNX_HANDLERS
    op = node.op_type
    if node.domain not in ("", "ai.onnx"):
        return []
    pos = set(SHAPE_VALUE_INPUTS.get(op, ()))
    h = ONNX_HANDLERS.get(op)
    if h is not None:
        pos |= set(h.const_inputs)
    else:
        pos |= set(LOWERED_CONST_INPUTS.get(op, ()))
    return sorted(i for i in pos if i < len(node.input) and node.input[i])


@dataclass
class ValueUse:
    """Where a value input's values are needed: input ``index`` (tensor ``tensor``) of
    node ``node`` (op ``op``), reached through the ops ``via`` (empty: directly)."""
    node: str
    op: str
    index: int
    tensor: str
    via: tuple = ()

    def describe(self) -> str:
        via = f" through {', '.join(self.via)}" if self.via else ""
        return f"{self.op} node {self.node!r} input {self.index} ({self.tensor!r}){via}"


def _node_name(n: onnx.NodeProto, k: int) -> str:
    return n.name or f"#{k} {n.op_type}"


def find_value_inputs(m: onnx.ModelProto, opset: int) -> dict[str, list[ValueUse]]:
    """The runtime graph inputs whose values clss needs when it plans (see above), each
    with where they are needed, in the model's input order. Refuses by name
    (UnsupportedModelError) what no input's value can settle: a needed value computed
    by a node that only runs with the model (random values, control flow), or one that
    follows the values of a data input (more than MAX_VALUE_ELEMENTS elements)."""
    g = m.graph
    inits = {t.name for t in g.initializer} | {t.values.name for t in g.sparse_initializer}
    runtime = [i.name for i in g.input if i.name not in inits]
    deps: dict[str, frozenset] = {t: frozenset({("in", t)}) for t in runtime}
    producer: dict[str, int] = {}
    for k, n in enumerate(g.node):
        op = n.op_type
        if n.domain in ("", "ai.onnx") and op in NO_FOLD:
            d = frozenset({("run", k)})
        elif n.domain in ("", "ai.onnx") and op == "Constant":
            d = frozenset()
        else:
            skip = _SHAPE_ONLY.get(op, ()) if n.domain in ("", "ai.onnx") else ()
            d = frozenset().union(*(deps.get(t, frozenset()) for i, t in enumerate(n.input)
                                    if t and skip is not None and i not in skip))
        for t in n.output:
            if t:
                deps[t] = d
                producer[t] = k

    def path(t: str, goal) -> tuple:
        """The ops between tensor t and the dependency ``goal`` (nearest first)."""
        ops = []
        while t in producer and len(ops) < 6:
            k = producer[t]
            n = g.node[k]
            if goal == ("run", k):
                break
            ops.append(f"{n.op_type} {_node_name(n, k)!r}")
            t = next((x for x in n.input if x and goal in deps.get(x, ())), None)
            if t is None:
                break
        return tuple(ops)

    uses: dict[str, list[ValueUse]] = {}
    bad = []
    for k, n in enumerate(g.node):
        for i in load_time_positions(n):
            t = n.input[i]
            for dep in sorted(deps.get(t, ()), key=str):
                use = ValueUse(_node_name(n, k), n.op_type, i, t, path(t, dep))
                if dep[0] == "in":
                    uses.setdefault(dep[1], []).append(use)
                else:
                    src = g.node[dep[1]]
                    what = "control flow" if src.op_type in ("If", "Loop", "Scan") else "random values"
                    bad.append((use.node, use.op, opset,
                                f"input {i} ({t!r}) is computed when the model runs, by {src.op_type} node "
                                f"{_node_name(src, dep[1])!r} ({what})"
                                + (f" through {', '.join(use.via)}" if use.via else "")
                                + "; clss needs it when it plans the model"))
    # (a symbolic size counts as past the limit: an input whose sizes vary is data)
    sizes = {}
    for i in g.input:
        if i.name in uses:
            dims = i.type.tensor_type.shape.dim
            sizes[i.name] = (int(np.prod([d.dim_value for d in dims], dtype=np.int64))
                             if all(d.HasField("dim_value") for d in dims) else None)
    for name, us in uses.items():
        n = sizes[name]
        if n is None or n > MAX_VALUE_ELEMENTS:
            for u in us:
                bad.append((u.node, u.op, opset,
                            f"input {u.index} ({u.tensor!r}) follows the values of graph input {name!r} "
                            + (f"({n:,} elements)" if n is not None else "(symbolic shape)")
                            + (f" through {', '.join(u.via)}" if u.via else "")
                            + f": a shape or setting that depends on data. clss plans for the values of "
                            f"inputs of up to {MAX_VALUE_ELEMENTS:,} elements (Resize scales, a Reshape "
                            "shape, ...), read at each run, not for those of data tensors"))
    if bad:
        raise UnsupportedModelError(unknown_ops(m, opset) + bad)
    return {t: uses[t] for t in runtime if t in uses}


def with_values(m: onnx.ModelProto, values: dict) -> onnx.ModelProto:
    """A copy of ``m`` whose graph inputs named in ``values`` are initializers of those
    values (in the input's declared element type)."""
    w = onnx.ModelProto()
    w.CopyFrom(m)
    g = w.graph
    keep = []
    for vi in g.input:
        if vi.name in values:
            dt = _np_dtype(vi.type.tensor_type.elem_type)
            g.initializer.append(numpy_helper.from_array(np.asarray(values[vi.name]).astype(dt), vi.name))
        else:
            keep.append(vi)
    if len(keep) != len(g.input):
        kept = []
        for vi in keep:
            kept.append(onnx.ValueInfoProto())
            kept[-1].CopyFrom(vi)
        del g.input[:]
        g.input.extend(kept)
    return w


def _to_graph(m, shapes, types, opset) -> Graph:
    g = m.graph
    consts = {t.name: _host_const(numpy_helper.to_array(t)) for t in g.initializer}
    init_names = set(consts)
    inputs = [i.name for i in g.input if i.name not in init_names]
    nodes = []
    opsets = {o.domain or "": o.version for o in m.opset_import}
    for k, n in enumerate(g.node):
        name = n.name or f"#{k} {n.op_type}"
        dom = n.domain if n.domain not in ("", "ai.onnx") else ""
        nodes.append(Node(n.op_type, list(n.input), list(n.output),
                          {a.name: helper.get_attribute_value(a) for a in n.attribute},
                          name, opsets.get(dom, opset), dom))
    for n in nodes:
        for t in n.outputs:
            if t and t not in shapes:
                why = (f"could not resolve the shape of tensor {t!r} (output of {n.op} node "
                       f"{n.name!r}); clss needs every shape static at load")
            elif t and t not in types:
                why = f"could not resolve the element type of tensor {t!r} (output of {n.op} node {n.name!r})"
            else:
                continue
            refuse_unknown_ops(m, opset, f"(also: {why})")
            raise ModelError(why)
    dtypes = {}
    for t, et in types.items():
        dtypes[t] = np.dtype(np.float32) if et in FLOAT_TYPES else _np_dtype(et)
    for t, v in consts.items():
        dtypes[t] = v.dtype
        shapes[t] = tuple(v.shape)
    elem_types = {t: types[t] for t in inputs + [o.name for o in g.output] if t in types}
    return Graph(nodes, inputs, [o.name for o in g.output], dict(shapes), dtypes, consts, opset,
                 elem_types)


def _host_const(v: np.ndarray) -> np.ndarray:
    """Float constants are handled as float32 on the host (fp16 storage is the
    device's business); others as they are."""
    v = np.asarray(v)
    if v.dtype == np.float16:
        return v.astype(np.float32)
    return np.ascontiguousarray(v).reshape(v.shape)   # (ascontiguousarray makes 0-d arrays 1-d)
