"""A frame enqueued without host waits (issue 19, section 4): between the first and the
last op of a frame step no queue.finish(), no blocking wait and only one host read, the
end-of-frame flags, enqueued last; clss.Model replays a launch plan bound once."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

import clss
from clss.pipeline.contract import FrameInputError

H, W = 20, 36


def _frame(seed=0):
    g = np.random.default_rng(seed)
    return (g.uniform(0, 2, (H, W, 3)).astype(np.float32), g.uniform(0.1, 1, (H, W)).astype(np.float32),
            g.uniform(-1, 1, (H, W, 2)).astype(np.float32))


class Calls:
    """Counts what the host asks of the queue while a frame is enqueued."""

    def __init__(self, monkeypatch):
        self.log = []
        real_finish, real_copy, real_wait = cl.CommandQueue.finish, cl.enqueue_copy, cl.Event.wait
        monkeypatch.setattr(cl.CommandQueue, "finish", lambda q: (self.log.append("finish"), real_finish(q))[1])

        def copy(queue, dest, src, **kw):
            self.log.append("read" if isinstance(dest, np.ndarray) else
                            "write" if isinstance(src, np.ndarray) else "copy")
            return real_copy(queue, dest, src, **kw)
        monkeypatch.setattr(cl, "enqueue_copy", copy)
        monkeypatch.setattr(cl.Event, "wait", lambda e: (self.log.append("wait"), real_wait(e))[1])


@pytest.mark.parametrize("method", ["clss", "clss-rules", "jbicubic"])
@pytest.mark.parametrize("profile", [False, True])
def test_frame_step_enqueues_without_host_waits(dev, monkeypatch, method, profile):
    up = clss.Upscaler(method=method, scale=2.0, device=dev, profile=profile,
                       **({"weights": "untrained"} if method == "clss" else {}))
    color, depth, motion = (dev.to_device(a) for a in _frame())
    up.step_device(color, depth, motion, (0.25, -0.25), reset=True)     # builds everything
    fs = up._fs
    calls = Calls(monkeypatch)
    launches = []
    real = cl.enqueue_nd_range_kernel
    monkeypatch.setattr(cl, "enqueue_nd_range_kernel",
                        lambda *a, **k: (launches.append(a[1].function_name), real(*a, **k))[1])
    ev = fs.run(color, depth, motion, None, (0.25, -0.25), False)
    # one host read, the flags, and it is the frame's last command; nothing waited for
    assert calls.log == ["read"], calls.log
    assert launches[-1] in ("resolve", "compose") and len(launches) >= 4
    ev.wait()
    fs.accept()
    if profile:
        st = up.stage_ms()
        assert all(v >= 0 for v in st.values())
        if method == "clss":
            assert st["classifier"] > 0       # its kernels' events, summed


def test_refused_frame_leaves_history(dev):
    """The flags read moved to the end of the frame: a NaN input still refuses the frame
    and the history stays as it was."""
    up = clss.Upscaler(method="clss", scale=2.0, device=dev, weights="untrained")
    c, d, m = _frame()
    up.step(c, d, m, (0.25, -0.25), reset=True)
    up.step(c, d, m, (-0.25, 0.25))
    before = up.state["history"].copy()
    bad = c.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(FrameInputError):
        up.step(bad, d, m, (0.25, 0.25))
    np.testing.assert_array_equal(up.state["history"], before)
    out = up.step(c, d, m, (0.25, 0.25))
    assert np.isfinite(out).all()


def test_model_launch_plan_replays_bit_identical(dev):
    """run_device with `out`: recorded once per buffer set, then replayed, with the same
    result as the unrecorded path; new buffers re-record."""
    from clss.model import Model
    from clss.methods.clss.networks import CLASSIFIER_CHANNELS, build_classifier
    shape = (1, CLASSIFIER_CHANNELS, 32, 48)
    m = Model(build_classifier(), device=dev, input_shapes={"x": shape})
    x = np.random.default_rng(1).uniform(0, 1, shape).astype(np.float32)
    want = m.run({"x": x})
    name = m.output_names[0]
    dx = dev.to_device(x)
    out = dev.empty(m.output_shapes[name])
    m.run_device({"x": dx}, out={name: out})
    assert m._launch_plan is not None
    plan = m._launch_plan
    out.fill(0)
    events = []
    res = m.run_device({"x": dx}, out={name: out}, events=events)
    assert m._launch_plan is plan and res[name] is out and len(events) == len(plan[1])
    np.testing.assert_array_equal(out.get(), want[name])
    dx2 = dev.to_device(x)
    m.run_device({"x": dx2}, out={name: out})
    assert m._launch_plan is not plan
    np.testing.assert_array_equal(out.get(), want[name])
    # alternating buffer sets (a double-buffered caller) replay both plans
    plan2 = m._launch_plan
    out.fill(0)
    m.run_device({"x": dx}, out={name: out})
    assert m._launch_plan is plan
    np.testing.assert_array_equal(out.get(), want[name])
    m.run_device({"x": dx2}, out={name: out})
    assert m._launch_plan is plan2
