"""The engine reads the tuning database (clss/tuning.py) at launch: a stored entry
changes the launch, the results stay right, and absurd entries are ignored."""
import numpy as np
import pytest

from bench.capture import Capture
from clss import device as D, tuning
from clss.tolerance import DEFAULT_TOL, compare
from clss.ops import conv, mlp, space_to_depth as s2d


@pytest.fixture
def db(tmp_path, monkeypatch):
    monkeypatch.setenv("CLSS_TUNING_DB", str(tmp_path / "tuning.json"))
    return tmp_path / "tuning.json"


def _launches(dev, fn, kernel):
    """fn's output, and the global sizes of its launches of `kernel`."""
    cap = Capture(dev, pool=False)
    with cap.active():
        cap.start_run()
        out = dev.to_host(fn())
    return out, [gs for name, gs in cap.launches if name == kernel]


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_stored_conv_block_changes_the_launch(dev, db, precision):
    g = np.random.default_rng(3)
    x = dev.to_device(g.standard_normal((1, 5, 9, 150)).astype(np.float32), precision)
    w = dev.to_device(g.standard_normal((6, 5, 3, 3)).astype(np.float32), precision)

    def run():
        return conv.conv2d(dev, precision, x, w, pads=(1, 1, 1, 1), activation="relu")
    ref, (default_launch,) = _launches(dev, run, "conv2d")
    key = tuning.shape_key((1, 5, 9, 150), (6, 5, 3, 3), "s1x1", precision)
    tuning.store(dev, "conv2d", key, {"XV": 1, "CB": 1})
    out, (tuned_launch,) = _launches(dev, run, "conv2d")
    # XV 2 -> 1 doubles the x blocks; CB 4 -> 1 makes 6 channel blocks of 2
    assert default_launch[0] < tuned_launch[0] and default_launch[2] < tuned_launch[2]
    assert compare(out, ref, DEFAULT_TOL[precision]).passed
    tuning.store(dev, "conv2d", key, {"XV": 4, "CB": 3})       # outside conv.TUNABLES: ignored
    _, (ignored_launch,) = _launches(dev, run, "conv2d")
    assert ignored_launch == default_launch
    # the caller's tuning= beats the database
    _, (explicit_launch,) = _launches(dev, lambda: conv.conv2d(dev, precision, x, w, pads=(1, 1, 1, 1),
                                                               activation="relu", tuning={"XV": 2, "CB": 4}), "conv2d")
    assert explicit_launch == default_launch


def test_stored_mlp_block_and_work_group_size(dev, db, monkeypatch):
    g = np.random.default_rng(4)
    x = dev.to_device(g.standard_normal((1, 6, 7, 9)).astype(np.float32))
    net = mlp.pack(dev, "fp32", [(g.standard_normal((8, 6)).astype(np.float32), None, "relu"),
                                 (g.standard_normal((3, 8)).astype(np.float32), None, "none")])
    ref, (default_launch,) = _launches(dev, lambda: mlp.mlp(dev, "fp32", x, net), "mlp")
    tuning.store(dev, "mlp", tuning.shape_key((1, 6, 7, 9), (6, 8, 3), "fp32"), {"XV": 2, "LX": 8})
    out, (tuned_launch,) = _launches(dev, lambda: mlp.mlp(dev, "fp32", x, net), "mlp")
    assert tuned_launch != default_launch
    assert compare(out, ref, DEFAULT_TOL["fp32"]).passed
    # a stored work-group size reaches launches for which the op sets none
    seen = []
    real = D.cl.enqueue_nd_range_kernel
    monkeypatch.setattr(D.cl, "enqueue_nd_range_kernel",
                        lambda q, k, gs, ls, **kw: seen.append((k.function_name, gs, ls)) or real(q, k, gs, ls, **kw))
    xs = np.arange(2 * 3 * 4 * 16, dtype=np.float32).reshape(2, 3, 4, 16)
    before = s2d.space_to_depth(dev, "fp32", dev.to_device(xs), 2).get()
    (_, gs, ls), = seen
    assert ls == (tuning.balanced_local_size(gs, dev.info.compute_units) if dev.is_cpu else None)
    tuning.store(dev, "local_size:space_to_depth", tuning.shape_key(gs), {"local": [1, 2, 1]})
    after = s2d.space_to_depth(dev, "fp32", dev.to_device(xs), 2).get()
    assert seen[-1][2] == (1, 2, 1)
    assert np.array_equal(before, after)


@pytest.mark.parametrize("gs", [(8100, 1), (1036800,), (60, 540, 2), (960, 540), (7,), (32,), (2025, 1),
                                (97, 13, 3), (1, 1, 1), (4096,), (254, 16)])
@pytest.mark.parametrize("units", [1, 2, 16])
def test_balanced_local_size(gs, units):
    """The CPU work-group size divides the global size, stays within 4096 work-items, and
    leaves at least 8 groups per compute unit wherever the global size has a divisor for
    it; dimension 0 is split last."""
    loc = tuning.balanced_local_size(gs, units)
    assert len(loc) == len(gs) and all(g % l == 0 for g, l in zip(gs, loc))
    assert np.prod(loc) <= 4096
    groups = int(np.prod([g // l for g, l in zip(gs, loc)]))
    if groups < 8 * units:
        # only where dimension 0 is down to its vector's worth (or to its last divisor)
        # and every outer dimension is split to single rows
        assert all(l == 1 for l in loc[1:])
        assert loc[0] <= 16 or gs[0] // loc[0] >= 2 or loc[0] == 1
    if gs == (8100, 1):       # NSRD's LSTM cell: 3 groups of 2700 left to PoCL
        assert groups >= 8 * units and loc[0] >= 16


def test_balanced_local_size_keeps_the_device_limits():
    # oclgrind: 1024 work-items a group, 1024 along each dimension
    loc = tuning.balanced_local_size((4096, 3), 2, 1024, (1024, 1024, 1024))
    assert np.prod(loc) <= 1024 and loc[0] <= 1024 and 4096 % loc[0] == 0
    loc = tuning.balanced_local_size((7, 2048), 1, 4096, (4096, 64, 64))
    assert loc[1] <= 64
