"""The conv2d variant table and its chooser (clss/ops/variants.py, clss/ops/conv.py VARIANTS),
the implicit-GEMM rows (kernels/conv_gemm.cl) and the layer tuner (bench/tune_layers.py).
The rows' conformance against onnxruntime, on every device, is tests/test_ops_conformance.py
(clss/verify/cases/conv_gemm.py); oclgrind runs their tiny cases (tests/test_oclgrind.py). The
winograd_gemm row (clss/ops/conv_winograd_gemm.py) runs its products through the same GEMMs."""
import json

import numpy as np
import pytest

from clss import selfcheck, tuning
from clss.ops import conv, conv_gemm, conv_winograd_gemm, variants
from clss.tolerance import DEFAULT_TOL, compare

LAYER = dict(x=(1, 6, 9, 13), w=(11, 6, 3, 3), pads=(1, 1, 1, 1))


@pytest.fixture
def db(tmp_path, monkeypatch):
    path = tmp_path / "tuning.json"
    monkeypatch.setenv("CLSS_TUNING_DB", str(path))
    return path


def _layer(**kw):
    d = {**LAYER, **kw}
    return conv.ConvLayer(d["x"], d["w"], (1, 1), d["pads"], (1, 1), 1)


def _tensors(dev, prec="fp32", seed=0):
    g = np.random.default_rng(seed)
    x = dev.to_device(g.standard_normal(LAYER["x"]).astype(np.float32), prec)
    w = dev.to_device(g.standard_normal(LAYER["w"]).astype(np.float32) * 0.2, prec)
    b = dev.to_device(g.standard_normal(LAYER["w"][0]).astype(np.float32), prec)
    return x, w, b


def _conv(dev, x, w, b, prec="fp32", **kw):
    return dev.to_host(conv.conv2d(dev, prec, x, w, b, pads=LAYER["pads"], activation="relu", **kw))


def test_every_row_is_described_and_the_direct_row_takes_any_nchw_layer(dev):
    names = [v.name for v in conv.VARIANTS]
    assert len(set(names)) == len(names)
    assert {"thin", "winograd", "blocked", "direct", "gemm", "gemm_global", "mma"} <= set(names)
    layer = _layer()
    rows = variants.candidates(dev, "fp32", conv.VARIANTS, layer)
    assert "direct" in [r.name for r in rows]
    # the tensor-core row takes half storage on NVIDIA only
    assert "mma" not in [r.name for r in rows]


def test_a_tuned_entry_beats_the_shipped_order_and_the_caller_beats_both(dev, db):
    layer = _layer()
    key = conv.layer_key(layer, "fp32")
    assert variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer).name != "gemm_global"
    tuning.store(dev, "conv2d", key, {"VARIANT": "gemm_global", "RM": 2, "RN": 2}, path=db)
    assert variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer).name == "gemm_global"
    assert conv.describe_choice(dev, "fp32", layer.x, layer.w, pads=layer.pads) == "gemm_global (tuned)"
    assert variants.params(dev, "conv2d", key, "gemm_global", conv_gemm.DEFAULTS)["RM"] == 2
    # ...the tuned row's tiles apply to that row only
    assert variants.params(dev, "conv2d", key, "gemm", conv_gemm.DEFAULTS)["RM"] == conv_gemm.DEFAULTS["RM"]
    chosen = variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer, explicit={"VARIANT": "gemm"})
    assert chosen.name == "gemm"
    # a stale entry (other kernel sources: another key) is never read
    other = conv.layer_key(_layer(pads=(0, 0, 0, 0)), "fp32")
    assert other != key and tuning.entry(dev, "conv2d", other) is None


