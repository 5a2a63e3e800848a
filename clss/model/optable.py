"""The ONNX ops clss runs, each with its limits in one line: the op table.

One entry per op type clss.Model runs: every registered handler (clss.ops.ONNX_HANDLERS
after clss.ops.load_all()) and every op the load-time passes rewrite (graph.LOWERED_OPS).
tests/test_optable.py holds the table to the registry both ways, and docs/model.md's
"Supported ops and opsets" section to render_markdown(); regenerate that section with

    python -m clss.model.optable --write docs/model.md

The opsets column is derived from onnx.defs: the model opsets at which the op can be
used (from MIN_OPSET, or the op's first version, to MAX_OPSET) and, in parentheses, the
op's ONNX versions in effect at opsets MIN_OPSET..21 (the forms the limits cover;
versions 22-25 only widened the type constraints).

The second half checks a model against the table without building anything
(`clss model info`): support_report() reads the ONNX file (external data not loaded)
and says per op type whether clss runs it, and why not, with its limits.
"""
from __future__ import annotations

import os
import sys

from .graph import LOWERED_OPS, MAX_OPSET, MIN_OPSET

# Said once above the table instead of on every row.
COMMON = ("Tensors are float32 or float16 (the model's `precision` decides the storage); integer and "
          "bool tensors only where a row says so, or folded at load (any node whose inputs are all "
          "constant is evaluated at load, whatever its op: Shape -> Gather -> Concat chains, Range, "
          "casts of constants). \"Known at load\": a constant after that folding, or computed from a small "
          "graph input whose value clss reads from each run's feeds and plans for, planning again when "
          "it changes (a value input: Resize scales, a Reshape shape, ...). Any rank, as long as "
          "the shape needs at most 4 dimensions (8 for the strided copies of Slice, Transpose, Expand, "
          "Tile and Gather) once the axes that stay together in memory are merged and size-1 ones "
          "dropped.")

