"""`clss bench` and `clss tune` (also `python -m bench`)."""
from __future__ import annotations

import argparse
import fnmatch
import sys
import time
from pathlib import Path

from clss.cli.args import (DEVICE_HELP, ArgParser, UsageError, check_output_file, device_spec, positive_float,
                           positive_int, prepare_output_dir)
from clss.errors import cli_message

LEVEL_HELP = ("Tiers are named by the frame's output resolution, whatever the method: [1080p] is a "
              "1080x1920 output (render 540x960 at 2x, 360x640 at 3x, 270x480 at 4x), [2160p] a "
              "2160x3840 one. --quick: a small subset (about a minute); default: every kernel at the "
              "CLSS 540p -> 1080p shapes, the CLSS networks and the frame steps at 1080p, but NSRR's, "
              "NSRD's and NSS's (minutes: `--list` says why); --full: adds those and the 2160p tier "
              "(CLSS 1080p -> 2160p)")
FULL_HELP = "also the NSRR, NSRD and NSS networks, layers and frame steps, and the 2160p-output tier"


def _level(a) -> str:
    if a.quick and a.full:
        raise UsageError("--quick and --full exclude each other")
    return "quick" if a.quick else "full" if a.full else "default"


def _precisions(dev, spec: str | None, level: str) -> list[str]:
    if spec is None:
        spec = "fp32" if level == "quick" else "all"
    if spec == "all":
        return ["fp32", "fp16"] + (["fp16-native"] if dev.has_fp16 else [])
    out = [p.strip() for p in spec.split(",") if p.strip()]
    for p in out:
        dev.require(p)
    return out


def _select(cases, pattern: str | None):
    if not pattern:
        return cases
    pats = [p.strip().lower() for p in pattern.split(",") if p.strip()]

    def hit(c):
        text = f"{c.name} {c.family} {c.kind} {c.tier}".lower()
        return any(fnmatch.fnmatch(c.name.lower(), p) if any(ch in p for ch in "*?[") else p in text
                   for p in pats)
    return [c for c in cases if hit(c)]


def _quiet_family_warnings():
    # Families not landed yet are listed once as "not benchmarked"; clss.Model would
    # repeat the warning for every network it loads.
    import warnings
    warnings.filterwarnings("ignore", message="op family .* is missing")


def _logger(bar):
    def log(msg):
        if hasattr(bar, "write"):
            bar.write(msg, file=sys.stderr)
        else:
            print(msg, file=sys.stderr, flush=True)
    return log


