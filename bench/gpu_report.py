"""`make gpu-report` (python -m bench.gpu_report): one command that measures a device, GPU or
not, and writes everything into one folder, ready to commit to bench/results/ and to the
shipped tables (clss/tuning_tables/):

  devices.txt      clss devices
  verify.txt       clss verify --precision all on the device (every case and fast path)
  tune.txt         clss tune --level fast: the conv2d variant per layer of the networks at
                   1080p -> 2160p, with each layer's ms, GFLOP/s and share of the FMA peak,
                   then whether each fused frame-step fast path is used (timed with and without)
  tuning.json      the tuning database that tune wrote (the device's measured choices)
  shipped-<class>.json  the same choices (layers and fast paths) as a shipped table for the
                   device's class
  hostwaits/       clss bench --host-waits --full in fp32 and fp16 (every method, 1080p ->
                   2160p included), run with the tuned database: bench.json and bench.md
  report.md, report.json  the commit measured, the device, each step's status and time

Each step runs as a child process with its own time limit, so a step that fails or hangs
is reported and the others still run; the whole report fits in about 8 minutes
(--budget-s splits it). --smoke runs every step at the tiny shapes (a CPU check of the
command itself, tests/test_gpu_report.py)."""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

# (step, share of the budget): verify and the host-wait bench have fixed work; tune takes
# what its --budget allows and stops
SHARES = {"devices": 0.04, "verify": 0.25, "tune": 0.33, "hostwaits": 0.38}


def _clss(*args) -> list[str]:
    return [sys.executable, "-W", "ignore", "-m", "clss", *args]


def steps(out: Path, device: str | None, budget: float, smoke: bool) -> list[tuple[str, list, dict]]:
    dev = ["--device", device] if device else []
    tiny = ["--tiny"] if smoke else []
    tune_budget = max(20.0, SHARES["tune"] * budget - 30)
    env = {"CLSS_TUNING_DB": str(out / "tuning.json")}
    return [
        ("devices", _clss("devices"), {}),
        ("verify", _clss("verify", *dev, "--precision", "all",
                         *(["--level", "tiny", "--family", "conv_gemm"] if smoke else [])), {}),
        ("tune", _clss("tune", "--level", "fast", *dev, "--precision", "fp32,fp16", "--budget", f"{tune_budget:.0f}",
                       "--db", str(out / "tuning.json"),
                       *(["--tiny", "--filter", "classifier,frame step bicubic"] if smoke
                         else ["--tier", "2160p"])), env),
        ("hostwaits", _clss("bench", "--host-waits", *(tiny or ["--full"]), *dev, "--precision", "fp32,fp16",
                            "--out", str(out / "hostwaits")), env),
    ]


def _git(*args) -> str:
    try:
        return subprocess.run(["git", *args], capture_output=True, text=True, timeout=10,
                              cwd=Path(__file__).resolve().parent.parent).stdout.strip()
    except Exception:
        return ""


