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