def _bench_parser() -> ArgParser:
    p = ArgParser(
        prog="clss bench",
        description="Benchmark every clss kernel, the methods' networks and their conv layers, and every "
                    "method's frame step against onnxruntime running the same ONNX twin on the CPU, in one "
                    "process, alternating, after warm-up. Reports median and min wall time, OpenCL event time, GFLOP/s "
                    "or GB/s, onnxruntime time / engine time, and the share of the device's measured peak "
                    "(FMA and stream probes). " + LEVEL_HELP + ".",
        epilog="examples:\n  clss bench --quick\n  clss bench --filter conv --precision fp32 --out out/bench\n"
               "  clss bench --full --json full.json\n  clss bench --methods --full -p fp32\n"
               "  clss bench --compare before.json after.json",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="a small subset that finishes in about a minute")
    p.add_argument("--full", action="store_true", help=FULL_HELP)
    p.add_argument("--tiny", action="store_true",
                   help="tiny shapes and a brief peak probe: a smoke test of the bench itself (numbers meaningless)")
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    p.add_argument("--precision", "-p", default=None,
                   help="fp32, fp16, fp16-native, a comma list, or all (default: fp32 with --quick, else all "
                        "the device supports)")
    p.add_argument("--filter", "-k", default=None,
                   help="only cases whose name/family contains this (comma list; * ? [ make it a glob on the name)")
    p.add_argument("--out", "-o", default="out/bench",
                   help="directory for bench.json, bench.md and roofline.png (default: out/bench; '' for none)")
    p.add_argument("--json", metavar="FILE", help="also write the JSON result here")
    p.add_argument("--runs", type=positive_int, default=None,
                   help="timed runs per case (default: by a time budget, 3..15)")
    p.add_argument("--budget", type=positive_float, default=None,
                   help="seconds of timed runs per case (default 4, quick 1.5)")
    p.add_argument("--ort-threads", type=positive_int, default=None,
                   help="onnxruntime intra-op threads (default: cores)")
    p.add_argument("--ort-spinning", action="store_true",
                   help="let onnxruntime's idle workers spin (its default; off here because they would "
                        "compete with the engine for the cores between alternating runs)")
    p.add_argument("--no-peak", action="store_true", help="skip the peak probes (no 'of peak' column)")
    p.add_argument("--no-check", action="store_true", help="skip the one-time output check per case")
    p.add_argument("--host-waits", action="store_true",
                   help="instead of the cases: wall time per frame step against its summed OpenCL event "
                        "time and the host's enqueue time, per method (clss, clss-rules, jbicubic, mlp, nsrr, "
                        "nsrd, nss) at 270p -> 540p and 540p -> 1080p after warm-up frames, with --full also "
                        "1080p -> 2160p (--tiny: the tiny tier's 16x32 -> 32x64 after one); --runs: the timed "
                        "frames (default 5, --tiny 2)")
    p.add_argument("--methods", action="store_true",
                   help="only the methods' frame steps at the level's tiers (clss net and rule, bicubic, mlp; "
                        "with --full also nsrr, nsrd, nss), one row each: clss and onnxruntime time, their "
                        "ratio, and where clss's time goes (the OpenCL event ms of one timed frame step per "
                        "kernel, largest first); no peak probes")
    p.add_argument("--tier", choices=("tiny", "540p", "1080p", "2160p"), default=None,
                   help="only this shape tier (named by the output: 1080p is 1080x1920, 540p 540x960, a "
                        "quarter of its pixels); with --full, the full level's cases at this tier alone")
    p.add_argument("--peers", default=None, metavar="LIST",
                   help="the runtimes clss is timed beside, alternating on the same ONNX twins and feeds: "
                        "ort (onnxruntime, the default and the oracle), openvino (OpenVINO's CPU plugin, two "
                        "columns: f32, and its default precision with its error; pip install -e '.[peers]'), "
                        "or a comma list")
    p.add_argument("--layers", metavar="NETWORK",
                   help="per layer of one network: clss's time, GFLOP/s, share of the FMA peak, bytes moved "
                        "and conv variant, beside each peer's time for the same ONNX nodes; NETWORK is a "
                        "network case of `clss bench --list --full` (e.g. 'nsrr reconstruct', 'classifier') "
                        "or an .onnx file (with --input-shape for symbolic sizes)")
    p.add_argument("--input-shape", action="append", metavar="NAME=SHAPE",
                   help="with --layers FILE.onnx: the shape of an input with symbolic sizes, e.g. "
                        "x=1x3x540x960 (repeatable)")
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    p.add_argument("--compare", nargs=2, metavar=("A.json", "B.json"), help="compare two runs and exit")
    return p


