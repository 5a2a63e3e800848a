"""The bench's peers: other CPU runtimes that run the same ONNX twin on the same feeds, in the
same process, alternating with clss (`clss bench --peers ort,openvino`).

A peer gives one or more columns. onnxruntime (`ort`, always installed: it is also the
oracle) gives one; OpenVINO (`openvino`, the optional `[peers]` extra) gives two: `ov_f32`,
its CPU plugin held to f32 arithmetic (INFERENCE_PRECISION_HINT f32: the fair column, beside
onnxruntime), and `ov`, its default precision, what a user gets (bf16 on CPUs with
AVX512_BF16 or AMX, else f32), whose error against the oracle the bench reports beside it.
The fair ratio compares clss with the faster of the f32 columns.
"""
from __future__ import annotations

import json
import os
import re
import tempfile
from dataclasses import dataclass
from typing import Callable

PEERS = ("ort", "openvino")
INSTALL_HINT = "pip install -e '.[peers]'"


@dataclass
class Column:
    key: str                 # the row's key: "ort", "ov_f32", "ov"
    label: str               # a table heading
    fp32: bool               # held to f32 arithmetic: counts for the fair ratio
    # model -> run(feeds) -> outputs (numpy, the twin's output order); profile=True: a run
    # whose per-node times `node_times()` gives
    session: Callable


def parse_peers(spec: str | None, flag: str = "--peers") -> list[str]:
    """The peer names of a comma list (default: ort alone); ValueError naming the flag for
    an unknown peer or one whose runtime is not installed."""
    names = [p.strip().lower() for p in (spec or "ort").split(",") if p.strip()]
    if not names:
        raise ValueError(f"{flag}: name one or more of {', '.join(PEERS)}")
    for n in names:
        if n not in PEERS:
            raise ValueError(f"{flag}: unknown peer {n!r}; the peers are {', '.join(PEERS)}")
    if "openvino" in names and not openvino_available():
        raise ValueError(f"{flag} openvino: OpenVINO is not installed; {INSTALL_HINT}")
    return list(dict.fromkeys(names))


def openvino_available() -> bool:
    import importlib.util
    return importlib.util.find_spec("openvino") is not None


def columns(peers, threads: int, spinning: bool = False) -> list[Column]:
    """The columns of the named peers, in order."""
    out = []
    for p in peers:
        if p == "ort":
            out.append(Column("ort", "onnxruntime", True, lambda m, profile=False: OrtSession(
                m, threads, spinning, profile)))
        elif p == "openvino":
            out.append(Column("ov_f32", "OpenVINO f32", True, lambda m, profile=False: OvSession(
                m, threads, "f32", profile)))
            out.append(Column("ov", f"OpenVINO default ({openvino_default_precision()})", False,
                              lambda m, profile=False: OvSession(m, threads, None, profile)))
    return out


def openvino_default_precision() -> str:
    """What OpenVINO's CPU plugin computes in when not told (bf16 where the CPU has it)."""
    import openvino as ov
    return ov.Core().get_property("CPU", "INFERENCE_PRECISION_HINT").to_string()


def openvino_version() -> str | None:
    try:
        from importlib import metadata
        return metadata.version("openvino")
    except Exception:
        return None


# --- the sessions ------------------------------------------------------------------------

class OrtSession:
    """onnxruntime on the CPU execution provider, as bench/runner.py's OrtRunner builds it;
    profile=True: with its per-node profiler on (enable_profiling)."""

    def __init__(self, model, threads: int, spinning: bool = False, profile: bool = False):
        import onnxruntime as ort
        from .runner import OrtRunner
        self._tmp = None
        if profile:
            self._tmp = tempfile.mkdtemp(prefix="clss-ort-profile-")
        self.sess = OrtRunner(threads, spinning).session(model, profile_prefix=self._tmp and os.path.join(
            self._tmp, "ort"))
        self.outputs = [o.name for o in self.sess.get_outputs()]
        self._ort = ort

    def __call__(self, feeds: dict) -> list:
        return self.sess.run(self.outputs, feeds)

    def node_times(self, runs: int) -> dict:
        """{onnxruntime node name: median ms per run} over the profiled runs so far (the
        first `len - runs` runs are dropped as warm-up); ends the profiling."""
        path = self.sess.end_profiling()
        try:
            events = json.loads(open(path).read())
        finally:
            os.remove(path)
            os.rmdir(self._tmp)
        per: dict[str, list] = {}
        for e in events:
            if e.get("cat") == "Node" and e.get("name", "").endswith("_kernel_time"):
                per.setdefault(e["name"][:-len("_kernel_time")], []).append(e["dur"] * 1e-3)
        return {k: _median(v[-runs:]) for k, v in per.items()}


class OvSession:
    """OpenVINO's CPU plugin on the twin: precision "f32" (INFERENCE_PRECISION_HINT) or None
    for its default; threads as onnxruntime's; profile=True: PERF_COUNT on."""

    def __init__(self, model, threads: int, precision: str | None, profile: bool = False):
        import openvino as ov
        core = ov.Core()
        config = {"INFERENCE_NUM_THREADS": int(threads), "PERFORMANCE_HINT": "LATENCY"}
        if precision:
            config["INFERENCE_PRECISION_HINT"] = precision
        if profile:
            config["PERF_COUNT"] = True
        self.compiled = core.compile_model(core.read_model(model.SerializeToString(), b""), "CPU", config)
        self.req = self.compiled.create_infer_request()
        self.outputs = list(self.compiled.outputs)
        self._times: dict[str, list] = {}
        self.profile = profile

    def __call__(self, feeds: dict) -> list:
        res = self.req.infer(feeds)
        if self.profile:
            for p in self.req.get_profiling_info():
                if p.real_time.total_seconds() > 0:
                    self._times.setdefault(p.node_name, []).append(p.real_time.total_seconds() * 1e3)
        return [res[o] for o in self.outputs]

    def fused_names(self) -> dict:
        """{runtime node name: the ONNX names it stands for} (rt_info originalLayersNames)."""
        out = {}
        for op in self.compiled.get_runtime_model().get_ordered_ops():
            rt = op.get_rt_info()
            names = rt["originalLayersNames"].astype(str) if "originalLayersNames" in rt else ""
            out[op.get_friendly_name()] = [n for n in names.split(",") if n]
        return out

    def node_times(self, runs: int) -> dict:
        return {k: _median(v[-runs:]) for k, v in self._times.items()}


def _median(v):
    import statistics
    return statistics.median(v) if v else 0.0


# onnxruntime and OpenVINO name a node they rewrote after an ONNX node or its output tensor
# with a suffix: "u_nchwc" (ort's NCHWc layout), "Conv_token_3", "y/sink_port_0".
_SUFFIX = re.compile(r"(_nchwc|_token_\d+|/sink_port_\d+|_output_\d+|_fused\w*)$")


def onnx_names(name: str, fused: dict | None = None) -> list[str]:
    """The ONNX node or tensor names a peer's node name may stand for: the names it fused
    (OpenVINO), else the name and the name with each known suffix stripped."""
    if fused and fused.get(name):
        return list(fused[name])
    out = [name]
    while True:
        stripped = _SUFFIX.sub("", out[-1])
        if stripped == out[-1] or not stripped:
            return out
        out.append(stripped)