# op type -> its limits (one line, Markdown).
OPS: dict[str, str] = {
    # --- convolution, resampling, pooling
    "Conv": "1-D and 2-D (1-D runs as [N,C,1,L]); any group, dilation, stride, asymmetric pads; auto_pad; "
            "fused with a following activation and residual Add; 3-D refused",
    "ConvTranspose": "2-D: any group, dilation, stride, pads, output_padding, output_shape, auto_pad; "
                     "1-D with explicit pads or VALID; 3-D refused",
    "Resize": "resizes the last two axes (rank >= 2, other scales 1); modes nearest/linear/cubic; every "
              "coordinate_transformation_mode; nearest_mode round_prefer_floor/round_prefer_ceil/floor/ceil; "
              "antialias (linear, cubic), exclude_outside, cubic_coeff_a, keep_aspect_ratio_policy, axes; "
              "roi/scales/sizes known at load",
    "Upsample": "deprecated at opset 10, so a model clss loads (opset 11+) cannot hold it (Resize does the "
                "same); the node cases of opsets 9-10 run it: nearest or (bi)linear over the last two axes",
    "GridSample": "4-D (2-D spatial) only; modes nearest/bilinear/bicubic (opset 20: linear/cubic); "
                  "padding zeros/border/reflection; align_corners; the grid stays float32 in fp16",
    "SpaceToDepth": "4-D; blocksize dividing H and W",
    "DepthToSpace": "4-D; modes DCR and CRD",
    "MaxPool": "1-3 spatial dims; kernel, strides, pads, dilations, ceil_mode, auto_pad; Indices output "
               "(storage_order 1 in 2-D only)",
    "AveragePool": "1-3 spatial dims; kernel, strides, pads, dilations, ceil_mode, auto_pad, count_include_pad",
    "GlobalAveragePool": "[N,C,spatial...], any number of spatial dims",
    "GlobalMaxPool": "[N,C,spatial...], any number of spatial dims",
    # --- linear algebra and normalisation
    "MatMul": "any rank: batched, batch dims broadcasting (at most 2 once merged when neither operand is "
              "constant), 1-D operands; a constant B runs as a 1x1 conv",
    "Gemm": "2-D A and B, constant or computed at run time; transA, transB, alpha, beta; C broadcast to "
            "[M,N]; a constant B runs as a 1x1 conv",
    "BatchNormalization": "scale, bias, mean, var constant; inference: folded into the Conv/ConvTranspose "
                          "before it, else a depthwise 1x1 conv (rank 2-4); training_mode: batch statistics "
                          "and running statistics as outputs",
    "LayerNormalization": "any axis (normalises axis..last), epsilon; scale and optional bias broadcasting "
                          "to the normalised shape; Mean and InvStdDev outputs; stash_type 1",
    "InstanceNormalization": "rank >= 3 [N,C,spatial...]; epsilon",
    "GroupNormalization": "rank >= 2; num_groups, epsilon, stash_type 1; scale and bias per channel "
                          "(opset 21) or per group (opset 18, deprecated: the onnx checker refuses it in "
                          "a model)",
    # --- reductions
    **{op: "any axes, as the attribute or as an input known at load; keepdims, noop_with_empty_axes; "
           "at most 4 kept and 4 reduced dims once merged"
       for op in ("ReduceMean", "ReduceSum", "ReduceMax", "ReduceMin", "ReduceL1", "ReduceL2",
                  "ReduceLogSum", "ReduceLogSumExp", "ReduceSumSquare", "ReduceProd")},
    "Softmax": "any axis; opset < 13: the input coerced to 2-D at axis, as the spec says",
    "LogSoftmax": "any axis; opset < 13: the input coerced to 2-D at axis, as the spec says",
    "ArgMax": "any axis, keepdims, select_last_index; int64 output",
    # --- elementwise: activations and functions
    "Relu": "any shape; fused into a Conv or binary op before it",
    "LeakyRelu": "any shape; alpha; fused into a Conv before it",
    "PRelu": "slope broadcasting to the input",
    "Sigmoid": "any shape; fused into a Conv before it",
    "Tanh": "any shape; fused into a Conv before it",
    "Elu": "any shape; alpha",
    "HardSigmoid": "any shape; alpha, beta",
    "HardSwish": "any shape",
    "Gelu": "any shape; approximate none (erf) and tanh",
    "Erf": "any shape",
    "Softplus": "any shape",
    "Softsign": "any shape",
    "Abs": "any shape",
    "Neg": "any shape",
    "Exp": "any shape",
    "Log": "any shape",
    "Sqrt": "any shape",
    "Reciprocal": "any shape",
    "Floor": "any shape",
    "Ceil": "any shape",
    "Round": "any shape; halves to even",
    "Sign": "any shape",
    "Sin": "any shape",
    "Cos": "any shape",
    "Selu": "any shape; alpha, gamma",
    "Celu": "any shape; alpha",
    "ThresholdedRelu": "any shape; alpha",
    "Mish": "any shape",
    "Clip": "min and max optional one-element tensors, constant or computed at run time",
    # --- elementwise: binary and variadic
    **{op: "broadcasting" for op in ("Add", "Sub", "Mul", "Div")},
    "Pow": "broadcasting; float base and exponent",
    **{op: "broadcasting, any number of inputs" for op in ("Min", "Max", "Sum")},
    **{op: "float inputs, broadcasting; bool output"
       for op in ("Equal", "Greater", "GreaterOrEqual", "Less", "LessOrEqual")},
    "Where": "bool condition, broadcasting",
    # --- data movement (bit-exact)
    "Concat": "any axis, any number of inputs",
    "Split": "any axis; sizes as the input or attribute, or num_outputs / equal parts",
    "Slice": "any axes and steps (negative included); starts, ends, axes, steps known at load",
    "Pad": "modes constant/edge/reflect/wrap; negative pads crop; pads, constant_value, axes known at load",
    "Transpose": "any perm leaving at most 8 runs of axes that move together; a view when only size-1 axes "
                 "move; the PixelShuffle/PixelUnshuffle Reshape-Transpose-Reshape runs as one "
                 "DepthToSpace/SpaceToDepth",
    "Expand": "shape known at load",
    "Tile": "repeats known at load",
    "Gather": "any axis; indices known at load (negative ones count from the end)",
    "ScatterElements": "rank 1-8, any axis, reduction none/add/mul/max/min; int32/int64 indices (add and mul "
                       "round in the order duplicates land)",
    # --- views and no-ops
    "Reshape": "a view (no copy); 0 and -1 in the shape, allowzero",
    "Flatten": "a view (no copy); any axis",
    "Squeeze": "a view (no copy); axes as the attribute or input",
    "Unsqueeze": "a view (no copy); axes as the attribute or input",
    "Identity": "tensors (not optional or sequence values); costs nothing",
    "Dropout": "inference, or training mode with ratio 0; the mask output is all ones",
    "Cast": "to float or float16: of a float tensor nothing runs, of a bool mask Where(mask, 1, 0); other "
            "casts only when folded at load",
    "CastLike": "as Cast, to a float or float16 target",
    "Constant": "every numeric form, sparse included; a constant at load",
}