def shipped_candidate(db: Path, out: Path) -> Path | None:
    """The device's tuned layer choices as a shipped table (clss/tuning_tables/<class>.json):
    the class order kept, the measured layers added."""
    from clss import tuning
    from clss.device import get_device
    if not db.is_file():
        return None
    dev = get_device(os.environ.get("CLSS_REPORT_DEVICE") or None)
    measured = json.loads(db.read_text()).get("devices", {}).get(tuning.device_key(dev), {})
    layers = {k: e["params"] for k, e in measured.get("conv2d", {}).items() if "VARIANT" in e.get("params", {})}
    choices = {op: {k: e["params"]["use"] for k, e in measured.get(op, {}).items()
                    if isinstance(e.get("params", {}).get("use"), bool)} for op in tuning.MEASURED_OPS}
    table = json.loads(json.dumps(tuning.shipped(dev))) or {"class": tuning.device_class(dev), "ops": {}}
    table["measured"] = (f"{dev.info.name} ({dev.info.platform}, driver {dev.info.driver}), "
                         f"{datetime.date.today().isoformat()}, clss tune --level fast at commit {_git('rev-parse', '--short', 'HEAD')}")
    table.setdefault("ops", {}).setdefault("conv2d", {}).setdefault("order", ["direct"])
    table["ops"]["conv2d"]["layers"] = layers
    for op, got in choices.items():     # the frame-step choices measured here (bench/tune_fastpaths.py)
        if got:
            table[op] = {**table.get(op, {}), **got}
    path = out / f"shipped-{tuning.device_class(dev)}.json"
    path.write_text(json.dumps(table, indent=1, sort_keys=True))
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.gpu_report", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=None, help="the report's folder (default bench/results/<date>-<device>-gpu-report)")
    p.add_argument("--device", "-d", default=None, help="the device to measure, as for clss devices (default: a GPU "
                                                         "if there is one, else clss's default)")
    p.add_argument("--budget-s", type=float, default=470.0, help="seconds for the whole report (default 470)")
    p.add_argument("--smoke", action="store_true", help="tiny shapes, one family and one network: check the "
                                                        "command on any machine")
    p.add_argument("--steps", default=",".join(SHARES), help=f"the steps to run (default {','.join(SHARES)})")
    a = p.parse_args(argv)
    device = a.device or _gpu_spec()
    stamp = datetime.date.today().isoformat()
    out = Path(a.out or f"bench/results/{stamp}-{_slug(device)}-gpu-report")
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    status = {}
    env_base = dict(os.environ)
    if device:
        env_base["CLSS_REPORT_DEVICE"] = device
    wanted = [x.strip() for x in a.steps.split(",") if x.strip()]
    if not wanted or set(wanted) - set(SHARES):
        p.error(f"--steps: choose from {', '.join(SHARES)}, got {a.steps!r}")
    for name, cmd, env in steps(out, device, a.budget_s, a.smoke):
        if name not in wanted:
            continue
        limit = max(30.0, SHARES[name] * a.budget_s)
        print(f"gpu-report: {name} (limit {limit:.0f} s): {' '.join(cmd[3:])}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=limit, env={**env_base, **env})
            rc, text = r.returncode, r.stdout + ("\n" + r.stderr[-4000:] if r.returncode else "")
        except subprocess.TimeoutExpired as e:
            rc, text = "timeout", (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) \
                else (e.stdout or "")
        (out / f"{name}.txt").write_text(text)
        status[name] = {"rc": rc, "seconds": round(time.perf_counter() - t0, 1)}
        print(f"gpu-report: {name}: {'ok' if rc == 0 else rc} in {status[name]['seconds']} s", file=sys.stderr)
    shipped = shipped_candidate(out / "tuning.json", out)
    doc = {"commit": _git("rev-parse", "HEAD"), "dirty": bool(_git("status", "--porcelain", "--untracked-files=no")),
           "date": stamp, "device": device or "default", "smoke": a.smoke, "steps": status,
           "seconds": round(time.perf_counter() - t_all, 1),
           "shipped_candidate": shipped.name if shipped else None}
    (out / "report.json").write_text(json.dumps(doc, indent=1))
    lines = [f"# GPU report: {device or 'default device'}, {stamp}", "",
             f"Commit `{doc['commit'][:12]}`{' (with uncommitted changes)' if doc['dirty'] else ''}; "
             f"{doc['seconds']:.0f} s in all{' (smoke: tiny shapes)' if a.smoke else ''}.", "",
             "| step | status | seconds | output |", "|---|---|---|---|"]
    for name, s in status.items():
        lines.append(f"| {name} | {'ok' if s['rc'] == 0 else s['rc']} | {s['seconds']} | `{name}.txt` |")
    for name in ("tune", "verify"):
        if name not in status:
            continue
        text = (out / f"{name}.txt").read_text()
        tail = "\n".join(text.strip().splitlines()[-40:])
        lines += ["", f"## {name}", "", "```", tail, "```"]
    hw = out / "hostwaits" / "bench.md"
    if hw.is_file():
        lines += ["", "## host waits (clss bench --host-waits)", "", hw.read_text()]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print(f"gpu-report: wrote {out} in {doc['seconds']:.0f} s", file=sys.stderr)
    return 0 if all(s["rc"] == 0 for s in status.values()) else 1


def _gpu_spec() -> str | None:
    """The first GPU's index in `clss devices`, else None (clss's default device)."""
    try:
        import pyopencl as cl
        from clss.device import list_devices
        for i, (_, d) in enumerate(list_devices()):
            if d.type & cl.device_type.GPU:
                return str(i)
    except Exception:
        pass
    return None


def _slug(device: str | None) -> str:
    try:
        from clss.device import get_device
        name = get_device(device).info.name
    except Exception:
        name = device or "default"
    return "".join(c if c.isalnum() else "-" for c in name.lower()).strip("-")[:40]


if __name__ == "__main__":
    from clss.exiting import leave
    leave(main())
