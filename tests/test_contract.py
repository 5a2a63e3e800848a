"""clss.Contract (issue 52 part 1): the caller's conventions in one validated object that
every method takes, as contract= or as keywords; what each method does with each
parameter is true (a transformed input under the matching contract gives the same frame);
a value a method cannot honour is refused by name, in Python and on the command line."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import clss
from clss import methods
from clss.pipeline.contract import (CANNOT, CONVERTS, HANDLINGS, HONOURS, NOT_READ, Contract,
                                    ContractError, FrameInputError)
from helpers import frames

RENDER = (13, 17)
DOC = Path(__file__).resolve().parents[1] / "docs" / "input-contract.md"

# A contract every method can honour, and the input it describes: depth in standard Z,
# motion and jitter stored in other units and signs, colour rendered at exposure 4 in
# units of 200 cd/m2. Each conversion is exact in float32 (depth on a 1/1024 grid, powers
# of two), so the frame is the default contract's, times K = exposure * 100 / nits.
CHANGED = dict(depth_inverted=False, motion_scale=(2.0, -1.0), jitter_scale=(-1.0, -1.0),
               exposure=4.0, nits=200.0)
K = 4.0 * 100.0 / 200.0
FLAGS = ["--depth-standard", "--motion-scale", "2,-1", "--jitter-scale", "-1,-1",
         "--exposure", "4", "--nits", "200"]


def _frames(n):
    """n frames of the sample scene with every G-buffer, depths on a 1/1024 grid."""
    out = []
    for f in frames(RENDER, n):
        f = dataclasses.replace(f, depth=np.round(f.depth * 1024) / np.float32(1024),
                                gbuffers=dict(f.gbuffers))
        f.gbuffers["depth_hr"] = np.round(f.gbuffers["depth_hr"] * 1024) / np.float32(1024)
        out.append(f)
    return out


def _as_changed(f):
    """Frame f as a caller under CHANGED stores it."""
    gb = dict(f.gbuffers, depth_hr=np.float32(1) - f.gbuffers["depth_hr"])
    return dataclasses.replace(f, color=f.color * np.float32(K), depth=np.float32(1) - f.depth,
                               motion=f.motion / np.float32([2.0, -1.0]),
                               jitter=tuple(-np.float32(v) for v in f.jitter), gbuffers=gb)


# ---- the object -------------------------------------------------------------------------------

def test_contract_defaults_frozen_and_exported():
    c = clss.Contract()
    assert c == Contract() and c.changed() == {}
    assert (c.depth_inverted, c.motion_scale, c.jitter_scale, c.hdr, c.exposure, c.nits) == \
        (True, (1.0, 1.0), (1.0, 1.0), True, 1.0, 100.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.hdr = False
    d = Contract(motion_scale=[2, 3], exposure=2)       # normalised once, in the constructor
    assert d.motion_scale == (2.0, 3.0) and d.exposure == 2.0
    assert d.changed() == {"motion_scale": (2.0, 3.0), "exposure": 2.0}
    assert set(Contract.FLAGS) == set(Contract.DESCRIBES) == set(Contract.names())


@pytest.mark.parametrize("param, value", [
    ("depth_inverted", "yes"), ("hdr", 1), ("motion_scale", (1,)), ("motion_scale", (1, np.nan)),
    ("jitter_scale", (0, 1)), ("jitter_scale", "x"), ("exposure", 0), ("exposure", True),
    ("nits", -100), ("nits", None)])
def test_a_bad_parameter_is_named(param, value):
    with pytest.raises(ContractError, match=rf"^{param}: expected") as e:
        Contract(**{param: value})
    assert e.value.cli.startswith(Contract.FLAGS[param] + ": expected")
    # the same through any method's constructor, before a device is touched
    with pytest.raises(ContractError, match=rf"^{param}: expected"):
        clss.Upscaler(method="bicubic", **{param: value})


def test_contract_as_object_or_keywords_not_both():
    with pytest.raises(ContractError, match="contract: given as contract= and as keyword"):
        clss.Upscaler(method="bicubic", contract=Contract(), exposure=2.0)
    with pytest.raises(ContractError, match="contract: expected a clss.Contract, got dict"):
        clss.Upscaler(method="bicubic", contract={"exposure": 2.0})
    # a misspelt parameter is a method keyword that does not exist: named, closest given
    with pytest.raises(TypeError, match="'depth_invertd'; did you mean 'depth_inverted'"):
        clss.Upscaler(method="nsrr", depth_invertd=False)


def test_jitter_units_are_checked_after_the_scale():
    c = Contract(jitter_scale=(2.0, -1.0))
    assert c.jitter((0.25, 0.5)).tolist() == [0.5, -0.5]
    with pytest.raises(FrameInputError, match=r"jitter: .*got \[0.6, -0.0\] \(the jitter given "
                                              r"times jitter_scale \(2.0, -1.0\)\)"):
        c.jitter((0.3, 0.0))


# ---- every method ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", methods.names())
def test_every_method_says_what_it_does_with_each_parameter(name):
    spec = methods.spec(name)
    for param in Contract.names():
        what, why = spec.handling(param)
        assert what in HANDLINGS and why, (name, param)
        # "not read" exactly where the method reads none of the inputs it describes
        reads = any(spec.reads(i) for i in Contract.DESCRIBES[param])
        assert (what == NOT_READ) == (not reads), (name, param, what)
    # one that says nothing takes only the default where it reads the input
    bare = dataclasses.replace(spec, conventions={})
    assert bare.handling("exposure")[0] == CANNOT
    assert bare.handling("jitter_scale")[0] in (CONVERTS, NOT_READ)


@pytest.mark.parametrize("name", methods.names())
def test_every_method_takes_the_contract_as_object_and_keywords(name, dev):
    c = Contract(**CHANGED)
    a = clss.Upscaler(method=name, scale=2, device=dev, contract=c)
    b = clss.Upscaler(method=name, scale=2, device=dev, **CHANGED)
    assert a.contract == b.contract == c
    assert (a.exposure, a.nits, a.depth_inverted) == (4.0, 200.0, False)
    assert clss.Upscaler(method=name, scale=2, device=dev).contract == Contract()


@pytest.mark.parametrize("name", methods.names())
def test_each_method_honours_the_contract_it_takes(name, dev):
    """The frame under CHANGED of the input stored that way is the default contract's
    frame times K, on the host path and (last frame) the device path: each parameter is
    honoured or converted, or has no effect where the method does not read it."""
    seq = _frames(3)
    ref = clss.Upscaler(method=name, scale=2, device=dev)
    up = clss.Upscaler(method=name, scale=2, device=dev, contract=Contract(**CHANGED))
    for i, f in enumerate(seq):
        a = ref.step(f.color, f.depth, f.motion, f.jitter, **f.gbuffers)
        g = _as_changed(f)
        if i < len(seq) - 1:
            b = up.step(g.color, g.depth, g.motion, g.jitter, **g.gbuffers)
        else:
            def d(x):
                return dev.to_device(np.ascontiguousarray(x, np.float32))
            b = up.step_device(d(g.color), d(g.depth), d(g.motion), g.jitter,
                               **{k: d(v) for k, v in g.gbuffers.items()}).get()
        np.testing.assert_allclose(b, K * a, rtol=2e-5, atol=1e-6,
                                   err_msg=f"{name}, frame {i}")


@pytest.mark.parametrize("name", methods.names())
def test_ldr_is_honoured_or_refused_by_name(name, dev):
    spec = methods.spec(name)
    what, why = spec.handling("hdr")
    if what != CANNOT:
        up = clss.Upscaler(method=name, scale=2, device=dev, hdr=False)
        f = _frames(1)[0]
        out = up.step(np.clip(f.color, 0, 1), f.depth, f.motion, f.jitter, **f.gbuffers)
        assert out.min() >= 0 and out.max() <= 1
        return
    can = [n for n in methods.names() if methods.spec(n).handling("hdr")[0] != CANNOT]
    for kw in (dict(hdr=False), dict(contract=Contract(hdr=False))):
        with pytest.raises(ContractError) as e:
            clss.Upscaler(method=name, scale=2, device=dev, **kw)
        assert str(e.value) == (f"method {name!r} cannot honour hdr=False: {why}; methods "
                                f"that can: {', '.join(can)}")
        assert e.value.cli.startswith(f"--ldr: the method {name} cannot honour it")


def test_default_contract_output_is_unchanged(dev):
    """contract=Contract() is the default to the bit (the twins hold the default output to
    each method's oracle: tests/test_methods.py)."""
    f = _frames(1)[0]
    for name in methods.names():
        a = clss.Upscaler(method=name, device=dev).step(f.color, f.depth, f.motion, f.jitter,
                                                        **f.gbuffers)
        b = clss.Upscaler(method=name, device=dev, contract=Contract()).step(
            f.color, f.depth, f.motion, f.jitter, **f.gbuffers)
        assert np.array_equal(a, b), name


# ---- the command line -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    from clss.io import write_sample_sequence
    d = tmp_path_factory.mktemp("contract")
    seq = _frames(2)
    write_sample_sequence(seq, d / "plain", half=False, gbuffers=True)
    write_sample_sequence([_as_changed(f) for f in seq], d / "changed", half=False, gbuffers=True)
    return d, seq


@pytest.mark.parametrize("name", methods.names())
def test_the_flags_reach_every_method_or_are_refused(name, sequences, tmp_path, dev, capsys):
    from clss.cli.main import main
    from clss.io import read_exr
    d, seq = sequences
    out = tmp_path / "out"
    rc = main(["upscale", str(d / "changed"), "-o", str(out), "--method", name] + FLAGS)
    err = capsys.readouterr().err
    assert rc == 0, err
    ref = clss.Upscaler(method=name, scale=2, device=dev)
    for i, f in enumerate(seq):
        a = ref.step(f.color, f.depth, f.motion, f.jitter, **f.gbuffers)
        b, _ = read_exr(str(out / f"frame.{i:04d}.exr"))
        # the written frame is half-float: K * a rounded to half
        np.testing.assert_allclose(b, K * a, rtol=2e-3, atol=1e-4, err_msg=f"{name}, frame {i}")
    if methods.spec(name).handling("hdr")[0] == CANNOT:
        ldr = tmp_path / "ldr"
        rc = main(["upscale", str(d / "plain"), "-o", str(ldr), "--method", name, "--ldr"])
        err = capsys.readouterr().err
        assert rc != 0 and f"--ldr: the method {name} cannot honour it" in err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert not ldr.exists()                 # refused before anything was written


# ---- the documentation -----------------------------------------------------------------------

def test_the_doc_table_is_each_methods_declaration():
    """docs/input-contract.md's table (parameter x method) says what the specs say."""
    lines = DOC.read_text().splitlines()
    top = next(i for i, r in enumerate(lines) if r.startswith("| parameter | `bicubic`"))
    body = []
    for r in lines[top + 2:]:
        if not r.startswith("|"):
            break
        body.append([c.strip().strip("`").replace("*", "") for c in r.strip("|").split("|")])
    head = [c.strip().strip("`") for c in lines[top].strip("|").split("|")]
    assert head[1:] == methods.names()
    assert [row[0] for row in body] == list(Contract.names())
    for param, *cells in body:
        for name, cell in zip(methods.names(), cells):
            assert cell.startswith(methods.spec(name).handling(param)[0]), (param, name, cell)


def test_clss_methods_json_says_what_each_method_does(capsys):
    import json
    from clss.cli.main import main
    assert main(["methods", "--json"]) == 0
    recs = {r["name"]: r["contract"] for r in json.loads(capsys.readouterr().out)["methods"]}
    assert recs["nsrr"]["hdr"]["handling"] == CANNOT and recs["clss"]["hdr"]["handling"] == HONOURS
    assert recs["bicubic"]["depth_inverted"]["handling"] == NOT_READ
    assert recs["nss"]["nits"] == {"handling": CONVERTS, "why": methods.spec("nss").handling("nits")[1]}