# Entries allowed to lack a registered handler for now (ops being written), each named;
# tests/test_optable.py fails once one is registered and still listed, so it only shrinks.
# Empty: the issue-49 ops (Reduce*, LogSoftmax, HardSwish, Gelu, Erf, ..., the
# normalisations, MatMul/Gemm of run-time operands, Tile) are registered.
PENDING: frozenset = frozenset()

BEGIN, END = "<!-- optable -->", "<!-- /optable -->"


def registered() -> set[str]:
    """The op types clss runs today: registered handlers and lowered ops."""
    from ..ops import ONNX_HANDLERS, load_all
    load_all()
    return set(ONNX_HANDLERS) | set(LOWERED_OPS)


def versions(op: str) -> list[int]:
    """The ONNX (default domain) versions of `op` known to onnx, ascending."""
    return sorted({s.since_version for s in _history().get(op, ())})


_HISTORY: dict | None = None


def _history() -> dict:
    global _HISTORY
    if _HISTORY is None:
        import onnx.defs
        h: dict = {}
        for s in onnx.defs.get_all_schemas_with_history():
            if s.domain in ("", "ai.onnx"):
                h.setdefault(s.name, []).append(s)
        _HISTORY = h
    return _HISTORY


def opsets(op: str) -> tuple[int, int, list[int]] | None:
    """(first, last, forms): the model opsets at which clss takes `op` and the op's
    versions in effect at MIN_OPSET..21 (type-only changes 22-25 left out); None for
    an op deprecated before MIN_OPSET (the onnx checker refuses it in such a model)."""
    schemas = sorted((s for s in _history().get(op, ()) if s.since_version <= MAX_OPSET),
                     key=lambda s: s.since_version)
    if not schemas:
        return MIN_OPSET, MAX_OPSET, []
    first = max(MIN_OPSET, schemas[0].since_version)
    live = [s for s in schemas if s.since_version > first or s is max(
        (x for x in schemas if x.since_version <= first), key=lambda x: x.since_version)]
    while live and live[0].deprecated:
        live.pop(0)
    if not live:
        return None
    first = max(first, live[0].since_version)
    forms = [s.since_version for s in live if s.since_version <= 21]
    return first, MAX_OPSET, forms


def opsets_text(op: str) -> str:
    o = opsets(op)
    if o is None:
        gone = min(s.since_version for s in _history()[op] if s.deprecated)
        return f"none (deprecated at {gone})"
    first, last, forms = o
    return f"{first}-{last}" + (f" ({', '.join(map(str, forms))})" if forms else "")


def render_markdown() -> str:
    """The op table as Markdown, with the lines that introduce it."""
    import textwrap
    intro = (f"{len(OPS)} op types, each with its limits (generated from `clss/model/optable.py`; "
             f"`clss model info FILE` checks a model against it). {COMMON}")
    opsets_note = ("Opsets: the model opsets at which clss takes the op; in parentheses the op's ONNX "
                   f"versions in effect at opsets {MIN_OPSET} to 21, the forms the limits cover (22-25 "
                   "only widened the types).")
    lines = [textwrap.fill(intro, 100, break_on_hyphens=False, break_long_words=False), "",
             textwrap.fill(opsets_note, 100, break_on_hyphens=False, break_long_words=False), "",
             "| op | opsets | limits |", "|---|---|---|"]
    for op in sorted(OPS, key=str.lower):
        lines.append(f"| {op} | {opsets_text(op)} | {OPS[op].replace('|', '/')} |")
    return "\n".join(lines) + "\n"