def test_a_row_whose_self_check_fails_is_never_launched_whatever_the_tables_say(dev, db):
    layer = _layer()
    key = conv.layer_key(layer, "fp32")
    tuning.store(dev, "conv2d", key, {"VARIANT": "gemm"}, path=db)
    with selfcheck.forcing("conv.gemm", False):
        assert variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer).name != "gemm"
    with selfcheck.forcing("conv.gemm", True):
        assert variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer).name == "gemm"


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("row", ["gemm", "gemm_global"])
@pytest.mark.parametrize("tiles", [{}, {"TM": 16, "TN": 32, "TK": 8, "RM": 2, "RN": 4},
                                   {"TM": 32, "TN": 16, "TK": 32, "RM": 8, "RN": 1}],
                         ids=["default", "16x32", "32x16"])
def test_gemm_rows_and_their_tiles_agree_with_the_direct_kernel(dev, precision, row, tiles):
    x, w, b = _tensors(dev, precision)
    ref = _conv(dev, x, w, b, precision, tuning={"VARIANT": "direct"}).astype(np.float32)
    with selfcheck.forcing(f"conv.{row}", True):
        out = _conv(dev, x, w, b, precision, tuning={"VARIANT": row, **tiles}).astype(np.float32)
    tol = 1e-5 if precision == "fp32" else 2e-3
    np.testing.assert_allclose(out, ref, rtol=tol, atol=tol)


def test_the_emulated_tensor_core_layout_matches_the_fp16_reference(dev):
    # CONV_MMA=1: the fragments of mma.sync m16n8k16 placed as the PTX ISA places them and
    # multiplied in scalar code; a wrong fragment map (row gid + 8 for a[2] instead of a[1],
    # say) puts products in the wrong accumulators and this fails
    from clss.verify.cases import conv_gemm as cases
    from clss.verify.conformance import check
    for case in cases.cases("tiny"):
        if "mma_emulated" in case.variant:
            assert check(case, dev, "fp16").passed, case.variant


def test_bad_tiles_are_a_clear_error(dev):
    x, w, b = _tensors(dev)
    with selfcheck.forcing("conv.gemm", True), pytest.raises(ValueError, match="multiple of RM"):
        _conv(dev, x, w, b, tuning={"VARIANT": "gemm", "TM": 16, "RM": 3})


@pytest.mark.parametrize("platform,name,cpu,width,expected", [
    ("NVIDIA CUDA", "NVIDIA H200", False, 1, "nvidia"),
    ("AMD Accelerated Parallel Processing", "gfx1100", False, 1, "amd"),
    ("Intel(R) OpenCL Graphics", "Intel(R) Arc(TM) A770", False, 1, "intel-gpu"),
    ("Portable Computing Language", "pthread-skylake-avx512-AMD EPYC", True, 16, "cpu-avx512"),
    ("Portable Computing Language", "pthread-haswell-AMD EPYC", True, 8, "cpu-avx2"),
    ("Some Vendor", "accelerator", False, 1, "default")])
def test_device_classes_pick_a_shipped_table(platform, name, cpu, width, expected):
    class Info:
        pass
    info = Info()
    info.platform, info.name, info.vendor = platform, name, ""

    class CL:
        preferred_vector_width_float = width

    class Dev:
        pass
    d = Dev()
    d.info, d.is_cpu, d.cl_device = info, cpu, CL()
    assert tuning.device_class(d) == expected
    table = json.loads((tuning.SHIPPED_DIR / f"{expected}.json").read_text())
    assert table["class"] == expected and table["measured"]
    order = table["ops"]["conv2d"]["order"]
    assert set(order) <= {v.name for v in conv.VARIANTS} and "direct" in order


def test_the_layer_tuner_stores_a_checked_choice_that_conv2d_then_runs(dev, db):
    from bench import tune_layers
    layer = _layer()
    logs = []
    res = tune_layers.tune_layer(dev, "fp32", layer, level="fast", runs=2, db=db, log=logs.append)
    names = [t[0] for t in res.trials]
    assert "direct" in names and "gemm" in names
    assert all(t[3] == "pass" for t in res.trials), res.trials
    stored = tuning.entry(dev, "conv2d", conv.layer_key(layer, "fp32"))
    assert stored["params"]["VARIANT"] == res.best and stored["default"] == res.default
    assert conv.describe_choice(dev, "fp32", layer.x, layer.w, pads=layer.pads) == f"{res.best} (tuned)"
    assert "GFLOP/s" in tune_layers.format_layers([res], 100.0)


