"""The bicubic room (clss/methods/bicubic/): its frame step stays on the device, and its
step agrees with its whole-frame ONNX twin (the twin check for every method, at odd and
prime sizes in both precisions, is tests/test_methods.py's)."""
from __future__ import annotations

import numpy as np
import pytest

import clss
from clss.pipeline.contract import output_size
from helpers import frames

RENDER = (13, 17)          # odd and prime: partial vectors, unpadded rows


def test_bicubic_device_path_stays_on_the_device(dev, monkeypatch):
    import pyopencl.array as cla
    f = frames(RENDER, 1)[0]
    up = clss.Upscaler(method="bicubic", device=dev)
    want = up.step(f.color)
    c = dev.to_device(f.color)

    def no_copy(*args, **kwargs):
        raise AssertionError("step_device copied through the host")
    monkeypatch.setattr(cla.Array, "get", no_copy)
    monkeypatch.setattr(cla.Array, "set", no_copy)
    out = up.step_device(c)
    monkeypatch.undo()
    assert np.array_equal(out.get(), want)


@pytest.mark.parametrize("scale", [1.5, 2.0, 3.0])
def test_bicubic_matches_its_twin_at_fractional_and_integer_scales(scale, dev):
    # fp32: |d| <= 1e-4 * max|ref| + 1e-4 * |ref| (the PQ transfer on the device against
    # onnxruntime's Pow), every pixel
    from clss.methods.bicubic.oracle import OracleBicubic
    f = frames(RENDER, 1)[0]
    got = clss.Upscaler(method="bicubic", scale=scale, device=dev).step(f.color)
    ref = OracleBicubic(RENDER, scale).step(f.color)
    assert got.shape == ref.shape == (*output_size(*RENDER, scale), 3)
    assert np.all(np.abs(got - ref) <= 1e-4 * np.abs(ref).max() + 1e-4 * np.abs(ref))


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
@pytest.mark.parametrize("render, scale", [((13, 17), 2.0), ((9, 27), 2.0), ((7, 9), 1.5)])
def test_bicubic_fused_path_matches_the_three_passes(render, scale, precision, dev):
    # the fast path bicubic.fused8 (float8 encode; cubic + decode in one pass, at 2x from one
    # window of 8 inputs per row) against the reference's encode, resize and decode, at the
    # bound the self-check uses (the twin test's), and both against the twin
    from clss import selfcheck
    from clss.methods.bicubic.oracle import OracleBicubic
    from clss.methods.bicubic.upscaler import FUSED, _tolerance
    from clss.tolerance import compare
    if not dev.is_cpu:
        pytest.skip("bicubic.fused8 is a CPU fast path")
    f = frames(render, 1)[0]
    out = {}
    for fast in (False, True):
        with selfcheck.forcing(FUSED, fast):
            out[fast] = clss.Upscaler(method="bicubic", scale=scale, device=dev,
                                      precision=precision).step(f.color * 8)
    c = compare(out[True], out[False], _tolerance(precision))
    assert c.passed, c.detail
    if precision == "fp32":
        ref = OracleBicubic(render, scale).step(f.color * 8)
        assert np.all(np.abs(out[True] - ref) <= 1e-4 * np.abs(ref).max() + 1e-4 * np.abs(ref))


OCLGRIND_SCRIPT = """
import numpy as np, warnings
warnings.simplefilter("ignore")
from clss.device import get_device
from clss.methods.bicubic import upscaler as U
from clss.ops.resize import cubic_tables
from clss.pipeline.contract import output_size
dev = get_device()
rng = np.random.default_rng(0)
i32, f = np.int32, np.float32
prec, clang = "{prec}", {clang}
if True:
    for (h, w), s in (((5, 13), 2.0), ((7, 9), 1.5), ((9, 27), 2.0)):
        H, W = output_size(h, w, s)
        fs = U.BicubicFrame(dev, prec, (h, w), s)
        c = dev.to_device(rng.uniform(0, 40, (h, w, 3)).astype(np.float32))
        d = dict(BICUBIC_FUSED=1, CLSS_CLANG_VECTORS=clang, SCALE2=int((H, W) == (2 * h, 2 * w)))
        _, idx, wt = cubic_tables(dev, prec, (h, w), (H, W))
        dev.launch(dev.kernel(U.KERNEL, "bicubic_encode8", prec, **d), (-(-w // 8), h),
                   (c.data, fs.x.data, i32(h), i32(w), f(1), f(0.01)))
        dev.launch(dev.kernel(U.KERNEL, "bicubic_resize_decode8", prec, **d), (-(-W // 8), H),
                   (fs.x.data, fs.out.data, i32(h), i32(w), i32(H), i32(W), f(100), idx.data,
                    wt.data)).wait()
        assert np.isfinite(fs.out.get()).all()
print("bicubic kernels ok")
"""


@pytest.mark.oclgrind
# clang vector loads (and the 2x window) in fp32; the builtin loads in fp32 and fp16 (oclgrind
# cannot simulate clang's half vector conversions). One process each: run one after the
# other in one process, the third reported uninitialised values in the output of a launch
# that is clean alone and in each pair (the oclgrind quirk of tests/test_oclgrind.py's
# blocked conv and test_method_clss_frame.py's refused frames).
@pytest.mark.parametrize("prec, clang", [("fp32", 1), ("fp32", 0), ("fp16", 0)])
def test_bicubic_fused_kernels_clean_under_oclgrind(prec, clang, tmp_path):
    """bicubic_encode8 and bicubic_resize_decode8 (fast path bicubic.fused8) on odd sizes,
    at 2x (row tails, the window inside and the gathers at the edges) and 1.5x, under
    oclgrind's out-of-bounds, uninitialised-read and data-race checks."""
    import os
    import subprocess
    import sys
    from helpers import DIAGNOSTIC, ICD, oclgrind_env
    if not os.path.exists(ICD):
        pytest.skip("oclgrind not installed (apt-get install oclgrind)")
    env = oclgrind_env(tmp_path)
    env["PYTHONPATH"] = os.pathsep.join([os.getcwd(), env.get("PYTHONPATH", "")])
    p = subprocess.run([sys.executable, "-W", "ignore", "-c", OCLGRIND_SCRIPT.format(prec=prec, clang=clang)], env=env,
                       capture_output=True, text=True, timeout=900)
    diags = [line for line in p.stderr.splitlines() if DIAGNOSTIC.search(line)]
    assert not diags, "oclgrind reported:\n" + "\n".join(p.stderr.splitlines()[:60])
    assert p.returncode == 0 and "bicubic kernels ok" in p.stdout, p.stdout[-3000:] + p.stderr[-3000:]