def splice(text: str, table: str) -> str:
    """`text` with the part between BEGIN and END replaced by `table`."""
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"no {BEGIN} ... {END} markers")
    return text[:start + len(BEGIN)] + "\n" + table + text[end:]


def write_doc(path: str) -> bool:
    """Regenerate the table in the Markdown file `path`; True when it changed."""
    with open(path, encoding="utf-8") as f:
        old = f.read()
    new = splice(old, render_markdown())
    if new != old:
        with open(path, "w", encoding="utf-8") as f:
            f.write(new)
    return new != old


# --- a model against the table (clss model info) ------------------------------------------

# Folding never evaluates these (graph.NO_FOLD); a node of them stays unsupported.
def _no_fold() -> set[str]:
    from .graph import NO_FOLD
    return set(NO_FOLD)


def _load(path: str):
    import onnx
    from .graph import ModelError
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ModelError(f"no such model file: {path}")
    if os.path.isdir(path):
        raise ModelError(f"{path}: is a directory, expected an ONNX file")
    try:
        m = onnx.load(path, load_external_data=False)
    except Exception as e:
        raise ModelError(f"{path}: not an ONNX model: {str(e).splitlines()[0] if str(e) else type(e).__name__}") \
            from None
    if not m.ir_version and not m.opset_import and not m.graph.node:   # an empty file parses as a message
        raise ModelError(f"{path}: not an ONNX model: no IR version, opset or nodes")
    return m


def _dims(vi) -> list | None:
    t = vi.type.tensor_type
    if vi.type.WhichOneof("value") != "tensor_type" or not t.HasField("shape"):
        return None
    return [d.dim_value if d.HasField("dim_value") else (d.dim_param or "?") for d in t.shape.dim]


def _value_info(vi) -> dict:
    import onnx
    kind = vi.type.WhichOneof("value")
    if kind == "tensor_type":
        et = vi.type.tensor_type.elem_type
        typ = onnx.TensorProto.DataType.Name(et).lower() if et else "?"
    else:
        typ = kind or "?"
    dims = _dims(vi)
    return {"name": vi.name, "type": typ, "shape": dims,
            "symbolic": dims is None or any(not isinstance(d, int) for d in dims)}


def _external(m, base: str) -> dict:
    """Tensors stored outside the file and the files they name (not read)."""
    import onnx
    tensors = list(m.graph.initializer)
    for n in m.graph.node:
        for a in n.attribute:
            if a.type == onnx.AttributeProto.TENSOR:
                tensors.append(a.t)
    files: dict[str, int] = {}
    count = 0
    for t in tensors:
        if t.data_location != onnx.TensorProto.EXTERNAL:
            continue
        count += 1
        info = {e.key: e.value for e in t.external_data}
        loc = info.get("location", "")
        files[loc] = files.get(loc, 0) + int(info.get("length", 0) or 0)
    out = []
    for loc, length in files.items():
        p = os.path.join(base, loc)
        exists = os.path.isfile(p)
        out.append({"location": loc, "exists": exists,
                    "bytes": os.path.getsize(p) if exists else length})
    return {"tensors": count, "files": out}