def bench_main(argv=None) -> int:
    a = _bench_parser().parse_args(argv)

    level = _level(a)
    if a.methods and a.host_waits:
        raise UsageError("--methods and --host-waits exclude each other")
    from .peers import parse_peers
    try:
        a.peer_names = parse_peers(a.peers)
    except ValueError as e:
        raise UsageError(str(e)) from None
    for flag, on in (("--host-waits", a.host_waits), ("--compare", a.compare)):
        if on and a.peers:
            raise UsageError(f"--peers goes with the cases or --layers, not with {flag}")
    if a.input_shape and not a.layers:
        raise UsageError("--input-shape goes with --layers FILE.onnx")
    if a.layers is not None:
        for flag, on in (("--host-waits", a.host_waits), ("--methods", a.methods), ("--compare", a.compare),
                         ("--list", a.list), ("--filter", a.filter)):
            if on:
                raise UsageError(f"--layers and {flag} exclude each other")
        from clss.device import DeviceError, get_device
        from .layers import main as layers_main
        tier = (_tiers(a) or ("1080p",))[0]
        _quiet_family_warnings()
        try:
            dev = get_device(a.device)
            precs = _precisions(dev, a.precision or "fp32", level)
        except (DeviceError, ValueError) as e:
            print(f"clss bench: {cli_message(e)}", file=sys.stderr)
            return 2
        return layers_main(a, dev, precs, tier)
    if a.json is not None:
        check_output_file(a.json, "--json", inputs=a.compare or ())
    if a.out and not a.compare and not a.list:
        # bench.json / bench.md / roofline.png are replaced on every run: no --overwrite here.
        prepare_output_dir(a.out, "--out", overwrite=True)
    from . import report
    if a.compare:
        try:
            docs = [report.load_json(f) for f in a.compare]
        except (OSError, ValueError) as e:
            print(f"clss bench: {cli_message(e)}", file=sys.stderr)
            return 2
        print(report.compare_docs(*docs))
        return 0

    from clss.device import DeviceError, get_device
    from .suite import all_cases

    _quiet_family_warnings()
    try:
        dev = get_device(a.device)
        precs = _precisions(dev, a.precision, level)
    except (DeviceError, ValueError) as e:
        print(f"clss bench: {cli_message(e)}", file=sys.stderr)
        return 2
    if a.host_waits:
        return _host_waits(a, dev, precs, level)
    cases, unavailable = all_cases(level, _tiers(a))
    if a.methods:
        cases = [c for c in cases if c.kind == "frame"]
    cases = _select(cases, a.filter)
    if not cases and not a.list:
        print(f"clss bench: --filter {a.filter!r} matches no case (`clss bench --list` lists them)",
              file=sys.stderr)
        return 2
    if a.list:
        for c in cases:
            print(f"{c.label:60s} {c.family:15s} {c.kind:8s} {c.shape}{'  (quick)' if c.quick else ''}")
        for what, why in unavailable:
            print(f"(not benchmarked) {what}: {why}")
        return 0
    settings = _settings(a, level)
    git_start = report.git_state()
    _announce(dev, cases, precs, settings, unavailable)
    rows, peak, t0 = _run_all(a, dev, cases, precs, settings, level)
    doc = report.document(rows, dev, peak, settings,
                          level + ("-tiny" if a.tiny else "") + ("-methods" if a.methods else ""), unavailable,
                          extra={"seconds": round(time.perf_counter() - t0, 1), "git_start": git_start,
                                 **_peer_info(a)})
    _write_results(a, doc, rows, peak)
    bad = [r for r in rows if r.status != "ok" and not r.status.startswith("skipped")]
    return 1 if bad else 0


def _tiers(a):
    """The shape tiers --tiny / --tier ask for, or None for the level's."""
    if a.tiny and a.tier and a.tier != "tiny":
        raise UsageError(f"--tiny and --tier {a.tier} exclude each other")
    return ("tiny",) if a.tiny else (a.tier,) if a.tier else None


def _host_waits(a, dev, precs, level) -> int:
    """clss bench --host-waits: the wall / event table, in bench.json as "host_waits"."""
    from . import hostwait, report
    t0 = time.perf_counter()
    from .cases import TIERS
    # --tiny: the frame steps of the tiny tier's cases, whose kernels a smoke run has built
    # --full: also the 2160p tier (1080p -> 2160p), the GPU figure issue 33 asks for
    sizes = (TIERS["tiny"],) if a.tiny else \
        hostwait.SIZES + ((TIERS["2160p"],) if level == "full" else ())
    kw = dict(warm=1, frames=a.runs or 2) if a.tiny else dict(frames=a.runs or 5)
    rows = [r for prec in precs for r in hostwait.run(dev, prec, sizes=sizes, log=lambda m: print(
        m, file=sys.stderr), **kw)]
    doc = report.document([], dev, None, None, level + ("-tiny" if a.tiny else "") + "-host-waits",
                          extra={"seconds": round(time.perf_counter() - t0, 1), "host_waits": rows})
    print(hostwait.format_table(rows))
    written = report.write_outputs(doc, report.markdown(doc), a.out, a.json)
    if written:
        print("wrote " + ", ".join(str(w) for w in written))
    return 0


def _peer_info(a) -> dict:
    """What the document says of the peers, where --peers named any."""
    if not a.peers:
        return {}
    info = {"peers": a.peer_names}
    if "openvino" in a.peer_names:
        from .peers import openvino_default_precision
        info["openvino_default_precision"] = openvino_default_precision()
    return info


def _settings(a, level):
    """The runner settings from the options."""
    from .runner import Settings
    settings = Settings(runs=a.runs, budget_s=a.budget or (1.5 if level == "quick" else 4.0),
                        check=not a.no_check)
    if level == "quick":
        settings.max_runs = 7
    if a.ort_threads:
        settings.ort_threads = a.ort_threads
    settings.ort_spinning = a.ort_spinning
    return settings


