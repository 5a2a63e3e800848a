"""The exported-model suite (issue 49): models as users bring them, exported from PyTorch,
through clss.Model against onnxruntime, fp32 and fp16.

tests/fixtures/exported holds small PyTorch versions of published architectures (ESPCN,
FSRCNN, EDSR, RCAN, Real-ESRGAN's RRDBNet, a BatchNorm U-Net, a U-Net padding to odd sizes
from the shapes, MobileNetV3 and MobileNetV2 blocks, ConvNeXt, a SwinIR block pair, a
BasicVSR propagation step, a ConvLSTM cell, InstanceNorm / GroupNorm blocks),
random weights from fixed seeds, each exported with torch's TorchScript exporter (opset 17)
and its dynamo exporter (torch's default exporter and opset; external data kept as written).
weights_tools/export_suite.py writes them and tests/fixtures/exported/manifest.json (`make
export-fixtures`, needs the [train] extra); these tests read only the manifest and the ONNX
files, never torch.

Every fixture runs at the manifest's input shapes (odd sizes, e.g. 1x3x23x37; the conv SR
models are exported with dynamic height and width and sized by ``input_shapes=``) with
seeded inputs (uniform or normal, as the manifest says). Tolerances, per element
|clss - ort| <= atol * max|ref| + rtol * |ref| (clss.tolerance), the house's for whole
networks (tests/test_model_networks.py):

* fp32: atol 2e-5, rtol 2e-4 against onnxruntime on the same model and inputs
  (accumulation order differs and compounds over ~20 layers);
* fp16: atol 5e-3, rtol 5e-3 against onnxruntime on the model with its float
  initializers and Constant values rounded to fp16, fed fp16-rounded inputs (clss stores
  every intermediate tensor in half; this reference does not round them). Where that
  differs by more (a GridSample grid computed inside the graph, BasicVSR's flow-built one:
  pixel coordinates stored in half move by up to 1/32 pixel at x = 32..64), the same
  tolerance against onnxruntime on the model with every float tensor it stores rounded to
  half too (a Cast to float16 and back after each node): what fp16 storage means. Fused
  kernels keep their intermediates in float, so a result between the two is right.

On the default device: the suite checks clss.Model on whole graphs; every kernel is checked
on every device by the conformance and node-case tests. A model clss refuses fails with the
nodes it names (UnsupportedModelError): these are the
targets of issue 49, never skipped. test_fixtures_match_manifest checks the directory and
the manifest agree (every entry's files present with their sizes and hashes, every file
listed)."""
from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

import clss
from clss.model import ModelError, UnsupportedModelError
from clss.tolerance import Tolerance, compare
from clss.verify.twin import run_ort

FIXTURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fixtures", "exported")
MANIFEST_PATH = os.path.join(FIXTURES, "manifest.json")
TOL = {"fp32": Tolerance(2e-5, 2e-4), "fp16": Tolerance(5e-3, 5e-3)}
MAX_BYTES = 300 * 1024          # per file: fixtures stay small
MIN_ARCHS = 9


def _manifest():
    with open(MANIFEST_PATH) as fh:
        return json.load(fh)


MANIFEST = _manifest()
ENTRIES = MANIFEST["models"]


def feeds(entry) -> dict[str, np.ndarray]:
    """The seeded inputs of an entry (the manifest's shapes and distributions)."""
    rng = np.random.default_rng(1000 + entry["seed"])
    out = {}
    for i in entry["inputs"]:
        if "std" in i:
            out[i["name"]] = rng.normal(0.0, i["std"], i["shape"]).astype(np.float32)
        else:
            out[i["name"]] = rng.uniform(i["low"], i["high"], i["shape"]).astype(np.float32)
    return out


def input_shapes(entry) -> dict | None:
    """input_shapes= for the inputs whose declared shape has symbolic axes."""
    given = {i["name"]: tuple(i["shape"]) for i in entry["inputs"]
             if any(not isinstance(d, int) for d in i["declared"])}
    return given or None


def _half_model(m: onnx.ModelProto) -> onnx.ModelProto:
    """The model with its float initializers and float Constant values rounded to fp16."""
    h = onnx.ModelProto()
    h.CopyFrom(m)

    def rounded(t):
        a = numpy_helper.to_array(t)
        if a.dtype == np.float32:
            t.CopyFrom(numpy_helper.from_array(a.astype(np.float16).astype(np.float32), t.name))
    for t in h.graph.initializer:
        rounded(t)
    for n in h.graph.node:
        if n.op_type == "Constant":
            for a in n.attribute:
                if a.name == "value":
                    rounded(a.t)
    return h


def _half_storage_model(m: onnx.ModelProto) -> onnx.ModelProto:
    """_half_model with every float tensor a node writes rounded to fp16 as well (a Cast
    to float16 and back after each node): the reference of fp16 storage."""
    h = _half_model(m)
    typed = onnx.shape_inference.infer_shapes(h)
    floats = {v.name for v in list(typed.graph.value_info) + list(typed.graph.output)
              if v.type.tensor_type.elem_type == onnx.TensorProto.FLOAT}
    nodes = []
    for n in h.graph.node:
        casts = []
        for k, t in enumerate(n.output):
            if t in floats:
                raw, half = f"{t}__f32", f"{t}__f16"
                n.output[k] = raw
                casts += [onnx.helper.make_node("Cast", [raw], [half], to=onnx.TensorProto.FLOAT16),
                          onnx.helper.make_node("Cast", [half], [t], to=onnx.TensorProto.FLOAT)]
        nodes += [n] + casts
    del h.graph.node[:]
    h.graph.node.extend(nodes)
    return h