def support_report(path: str) -> dict:
    """What clss would make of the ONNX file at `path`, from the file alone: no device,
    no shape resolution, no kernel build, external data not loaded. Raises
    graph.ModelError for a file that is not an ONNX model."""
    import onnx
    from ..ops import ONNX_HANDLERS
    from .graph import NO_KERNEL, custom_domain_reason, sort_nodes
    m = _load(path)
    have = registered()
    # Graph inputs whose values clss reads at each run and plans for (Resize scales, a
    # Reshape shape, ...), where this clss has them; else such inputs must be constants.
    from . import graph as _graph
    find_value_inputs = getattr(_graph, "find_value_inputs", None)
    problems: list[str] = []
    opsets_all = {o.domain or "ai.onnx": int(o.version) for o in m.opset_import}
    opset = opsets_all.get("ai.onnx")
    if opset is None:
        problems.append("the model imports no default-domain (ai.onnx) opset")
    elif opset < MIN_OPSET:
        problems.append(f"opset {opset} is below {MIN_OPSET}: clss refuses the model "
                        f"(onnx.version_converter.convert_version can move it to {MIN_OPSET}..{MAX_OPSET})")
    n_functions = len(m.functions)
    if m.functions:
        try:
            from onnx import inliner
            m = inliner.inline_local_functions(m)
        except Exception as e:
            problems.append(f"could not inline the model's {n_functions} local function(s): {e}")
    g = m.graph
    sort_nodes(g)
    inits = {t.name for t in g.initializer} | {t.values.name for t in g.sparse_initializer}
    runtime = [i for i in g.input if i.name not in inits]
    const = set(inits) | {""}
    no_fold = _no_fold()
    ops: dict[str, dict] = {}
    for k, n in enumerate(g.node):
        name = n.name or f"#{k} {n.op_type}"
        custom = n.domain not in ("", "ai.onnx")
        key = f"{n.domain}:{n.op_type}" if custom else n.op_type
        e = ops.setdefault(key, {"op": n.op_type, "domain": n.domain if custom else "", "nodes": 0, "folded": 0,
                                 "supported": None, "limits": None if custom else OPS.get(n.op_type),
                                 "opsets": None if custom or n.op_type not in OPS else opsets_text(n.op_type),
                                 "refused": []})
        e["nodes"] += 1
        why, kind = None, "op"
        if custom:
            why = custom_domain_reason(n.domain)
        elif opset is not None and n.op_type in _history():
            try:
                since = onnx.defs.get_schema(n.op_type, opset).since_version
            except Exception:
                since = None
            if since is None:
                first = versions(n.op_type)[0]
                why = f"not an ONNX op at opset {opset} (it came with opset {first}); the onnx checker refuses it"
            elif onnx.defs.get_schema(n.op_type, opset).deprecated:
                why = f"deprecated at opset {since}; the onnx checker refuses it at opset {opset}"
            elif since > MAX_OPSET:
                why = (f"changed at opset {since}, after {MAX_OPSET}, the last clss knows "
                       f"(onnx.version_converter.convert_version can move the model to {MAX_OPSET})")
        foldable = (not custom and n.op_type not in no_fold and len(n.input) > 0
                    and (n.op_type in ("Shape", "Size") or all(t in const for t in n.input)))
        if why is None and n.op_type == "Constant":
            foldable = True   # (no inputs: a constant by itself)
        if why is None and foldable:
            e["folded"] += 1
            const.update(t for t in n.output if t)
            continue
        if why is None and n.op_type not in have:
            why = NO_KERNEL
        if why is None and find_value_inputs is None:   # clss plans for constants only
            h = ONNX_HANDLERS.get(n.op_type)
            if h is not None and n.op_type not in LOWERED_OPS:
                for i in sorted(h.const_inputs):
                    if i < len(n.input) and n.input[i] and n.input[i] not in const:
                        why = (f"input {i} ({n.input[i]!r}) must be known at load; here it depends on "
                               "the graph's inputs")
                        kind = "node"
                        break
        if why is not None:
            e["refused"].append({"node": name, "reason": why, "kind": kind})
    value_inputs = {}
    if find_value_inputs is not None and opset is not None:
        value_inputs = _value_inputs(find_value_inputs, m, opset, ops)
    rank = {"unsupported": 0, "refused": 1, "supported": 2, "folded": 3}
    for e in ops.values():
        kinds = {r["kind"] for r in e["refused"]}
        e["supported"] = not kinds
        e["status"] = ("unsupported" if "op" in kinds else "refused" if kinds
                       else "supported" if e["op"] in have else "folded")
    order = sorted(ops, key=lambda k: (rank[ops[k]["status"]], -ops[k]["nodes"], k))
    ops = {k: ops[k] for k in order}
    ext = _external(m, os.path.dirname(os.path.abspath(path)))
    for f in ext["files"]:
        if not f["exists"]:
            problems.append(f"external data file {f['location']!r} is missing (it belongs next to the model)")
    verdict = _verdict(ops, problems)
    bad = [k for k, e in ops.items() if not e["supported"]]
    return {
        "model": os.fspath(path),
        "ir_version": int(m.ir_version),
        "producer": f"{m.producer_name} {m.producer_version}".strip(),
        "opset": opset,
        "opsets": opsets_all,
        "clss_opsets": [MIN_OPSET, MAX_OPSET],
        "inputs": [_value_info(vi) for vi in runtime],
        "outputs": [_value_info(vi) for vi in g.output],
        "external_data": ext,
        "local_functions": n_functions,
        "value_inputs": value_inputs,
        "nodes": len(g.node),
        "ops": ops,
        "problems": problems,
        "supported": not bad and not problems,
        "verdict": verdict,
    }