def _announce(dev, cases, precs, settings, unavailable):
    print(f"device: {dev.info.platform} / {dev.info.name} (driver {dev.info.driver}); {len(cases)} cases x "
          f"{len(precs)} precision(s) [{', '.join(precs)}]; onnxruntime threads {settings.ort_threads}",
          file=sys.stderr)
    for what, why in unavailable:
        print(f"not benchmarked: {what}: {why}", file=sys.stderr)


def _run_all(a, dev, cases, precs, settings, level):
    """Peak probes, then every (case, precision), alternating with onnxruntime; returns
    (rows, peak, t0)."""
    from clss.progress import progress
    from .peak import measure
    from .runner import OrtRunner, run_case
    t0 = time.perf_counter()
    peak = None
    if not a.no_peak and not a.methods:
        peak = measure(dev, quick=level == "quick", log=lambda m: print(m, file=sys.stderr),
                       **(dict(target_s=0.02, mib=8) if a.tiny else {}))
    ort = OrtRunner(settings.ort_threads, settings.ort_spinning)
    # --peers: the peer columns; without it, onnxruntime alone, as before peers existed
    cols = None
    if a.peers:
        from .peers import columns
        cols = columns(a.peer_names, settings.ort_threads, settings.ort_spinning)
    rows = []
    work = [(c, pr) for c in cases for pr in precs if pr in c.precisions]
    bar = progress(work, desc="bench", unit="case")
    log = _logger(bar)
    for case, prec in bar:
        row = run_case(case, dev, prec, settings, peak, ort, columns=cols)
        rows.append(row)
        if row.status == "ok" or row.status == "mismatch":
            others = "".join(f", {p['label']} {p.get('ms', float('nan')):.2f} ms" for p in row.peers.values())
            log(f"{case.label} {prec}: engine {row.engine_ms:.2f} ms (event {row.engine_event_ms:.2f}), "
                f"ort {row.ort_ms:.2f} ms{others}, {row.speedup_vs_ort:.2f}x, check {row.check}")
        else:
            log(f"{case.label} {prec}: {row.status}")
    return rows, peak, t0


def _write_results(a, doc, rows, peak):
    """The table on stdout, then bench.json, bench.md, roofline.png and --json."""
    from . import report
    if a.methods:
        print(report.format_methods(rows))
    else:
        print(report.format_table(rows))
        if peak:
            print("\n" + report.format_peak(peak))
        print("\ntargets (1080p output, fp32):\n" + report.format_targets(doc["targets"]))
    print(f"\n{len(rows)} rows in {doc['seconds']:.0f} s")
    written = report.write_outputs(doc, report.markdown(doc), a.out, a.json)
    if a.out:
        try:
            report.roofline(doc, Path(a.out) / "roofline.png")
            written.append(Path(a.out) / "roofline.png")
        except Exception as e:   # a plot must not cost the numbers
            print(f"clss bench: roofline plot failed: {e}", file=sys.stderr)
    if written:
        print("wrote " + ", ".join(str(w) for w in written))


def _tune_layers(a) -> int:
    """clss tune --level: the device, precisions and network cases, then bench/tune_layers.py."""
    from clss.device import DeviceError, get_device
    from .suite import all_cases
    from .tune_layers import main as tune_layers_main
    if a.db is not None and not a.dry_run:
        check_output_file(a.db, "--db")
    try:
        dev = get_device(a.device)
        precs = _precisions(dev, a.precision, "quick" if a.precision is None else _level(a))
    except (DeviceError, ValueError) as e:
        print(f"clss tune: {cli_message(e)}", file=sys.stderr)
        return 2
    tiers = ("tiny",) if a.tiny else ((a.tier,) if a.tier else None)
    cases, _ = all_cases("full" if a.tier == "2160p" else _level(a), tiers)
    cases = [c for c in _select(cases, a.filter) if c.kind in ("network", "frame")]
    if not cases:
        print("clss tune: no network or frame cases selected (--filter matches the bench's network and "
              "frame cases, e.g. 'nsrr', 'classifier'; clss bench --list shows them)", file=sys.stderr)
        return 2
    return tune_layers_main(a, dev, precs, cases, _logger)


