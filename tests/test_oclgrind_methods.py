"""The NSRR, NSRD and NSS frame kernels (clss/methods/nsrr/nsrr.cl, clss/methods/nsrd/nsrd.cl,
clss/methods/nss/nss.cl with both depth paths) on tiny frames under
oclgrind's out-of-bounds, uninitialised-read and data-race checks: three frames with a
reset, fp32 and fp16 storage, odd sizes (their networks run through clss.Model, whose
kernels have their own oclgrind tests). Any diagnostic fails.

Skipped (with the reason shown) where oclgrind is not installed; .ci/run installs it."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from helpers import DIAGNOSTIC, ICD, oclgrind_env

SCRIPT = """
import numpy as np, warnings, clss
warnings.simplefilter("ignore")
h, w, s = 5, 7, {scale}
H, W = h * s, w * s
rng = np.random.default_rng(0)
up = clss.Upscaler(method="{method}", scale=s, precision="{prec}"{extra})
for t in range(3):
    g = dict(albedo=rng.uniform(0, 1, (h, w, 3)).astype(np.float32),
             normal=rng.uniform(-1, 1, (h, w, 3)).astype(np.float32),
             albedo_hr=rng.uniform(0, 1, (H, W, 3)).astype(np.float32)) if "{method}" == "nsrd" else {{}}
    y = up.step(rng.uniform(0, 2, (h, w, 3)).astype(np.float32),
                rng.uniform(0.1, 0.9, (h, w)).astype(np.float32),
                rng.uniform(-1.5, 1.5, (h, w, 2)).astype(np.float32),
                (0.25, -0.125), reset=(t == 1), **g)
    assert np.isfinite(y).all()
print("method kernels ok")
"""


# NSRR's untrained U-Net at the "fast" widths: the frame kernels are the same, and the
# default widths' network made this the slowest test of the suite (5 minutes); with the
# depth rejection (networks.REJECTS, the shipped weights'), whose reads the random depths
# and motions send everywhere
# NSRD x2 with the shipped weights: their guided base (networks.BASES) in the float8
# finish (fp32) and the per-pixel one (fp16); x3 untrained: the bilinear base
U = ', weights="untrained"'
NSRR_FAST_REJECT = (', weights=(lambda n: (lambda c: (c, n.init_weights(c, 1)))(n.make_config("fast", '
                    'reject="depth")))(__import__("clss.methods.nsrr.networks", fromlist=["n"]))')
# NSS's rules' base (networks.BASES): clss-rules' frame step inside, nss_rules_in and
# nss_rules_mix; the seeded init (its mix head at zero still reads and writes every buffer)
NSS_RULES = (', weights=(lambda n: (lambda c: (c, n.init_weights(c, 1)))(n.make_config(2, '
             'base="rules")))(__import__("clss.methods.nss.networks", fromlist=["n"]))')
# NSRD's rules' base (networks.OUT_BASES): clss-rules' frame step inside, nsrd_rules_in and
# nsrd_rules_mix; the seeded init with the shipped form's guided base (its mix head at zero
# still reads and writes every buffer)
NSRD_RULES = (', weights=(lambda n: (lambda c: (c, n.init_weights(c, 1)))(n.make_config(2, base="guided", '
              'remod="learned", out_base="rules")))(__import__("clss.methods.nsrd.networks", fromlist=["n"]))')
# One case per method in the default tier (each method's frame kernels in their shipped
# configuration: NSRD's guided base and float8 kernels, NSS's atomic depth scatter); the
# other storage precision, NSRD's untrained x3, NSS's gather path and the rules' bases in the slow tier
# (these runs were CI's longest: 2.5 minutes of its 20 with all six).
SLOW = pytest.mark.slow
CASES = [("nsrr", 2, "fp32", NSRR_FAST_REJECT), ("nsrd", 2, "fp32", ""),
         pytest.param("nsrd", 2, "fp16", "", marks=SLOW), pytest.param("nsrd", 3, "fp16", U, marks=SLOW),
         ("nss", 2, "fp32", U), pytest.param("nss", 2, "fp16", U + ', depth_scatter="gather"', marks=SLOW),
         pytest.param("nss", 2, "fp32", NSS_RULES, marks=SLOW),
         pytest.param("nsrd", 2, "fp32", NSRD_RULES, marks=SLOW)]


def _run(case, tmp):
    method, scale, prec, extra = case
    env = oclgrind_env(tmp)
    # the networks' convolutions on the NCHW kernel: the channel-blocked one is run under
    # oclgrind on its own (tests/test_oclgrind.py, xfail: a second launch in one process
    # reads as uninitialised there); NSRR's reprojection in its vector form, which CPUs
    # run (its self-check would run two more frame steps under oclgrind; the reference
    # form ran clean here before the vector form existed)
    # NSRD's float8 kernels (nsrd.encode8) in the fp32 runs, its per-pixel ones in fp16
    env["CLSS_SELFCHECK_FORCED"] = ("conv.blocked=0,nsrr.reproject_vectors=1,nsrd.encode8="
                                    + ("1" if prec == "fp32" else "0"))
    env["PYTHONPATH"] = os.pathsep.join([os.getcwd(), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-W", "ignore", "-c",
                           SCRIPT.format(method=method, scale=scale, prec=prec, extra=extra)],
                          env=env, capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def runs(request, tmp_path_factory):
    """The selected cases' oclgrind runs, started together two at a time: oclgrind
    interprets on one thread, and these runs are most of their module's time (about 7
    minutes one after the other)."""
    from concurrent.futures import ThreadPoolExecutor
    chosen = [tuple(it.callspec.params[k] for k in ("method", "scale", "prec", "extra"))
              for it in request.session.items
              if getattr(it, "originalname", "") == "test_method_kernels_clean_under_oclgrind"
              and not it.get_closest_marker("skip")]      # a tier conftest leaves out
    pool = ThreadPoolExecutor(2)
    futures = {c: pool.submit(_run, c, tmp_path_factory.mktemp("oclgrind")) for c in chosen}
    yield futures
    pool.shutdown(wait=True, cancel_futures=True)


@pytest.mark.oclgrind
@pytest.mark.skipif(not os.path.exists(ICD), reason="oclgrind not installed (apt-get install oclgrind)")
@pytest.mark.parametrize("method, scale, prec, extra", CASES)
def test_method_kernels_clean_under_oclgrind(method, scale, prec, extra, runs):
    p = runs[(method, scale, prec, extra)].result()
    diags = [line for line in p.stderr.splitlines() if DIAGNOSTIC.search(line)]
    assert not diags, "oclgrind reported:\n" + "\n".join(p.stderr.splitlines()[:60])
    assert p.returncode == 0 and "method kernels ok" in p.stdout, p.stdout[-3000:] + p.stderr[-3000:]