def _value_inputs(find, m, opset: int, ops: dict) -> dict:
    """{graph input: [where its value is needed]} from graph.find_value_inputs; the nodes
    it refuses (a needed value that random values, control flow or a data tensor decide)
    become node refusals in ``ops``."""
    from .graph import UnsupportedModelError
    try:
        uses = find(m, opset)
    except UnsupportedModelError as e:
        known = {r["node"] for o in ops.values() for r in o["refused"]}
        for name, op, _, why in e.nodes:
            if name in known:
                continue
            entry = next((o for k, o in ops.items() if o["op"] == op and not o["domain"]), None)
            if entry is not None:
                entry["refused"].append({"node": name, "reason": why, "kind": "node"})
        return {}
    except Exception:   # an analysis that fails here is the load's to report
        return {}
    refused = {r["node"] for o in ops.values() for r in o["refused"]}
    out = {t: [u.describe() for u in us if u.node not in refused] for t, us in uses.items()}
    return {t: us for t, us in out.items() if us}


def _verdict(ops: dict, problems: list) -> str:
    unsupported = [k for k, e in ops.items() if e["status"] == "unsupported"]
    refused = [(k, r) for k, e in ops.items() for r in e["refused"] if r["kind"] == "node"]
    if unsupported:
        why = [f"{k} ({'; '.join(sorted({_short(r['reason']) for r in ops[k]['refused']}))})" for k in unsupported]
        text = f"{len(unsupported)} of {len(ops)} op types unsupported: {', '.join(why)}"
    else:
        text = f"all {len(ops)} op types supported"
    if refused:
        text += (f"; {len(refused)} node(s) of supported op types refused: " if unsupported
                 else f", but {len(refused)} node(s) refused: ")
        text += (", ".join(f"{k} {r['node']!r} ({_short(r['reason'])})" for k, r in refused[:5])
                 + (", ..." if len(refused) > 5 else ""))
    for p in problems:
        text += f"; {p}"
    return text


def _short(reason: str) -> str:
    from .graph import NO_KERNEL
    if reason == NO_KERNEL:
        return "no kernel"
    if reason.startswith("custom domain"):
        return reason.split(":")[0]
    if reason.startswith("changed at opset"):
        return reason.split(",")[0]
    if reason.startswith("input "):
        return reason.split(";")[0]
    return reason


def _shape_text(d: dict) -> str:
    if d["shape"] is None:
        return "shape not declared (shape inference gives it at load)"
    return "[" + ", ".join(str(s) if isinstance(s, int) else repr(s) for s in d["shape"]) + "]"