def test_the_layer_tuner_rejects_a_wrong_variant(dev, db, monkeypatch):
    from bench import tune_layers
    _gemm_off_by_one(monkeypatch)
    res = tune_layers.tune_layer(dev, "fp32", _layer(), level="fast", runs=1, db=db, log=lambda m: None)
    assert any(t[0] == "gemm" and t[3].startswith("wrong") for t in res.trials)
    assert res.best != "gemm"


def _gemm_off_by_one(monkeypatch):
    """conv2d_gemm's outputs, one too large: a row that compiles and runs but is wrong."""
    real = conv_gemm.launch

    def off_by_one(dev_, prec, *a, **kw):
        out = real(dev_, prec, *a, **kw)
        out.set((out.get() + 1).astype(out.dtype))
        return out
    monkeypatch.setattr(conv_gemm, "launch", off_by_one)


def _probing(monkeypatch, rows=("gemm",)):
    """The GPU rows' first-use probe, turned on for `rows` on this (CPU) device, with an empty
    in-process memo of probed layers."""
    import dataclasses
    from clss.ops import variants
    monkeypatch.setattr(variants, "_probed", {})
    table = tuple(dataclasses.replace(v, probe=lambda d: True) if v.name in rows else v
                  for v in conv.VARIANTS)
    monkeypatch.setattr(conv, "VARIANTS", table)


def test_a_probed_row_is_timed_at_first_use_and_the_choice_is_stored(dev, db, monkeypatch):
    _probing(monkeypatch)
    calls = []
    real = conv_probe_module().probe
    monkeypatch.setattr(conv_probe_module(), "probe", lambda *a, **kw: (calls.append(a[2]), real(*a, **kw)))
    x, w, b = _tensors(dev)
    with selfcheck.forcing("conv.gemm", True):
        first = _conv(dev, x, w, b)
        key = conv.layer_key(_layer(), "fp32")
        stored = tuning.entry(dev, "conv2d", key)
        assert stored["probed"] is True and stored["params"]["VARIANT"] in ("gemm", stored["default"])
        assert set(stored["trials"]) == {"gemm", stored["default"]}
        again = _conv(dev, x, w, b)         # the stored choice: no second probe
    assert calls == [key]
    np.testing.assert_allclose(first, again, rtol=1e-5, atol=1e-5)


def test_the_probe_rejects_a_row_that_disagrees_on_the_layer(dev, db, monkeypatch):
    _probing(monkeypatch)
    _gemm_off_by_one(monkeypatch)
    x, w, b = _tensors(dev)
    with selfcheck.forcing("conv.gemm", True):
        _conv(dev, x, w, b)
    stored = tuning.entry(dev, "conv2d", conv.layer_key(_layer(), "fp32"))
    assert stored["params"]["VARIANT"] != "gemm" and str(stored["trials"]["gemm"]).startswith("wrong")


def test_no_probe_where_a_table_names_the_row_or_clss_probe_is_off(dev, db, monkeypatch):
    _probing(monkeypatch)
    calls = []
    monkeypatch.setattr(conv_probe_module(), "probe", lambda *a, **kw: calls.append(a))
    x, w, b = _tensors(dev)
    monkeypatch.setenv("CLSS_PROBE", "0")
    _conv(dev, x, w, b)
    monkeypatch.delenv("CLSS_PROBE")
    tuning.store(dev, "conv2d", conv.layer_key(_layer(), "fp32"), {"VARIANT": "direct"}, path=db)
    _conv(dev, x, w, b)
    assert calls == []


def conv_probe_module():
    from clss.ops import conv_probe
    return conv_probe