def tune_main(argv=None) -> int:
    p = ArgParser(
        prog="clss tune",
        description="Search kernel tunables (register blocks, channels/pixels per work-item) and work-group "
                    "sizes for the bench cases on this device; each candidate's output is checked against "
                    "onnxruntime before it is timed; the fastest is stored in the tuning database "
                    "($CLSS_TUNING_DB, default tuning.json in clss's cache directory: $CLSS_CACHE_DIR, else $XDG_CACHE_HOME/clss, else ~/.cache/clss), keyed by device name and driver "
                    "version, where the engine looks it up.",
        epilog="examples:\n  clss tune --quick\n  clss tune --filter conv --precision fp16\n"
               "  clss tune --filter 'conv cls.stem*' --dry-run",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="only the --quick bench cases")
    p.add_argument("--full", action="store_true", help=FULL_HELP)
    p.add_argument("--tiny", action="store_true", help="tiny shapes (a smoke test of the tuner)")
    p.add_argument("--device", "-d", default=None, type=device_spec, help=DEVICE_HELP)
    p.add_argument("--precision", "-p", default="fp32", help="fp32, fp16, fp16-native, a comma list, or all")
    p.add_argument("--filter", "-k", default=None, help="as for clss bench")
    p.add_argument("--runs", type=positive_int, default=5, help="timed runs per candidate (median)")
    p.add_argument("--max-candidates", type=positive_int, default=48,
                   help="cap on parameter combinations per case")
    p.add_argument("--no-local", action="store_true", help="do not search work-group sizes")
    p.add_argument("--all", action="store_true", help="also cases without tunables (work-group sizes only)")
    p.add_argument("--db", default=None, help="tuning database file (default: $CLSS_TUNING_DB, else tuning.json in $CLSS_CACHE_DIR, $XDG_CACHE_HOME/clss or ~/.cache/clss)")
    p.add_argument("--dry-run", action="store_true", help="search and report, store nothing")
    p.add_argument("--level", choices=("fast", "full"), default=None,
                   help="choose the conv2d kernel variant per layer of the networks the bench runs, by "
                        "measuring every variant the device verifies (fast), and their register and "
                        "work-group tiles too (full); then whether each fused frame-step fast path is "
                        "used, by timing the frame steps with and without it; without --level, the "
                        "register blocks and work-group sizes of the bench cases (see above)")
    p.add_argument("--budget", type=positive_float, default=None, metavar="SECONDS",
                   help="with --level: stop searching after this long (default: 240 fast, 1200 full); "
                        "layers left keep their defaults and are listed")
    p.add_argument("--tier", choices=("tiny", "1080p", "2160p"), default=None,
                   help="with --level: the networks' shape tier (2160p: 1080p -> 2160p, the GPU report's)")
    a = p.parse_args(argv)
    if a.tier and not a.level:
        raise UsageError("--tier goes with --level fast|full")
    if a.level:
        return _tune_layers(a)
    from clss import tuning
    from clss.device import DeviceError, get_device
    from clss.progress import progress
    from .suite import all_cases
    from .tune import format_results, tune_case

    level = _level(a)
    if a.db is not None and not a.dry_run:
        check_output_file(a.db, "--db")
    try:
        dev = get_device(a.device)
        precs = _precisions(dev, a.precision, level)
    except (DeviceError, ValueError) as e:
        print(f"clss tune: {cli_message(e)}", file=sys.stderr)
        return 2
    cases, _ = all_cases(level, ("tiny",) if a.tiny else None)
    cases = [c for c in _select(cases, a.filter) if c.tunables or a.all]
    if not cases:
        print("clss tune: no tunable cases selected (families that declare tunables: conv; --all for "
              "work-group sizes of the rest)", file=sys.stderr)
        return 2
    db = Path(a.db) if a.db else tuning.db_path()
    print(f"device: {dev.info.name} (driver {dev.info.driver}); {len(cases)} cases x {len(precs)} precision(s); "
          f"database {db}{' (dry run)' if a.dry_run else ''}", file=sys.stderr)
    results, failed = [], 0
    work = [(c, pr) for c in cases for pr in precs if pr in c.precisions]
    bar = progress(work, desc="tune", unit="case")
    log = _logger(bar)
    for case, prec in bar:
        try:
            results.append(tune_case(case, dev, prec, runs=a.runs, max_candidates=a.max_candidates,
                                     search_local=not a.no_local, store=not a.dry_run, db=db, log=log))
        except Exception as e:
            failed += 1
            log(f"{case.label} [{prec}]: {type(e).__name__}: {e}")
    print(format_results(results))
    stored = sum(len(r.stored) for r in results)
    print(f"\n{stored} entries {'would be ' if a.dry_run else ''}stored in {db}")
    return 1 if failed else 0