_loaded: dict[str, onnx.ModelProto] = {}


def load(entry) -> onnx.ModelProto:
    """The model with its external data read in (onnxruntime gets it as bytes)."""
    m = _loaded.get(entry["name"])
    if m is None:
        m = _loaded[entry["name"]] = onnx.load(os.path.join(FIXTURES, entry["file"]))
    return m


def describe(entry) -> str:
    return f"{entry['name']} ({entry['about']}; {entry['exporter']} exporter, opset {entry['opset']})"


@pytest.mark.parametrize("prec", ["fp32", "fp16"])
@pytest.mark.parametrize("entry", ENTRIES, ids=[e["name"] for e in ENTRIES])
def test_exported_model(entry, prec, dev):
    x = feeds(entry)
    path = os.path.join(FIXTURES, entry["file"])
    try:
        cm = clss.Model(path, dev, precision=prec, input_shapes=input_shapes(entry))
    except UnsupportedModelError as e:
        ops = sorted({op for _, op, _, _ in e.nodes})
        pytest.fail(f"{describe(entry)} {prec}: clss refuses {len(e.nodes)} node(s), ops "
                    f"{', '.join(ops)}:\n{e}", pytrace=False)
    except ModelError as e:
        pytest.fail(f"{describe(entry)} {prec}: clss cannot load it: {type(e).__name__}: {e}",
                    pytrace=False)
    outs = cm.run(x)
    m = load(entry)
    names = [o["name"] for o in entry["outputs"]]
    assert cm.output_names == names
    if prec == "fp32":
        bad = _differences(outs, run_ort(m, x), names, prec)
    else:
        xh = {k: v.astype(np.float16).astype(np.float32) for k, v in x.items()}
        bad = _differences(outs, run_ort(_half_model(m), xh), names, prec)
        if bad:   # against fp16 storage itself (the docstring)
            stored = _differences(outs, run_ort(_half_storage_model(m), xh), names, prec)
            bad = [] if not stored else bad + ["against the model with every float tensor stored in half:"] + stored
    assert not bad, f"{describe(entry)} {prec} differs from onnxruntime ({TOL[prec]}):\n" + "\n".join(bad)


def _differences(outs, refs, names, prec) -> list[str]:
    bad = []
    for name, r in zip(names, refs):
        c = compare(outs[name], r, TOL[prec])
        if not c.passed:
            bad.append(f"{name}: max abs {c.max_abs:.3g} (scale {np.abs(r).max():.3g}), err/tol "
                       f"{c.ratio:.3g} {c.detail}")
    return bad


def _sha256(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def test_fixtures_match_manifest():
    """Every manifest entry's files exist with the sizes and hashes it records; every file
    in the directory is listed; each is small; every architecture has both exporters."""
    problems = []
    listed = {"manifest.json"}
    for e in ENTRIES:
        assert e["file"] in e["files"], e["name"]
        for f, meta in e["files"].items():
            listed.add(f)
            p = os.path.join(FIXTURES, f)
            if not os.path.isfile(p):
                problems.append(f"{e['name']}: {f} is missing")
                continue
            if os.path.getsize(p) != meta["bytes"] or _sha256(p) != meta["sha256"]:
                problems.append(f"{e['name']}: {f} differs from the manifest (regenerate: make export-fixtures)")
            if meta["bytes"] > MAX_BYTES:
                problems.append(f"{f} is {meta['bytes']} bytes (> {MAX_BYTES})")
    unlisted = sorted(set(os.listdir(FIXTURES)) - listed)
    if unlisted:
        problems.append(f"files not in the manifest: {unlisted}")
    names = [e["name"] for e in ENTRIES]
    if len(set(names)) != len(names):
        problems.append("duplicate names")
    by_arch = {}
    for e in ENTRIES:
        by_arch.setdefault(e["arch"], set()).add(e["exporter"])
    for arch, exps in by_arch.items():
        if exps != {"torchscript", "dynamo"}:
            problems.append(f"{arch}: exporters {sorted(exps)}")
    if len(by_arch) < MIN_ARCHS:
        problems.append(f"{len(by_arch)} architectures (< {MIN_ARCHS})")
    for e in ENTRIES:
        m = onnx.load(os.path.join(FIXTURES, e["file"]), load_external_data=False)
        if m.ir_version > MANIFEST["max_ir_version"] or m.ir_version != e["ir_version"]:
            problems.append(f"{e['name']}: ir_version {m.ir_version}")
        if [i.name for i in m.graph.input if i.name not in {t.name for t in m.graph.initializer}] \
                != [i["name"] for i in e["inputs"]]:
            problems.append(f"{e['name']}: inputs differ from the manifest")
    assert not problems, "\n".join(problems)


def test_onnxruntime_runs_every_fixture():
    """The references themselves: onnxruntime loads and runs every fixture at its shapes."""
    for e in ENTRIES:
        refs = run_ort(load(e), feeds(e))
        assert len(refs) == len(e["outputs"]) and all(np.isfinite(r).all() for r in refs), e["name"]