def test_clss_verify_lists_every_conv_row_and_its_state_on_the_device(dev):
    from clss.verify.conformance import format_variants
    text = format_variants(dev, ["fp32"], [])
    assert tuning.device_class(dev) in text
    for row in conv.VARIANTS:
        assert f"  {row.name} " in text
    if dev.is_cpu:
        assert "mma          fp32 does not apply here" in text


def test_a_device_with_small_work_groups_gets_larger_register_tiles(dev):
    # the default 64 x 64 tile needs 256 work-items at RM = RN = 4; a device that allows 64
    # runs the same tile with 8 x 8 per work-item, and the same result
    class Small:
        max_work_group_size = 64

    class Dev:
        def __init__(self, real):
            self._real, self.cl_device = real, Small()

        def __getattr__(self, name):
            return getattr(self._real, name)
    launched = []
    small = Dev(dev)
    small.launch = lambda k, gs, args, local_size=None: launched.append(local_size) or dev.launch(
        k, gs, args, local_size=local_size)
    x, w, b = _tensors(dev)
    ref = _conv(dev, x, w, b, tuning={"VARIANT": "direct"})
    layer = _layer()
    out = dev.empty(ref.shape, "fp32")
    call = conv.ConvCall(x, w, b, None, "relu", 0.01, None, True, out, ref.shape[2], ref.shape[3], None)
    conv_gemm.launch(small, "fp32", layer, call, conv._act("relu"), conv._flags(b, None, True),
                     key=conv.layer_key(layer, "fp32"), variant="gemm")
    assert launched[0][0] * launched[0][1] <= 64
    np.testing.assert_allclose(dev.to_host(out), ref, rtol=1e-5, atol=1e-5)


def test_a_probe_runs_once_per_layer_even_where_the_cache_cannot_be_written(dev, db, monkeypatch):
    from clss.ops import variants
    _probing(monkeypatch)
    monkeypatch.setattr(variants, "_probed", {})
    calls = []

    def failing_store(*a, **kw):
        calls.append(1)
        raise PermissionError("read-only cache")
    monkeypatch.setattr(tuning, "store", failing_store)
    x, w, b = _tensors(dev)
    with selfcheck.forcing("conv.gemm", True), pytest.warns(UserWarning, match="probing the variants"):
        first = _conv(dev, x, w, b)
    with selfcheck.forcing("conv.gemm", True):
        again = _conv(dev, x, w, b)
    assert calls == [1]
    np.testing.assert_allclose(first, again, rtol=1e-5, atol=1e-5)


# winograd_gemm's layers: (batch, in, out, (h, w), pads, activation, residual). Whole tiles; prime
# sizes and channel counts (partial tiles, ragged GEMM tiles); asymmetric pads and a batch;
# pads of 2 on a tiny image (tiles mostly padding)
WINOGRAD_LAYERS = [(1, 16, 16, (8, 8), (1, 1, 1, 1), "relu", None),
                   (1, 19, 23, (13, 17), (1, 1, 1, 1), "tanh", "before"),
                   (2, 17, 31, (7, 11), (0, 2, 2, 0), "leaky_relu", "after"),
                   (1, 16, 20, (5, 3), (2, 2, 2, 2), "sigmoid", "after")]


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("gemm", ["gemm", "gemm_global", "mma_emulated"])
def test_the_winograd_gemm_row_agrees_with_the_direct_row(any_dev, precision, gemm):
    if gemm == "mma_emulated" and precision != "fp16":
        pytest.skip("the tensor-core layout takes half storage")
    from clss.verify.cases.conv_gemm import WINOGRAD_MMA_TOL
    tol = WINOGRAD_MMA_TOL[precision] if gemm == "mma_emulated" else DEFAULT_TOL[precision]
    g = np.random.default_rng(3)
    for n, cin, cout, (h, w), pads, act, res in WINOGRAD_LAYERS:
        x = any_dev.to_device(g.standard_normal((n, cin, h, w)).astype(np.float32), precision)
        wt = any_dev.to_device((g.standard_normal((cout, cin, 3, 3)) / np.sqrt(9 * cin)).astype(np.float32),
                               precision)
        b = any_dev.to_device(g.standard_normal(cout).astype(np.float32), precision)
        ho, wo = h + pads[0] + pads[2] - 2, w + pads[1] + pads[3] - 2
        r = any_dev.to_device(g.standard_normal((n, cout, ho, wo)).astype(np.float32), precision) if res else None
        kw = dict(pads=pads, activation=act, alpha=0.2, residual=r, residual_before_act=res == "before")
        ref = any_dev.to_host(conv.conv2d(any_dev, precision, x, wt, b, tuning={"VARIANT": "direct"}, **kw))
        with selfcheck.forcing("conv.winograd_gemm", True), selfcheck.forcing("conv.gemm", True), \
                selfcheck.forcing("conv.gemm_global", True):
            out = any_dev.to_host(conv.conv2d(any_dev, precision, x, wt, b, tuning={
                "VARIANT": "winograd_gemm", "GEMM": gemm}, **kw))
        c = compare(np.asarray(out, np.float32), np.asarray(ref, np.float32), tol)
        assert c.passed, ((n, cin, cout, h, w, pads), c.detail)