def format_report(r: dict) -> str:
    lines = [f"model: {os.path.basename(r['model'])}  (IR {r['ir_version']}"
             + (f", producer {r['producer']})" if r["producer"] else ")")]
    others = [f"{d} {v}" for d, v in r["opsets"].items() if d != "ai.onnx"]
    op_line = (f"opset: {r['opset']}" if r["opset"] is not None else "opset: none (no ai.onnx import)")
    op_line += f"  (clss runs {r['clss_opsets'][0]} to {r['clss_opsets'][1]})"
    if others:
        op_line += f"; other domains: {', '.join(others)}"
    lines.append(op_line)
    sym = []
    for d in r["inputs"]:
        lines.append(f"  input  {d['name']}: {d['type']} {_shape_text(d)}")
        if d["symbolic"]:
            sym.append(d)
    for d in r["outputs"]:
        lines.append(f"  output {d['name']}: {d['type']} {_shape_text(d)}")
    if sym:
        ex = " ".join(f"--input-shape {d['name']}=" + "x".join(
            str(s) if isinstance(s, int) else ("1" if ax == 0 else "64")
            for ax, s in enumerate(d["shape"] or [1, 3, 64, 64])) for d in sym)
        lines.append(f"  symbolic input sizes: give them to `clss info` / `clss run` with {ex} (your sizes)")
    for t, uses in r.get("value_inputs", {}).items():
        lines.append(f"  value input {t}: clss reads its value at each run and plans for it "
                     f"({'; '.join(uses[:3])}{'; ...' if len(uses) > 3 else ''})")
    ext = r["external_data"]
    if ext["tensors"]:
        files = ", ".join(f"{f['location']} ({_mib(f['bytes'])}" + (")" if f["exists"] else ", MISSING)")
                          for f in ext["files"])
        lines.append(f"external data: {ext['tensors']} tensor(s) in {files}; not read here")
    else:
        lines.append("external data: none")
    if r["local_functions"]:
        lines.append(f"local functions: {r['local_functions']} (inlined, as clss does at load)")
    lines.append(f"ops: {r['nodes']} nodes of {len(r['ops'])} types (nothing built; the limits are clss's op table)")
    width = max([len(k) for k in r["ops"]] + [2])
    for k, e in r["ops"].items():
        if not e["supported"]:
            status = e["status"].upper()
            reasons = sorted({x["reason"] for x in e["refused"]})
            text = "; ".join(reasons)
            named = [x["node"] for x in e["refused"]]
            if len(e["refused"]) < e["nodes"] or len(named) <= 3:
                text += f"  [{', '.join(repr(x) for x in named[:5])}{', ...' if len(named) > 5 else ''}]"
        elif e["status"] == "folded":
            status = "folded"
            text = ("no kernel needed: evaluated at load from the resolved shapes" if e["op"] in ("Shape", "Size")
                    else "no kernel needed: its inputs are constants, evaluated at load")
        else:
            status, text = "supported", e["limits"] or ""
        if e["folded"] and status != "folded":
            text += f"  ({e['folded']} of {e['nodes']} folded at load)"
        lines.append(f"  {k:<{width}} {e['nodes']:>5}  {status:<11}  {text}")
    for p in r["problems"]:
        lines.append(f"problem: {p}")
    lines.append(f"verdict: {r['verdict']}")
    return "\n".join(lines)


def _mib(b: int) -> str:
    return f"{b / 2**20:.2f} MiB" if b >= 2**20 else f"{b / 2**10:.1f} KiB"


def main(argv=None) -> int:
    import argparse
    p = argparse.ArgumentParser(prog="python -m clss.model.optable",
                                description="Print clss's op table as Markdown, or write it into a "
                                            f"document between {BEGIN} and {END}.")
    p.add_argument("--write", metavar="FILE.md", help="regenerate the table in FILE.md (docs/model.md)")
    p.add_argument("--check", metavar="FILE.md", help="exit 1 if FILE.md's table differs from the rendered one")
    a = p.parse_args(argv)
    if a.write:
        print(f"{a.write}: {'updated' if write_doc(a.write) else 'already up to date'}")
        return 0
    if a.check:
        with open(a.check, encoding="utf-8") as f:
            text = f.read()
        same = splice(text, render_markdown()) == text
        print(f"{a.check}: {'up to date' if same else 'differs; run python -m clss.model.optable --write ' + a.check}")
        return 0 if same else 1
    sys.stdout.write(render_markdown())
    return 0


if __name__ == "__main__":
    sys.exit(main())