def test_winograd_gemm_takes_dense_3x3_unit_stride_layers_of_16_channels_and_a_cpu_only_when_forced(dev, db):
    layer = conv.ConvLayer((1, 16, 9, 9), (16, 16, 3, 3), (1, 1), (1, 1, 1, 1), (1, 1), 1)
    assert conv_winograd_gemm.eligible(layer) and conv_winograd_gemm.eligible(layer._replace(pads=(0, 2, 2, 0)))
    for other in (layer._replace(strides=(2, 2)), layer._replace(dilations=(2, 2)), layer._replace(w=(15, 16, 3, 3)),
                  layer._replace(x=(1, 15, 9, 9), w=(16, 15, 3, 3)), layer._replace(x=(1, 32, 9, 9), group=2),
                  layer._replace(w=(16, 16, 5, 5)), layer._replace(block_in=16)):
        assert not conv_winograd_gemm.eligible(other), other
    row = next(v for v in conv.VARIANTS if v.name == "winograd_gemm")
    assert row.probe(dev) == (not dev.is_cpu)
    key = conv.layer_key(layer, "fp32")
    if dev.is_cpu:      # CPUs never probe: their tables were measured, and it is not in them
        assert variants.choose(dev, "fp32", "conv2d", key, conv.VARIANTS, layer).name != "winograd_gemm"
    # the GEMM of its step 2 is a tuning parameter like its tiles: the tuned entry's, the caller's
    assert conv_winograd_gemm._gemm(dev, "fp32", key, None) == (1, 0)
    tuning.store(dev, "conv2d", key, {"VARIANT": "winograd_gemm", "GEMM": "gemm_global", "TM": 32}, path=db)
    with selfcheck.forcing("conv.gemm_global", True):
        assert conv_winograd_gemm._gemm(dev, "fp32", key, None) == (0, 0)
        assert variants.params(dev, "conv2d", key, "winograd_gemm", conv_gemm.DEFAULTS)["TM"] == 32
        assert conv_winograd_gemm._gemm(dev, "fp16", key, {"GEMM": "mma_emulated"}) == (1, 1)
    with selfcheck.forcing("conv.gemm_global", False):    # its self-check failed: the row's own GEMM,
        assert conv_winograd_gemm._gemm(dev, "fp32", key, None) == (1, 0)
        with pytest.raises(ValueError, match="not used on this device"):    # or the caller's error
            conv_winograd_gemm._gemm(dev, "fp32", key, {"GEMM": "gemm_global"})
    with pytest.raises(ValueError, match="fp16 storage"):
        conv_winograd_gemm._gemm(dev, "fp32", key, {"GEMM": "mma"})
