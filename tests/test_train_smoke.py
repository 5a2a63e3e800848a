"""A smoke run of `python -m weights_tools train` on tiny data (seconds): it runs both
stages, the loss is finite, the weights change, a checkpoint resumes, and the result
loads into clss.Upscaler.  Skipped without torch (the [train] extra)."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from weights_tools.__main__ import main  # noqa: E402
from clss.networks import load_weights  # noqa: E402

RENDER = (16, 24)


def write_tiny_sequence(path, n=6, seed=0):
    """A DATA.md sequence from the built-in scene with crude labels (for this test only:
    ghosting where the depth changes a lot between frames, geometry aliasing where the
    reference has strong edges)."""
    from clss.demo.scene import render_sequence
    seq = render_sequence(n, RENDER, 2.0, spp_ref=2, seed=seed)
    ref = np.stack([f.reference for f in seq])
    lum = ref.mean(-1)
    edge = np.zeros_like(lum)
    edge[:, :, 1:] = np.abs(np.diff(lum, axis=2))
    alias = np.where(edge > np.percentile(edge, 80), 0, 2).astype(np.uint8)
    d = np.stack([f.depth for f in seq])
    dd = np.abs(np.diff(d, axis=0, prepend=d[:1])).repeat(2, 1).repeat(2, 2)
    ghost = np.where(dd > 0.02, 0, 2).astype(np.uint8)
    np.savez(path, color=np.stack([f.color for f in seq]), depth=d,
             motion=np.stack([f.motion for f in seq]),
             jitter=np.array([f.jitter for f in seq], np.float32),
             reset=np.array([i == 0 for i in range(n)]), reference=ref,
             label_ghost=ghost, label_alias=alias, scale=np.float32(2.0),
             meta=np.array(json.dumps({"generator": "test_train_smoke"})))


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    d = tmp_path_factory.mktemp("train_data")
    write_tiny_sequence(str(d / "a.npz"), seed=0)
    return str(d)


ARGS = ["--seed", "0", "--cls-steps", "3", "--comp-steps", "2", "--batch", "2",
        "--patch", "16", "--frames", "4", "--candidates", "12", "--threads", "2"]


def test_train_smoke(tiny_data, tmp_path, capsys):
    out = str(tmp_path / "run")
    assert main(["train", "--data", tiny_data, "--out", out, "--init", "untrained-seed"]
                + ARGS) == 1
    assert "--init" in capsys.readouterr().err
    assert main(["train", "--data", tiny_data, "--out", out, "--heldout", tiny_data] + ARGS) == 0
    log = json.load(open(os.path.join(out, "train.json")))
    for stage, n in (("classifier", 3), ("composition", 2)):
        assert len(log["losses"][stage]) == n and np.isfinite(log["losses"][stage]).all()
    assert os.path.isfile(os.path.join(out, "loss.png"))
    assert log["heldout_psnr_pq"][0]["net"] > 10
    trained = load_weights(os.path.join(out, "weights.safetensors"))
    # --export writes the same weights from the final checkpoint
    os.rename(os.path.join(out, "weights.safetensors"), os.path.join(out, "first.safetensors"))
    assert main(["train", "--data", tiny_data, "--out", out, "--export"]) == 0
    again = load_weights(os.path.join(out, "weights.safetensors"))
    assert all(np.array_equal(again[k], v) for k, v in trained.items())

    # the weights moved away from the seeded init
    from clss.methods.clss.networks import build_classifier, build_composition
    from clss.networks import model_weights
    init = {**model_weights(build_classifier()), **model_weights(build_composition())}
    assert sorted(trained) == sorted(init)
    for prefix in ("cls.", "comp."):
        assert any(not np.array_equal(trained[k], init[k]) for k in init if k.startswith(prefix))

    # they run in clss.Upscaler, agreeing with the torch twin
    from clss import Upscaler
    from clss.demo.scene import render_sequence
    from weights_tools.methods.clss.twin import TorchUpscaler
    up = Upscaler(2.0, mode="net", weights=os.path.join(out, "weights.safetensors"))
    twin = TorchUpscaler(2.0, "net", weights=trained, device="cpu")
    for f in render_sequence(3, (11, 13), 2.0, spp_ref=0):
        a, b = up.step(f.color, f.depth, f.motion, f.jitter), twin.step(f.color, f.depth,
                                                                         f.motion, f.jitter)
        assert np.abs(a - b).max() <= 1e-3 * np.abs(b).max() + 1e-12


@pytest.mark.slow     # a long training smoke (a study's switch, two trainings)
@pytest.mark.parametrize("labels", ["useful", "cost"])
def test_train_useful_ghost_labels(tiny_data, tmp_path, labels):
    """--ghost-labels useful/cost (a study, not the recipe): the classifier stage trains on
    labels made from the frame step's own clipped history, and the run finishes."""
    out = str(tmp_path / labels)
    assert main(["train", "--data", tiny_data, "--out", out, "--ghost-labels", labels]
                + ARGS) == 0
    log = json.load(open(os.path.join(out, "train.json")))
    assert np.isfinite(log["losses"]["classifier"]).all()
    assert log["settings"]["ghost_labels"] == labels


def test_useful_ghost_labels_mark_where_the_history_is_worse():
    """Visibility exactly where the blended history's squared error exceeds ratio x the
    upsample's plus the floor; the generator's visibility becomes none, its shading stays;
    cost is |eh - eu| over its mean on valid pixels."""
    import torch
    from weights_tools.methods.clss.recipe import useful_ghost_labels
    ref = torch.zeros(1, 3, 1, 4)
    up = torch.full((1, 3, 1, 4), 0.1)
    hist = torch.tensor([0.0, 0.1, 0.2, 0.3]).view(1, 1, 1, 4).expand(1, 3, 1, 4)
    r = {"blend_hist": hist, "up": up, "valid": torch.ones(1, 1, 1, 4, dtype=torch.bool)}
    gen = torch.tensor([[[0, 1, 2, 0]]])
    lab, cost = useful_ghost_labels(r, gen, ref, 2.0, 0.0)
    assert lab.tolist() == [[[2, 1, 0, 0]]] and cost is None
    lab, cost = useful_ghost_labels(r, gen, ref, 1.0, 1.0, cost=True)
    assert lab.tolist() == [[[2, 1, 2, 2]]]
    eh, eu = (hist[0, 0, 0] ** 2) * 3, torch.full((4,), 0.03)
    c = (eh - eu).abs()
    assert torch.allclose(cost[0, 0], c / c.mean(), atol=1e-6)


@pytest.mark.slow     # a long training smoke (three trainings)
def test_train_resumes(tiny_data, tmp_path):
    """An interrupted run (classifier done, composition not) resumes to the same weights
    as an uninterrupted one."""
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    assert main(["train", "clss", "--data", tiny_data, "--out", a] + ARGS) == 0
    short = [v if ARGS[i - 1] != "--comp-steps" else "0" for i, v in enumerate(ARGS)]
    assert main(["train", "--data", tiny_data, "--out", b] + short) == 0
    assert main(["train", "--data", tiny_data, "--out", b, "--resume"] + ARGS) == 0
    wa = load_weights(os.path.join(a, "weights.safetensors"))
    wb = load_weights(os.path.join(b, "weights.safetensors"))
    for k in wa:
        np.testing.assert_allclose(wa[k], wb[k], rtol=1e-5, atol=1e-6, err_msg=k)


def test_train_bad_data_is_one_line(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --data:") and "Traceback" not in err


@pytest.mark.slow     # a long training smoke (two seeds in two processes, scored twice)
def test_seeds_trains_scores_and_picks(tiny_data, tmp_path, capsys):
    """`seeds`: two seeds trained in two processes, each scored against rules on the
    groups, the best on --pick copied to --out; a second call trains nothing again."""
    from weights_tools import seeds
    assert seeds.parse_seeds("0-2,5,1") == [0, 1, 2, 5]
    for bad in ("3-1", "a", ","):
        with pytest.raises(ValueError, match="--seeds"):
            seeds.parse_seeds(bad)
    out = str(tmp_path / "s")
    train = " ".join(ARGS[2:])         # all but --seed
    seq = os.path.join(tiny_data, "a.npz")
    argv = ["seeds", "clss", "--data", tiny_data, "--out", out, "--seeds", "0-1", "--jobs", "2",
            "--score", f"val={seq}", "--score", f"other={seq}", "--train", train,
            "--warmup", "1", "--device", "cpu"]
    assert main(argv + ["--pick", "nope"]) == 1
    assert "--pick nope: not one of the --score groups (val, other)" in capsys.readouterr().err
    assert main(argv + ["--pick", "val"]) == 0
    table = capsys.readouterr().out
    rec = json.load(open(os.path.join(out, "seeds.json")))
    assert sorted(rec["seeds"]) == ["0", "1"] and rec["failed"] == []
    best = rec["picked"]["seed"]
    assert rec["seeds"][str(best)]["val"][0] == max(v["val"][0] for v in rec["seeds"].values())
    picked = load_weights(os.path.join(out, "weights.safetensors"))
    same = load_weights(os.path.join(out, f"seed_{best}", "weights.safetensors"))
    assert all(np.array_equal(picked[k], same[k]) for k in same)
    for g in ("val", "other"):
        d = [v[g][0] - rec["rules"][g][0] for v in rec["seeds"].values()]
        assert rec["summary"][g]["psnr"]["min"] == pytest.approx(min(d))
    assert f"picked seed {best}" in table and "mean" in table and "rules" in table
    # finished seeds are not trained again
    stamp = os.path.getmtime(os.path.join(out, "seed_0", "weights.safetensors"))
    assert main(argv + ["--pick", "val"]) == 0
    assert os.path.getmtime(os.path.join(out, "seed_0", "weights.safetensors")) == stamp


def test_seeds_bad_arguments_are_one_line(tiny_data, tmp_path, capsys):
    seq = os.path.join(tiny_data, "a.npz")
    for argv, msg in ((["--data", str(tmp_path / "nope"), "--score", f"v={seq}"], "--data"),
                      (["--data", tiny_data, "--score", "v=/nowhere/*.npz"], "--score v=/nowhere"),
                      (["--data", tiny_data, "--score", f"v={seq}", "--seeds", "4-2"], "--seeds"),
                      (["--data", tiny_data, "--score", f"v={seq}", "--jobs", "0"], "--jobs")):
        assert main(["seeds", "--out", str(tmp_path / "o")] + argv) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: {msg}") and "Traceback" not in err, err


def test_train_method_without_recipe_says_why(capsys):
    # train METHOD: a baseline (and a planned method, while there is one) answer in one line, exit 2
    from clss import methods
    for name in methods.PLANNED:
        assert main(["train", name, "--data", "x", "--out", "y"]) == 2
        assert "not built yet" in capsys.readouterr().err
    assert main(["train", "bicubic", "--data", "x", "--out", "y"]) == 2
    assert "nothing to train" in capsys.readouterr().err
    assert main(["train", "bicubic"]) == 2
    assert "nothing to train" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "taa", "--data", "x"])
    assert "invalid choice" in capsys.readouterr().err


def test_recipes_are_found_in_their_rooms():
    """A method's training is its folder weights_tools/methods/<name>/ (twin.py, recipe.py
    exporting RECIPE): `train` lists what it finds there, each a method of clss.methods."""
    from clss import methods as runtime
    from weights_tools import methods
    assert {"clss", "mlp", "nsrr", "nsrd"} <= set(methods.names())
    for name in methods.names():
        assert name in runtime.names()
        r = methods.recipe(name)
        assert isinstance(r, methods.Recipe) and r.doc
    assert methods.commands() == {"classifier": "weights_tools.methods.clss.classifier_report"}
    with pytest.raises(KeyError, match="no training recipe for 'bicubic'"):
        methods.recipe("bicubic")


def test_trainloop_losses():
    import torch
    from weights_tools import trainloop
    g = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 17, 19, generator=g)
    b = torch.rand(2, 3, 17, 19, generator=g)
    assert float(trainloop.ssim(a, a)) == pytest.approx(1.0, abs=1e-5)
    assert float(trainloop.ssim(a, b)) < 0.2
    assert float(trainloop.l1(a, a)) == 0.0
    m = torch.zeros(2, 1, 17, 19)
    m[:, :, :4] = 1
    assert float(trainloop.l1(a, b, m)) == pytest.approx(float((a - b).abs()[:, :, :4].mean()), rel=1e-5)
    assert float(trainloop.temporal(a, b, a + 1, b + 1)) == pytest.approx(0.0, abs=1e-6)


def test_default_method_rewrites_only_its_own_command():
    from weights_tools.recipes import with_default_method as w
    assert w(["train", "--data", "d"]) == ["train", "clss", "--data", "d"]
    assert w(["train", "bicubic", "--data", "d"]) == ["train", "bicubic"]
    assert w(["train", "nsrd", "--data", "d"]) == ["train", "nsrd", "--data", "d"]
    assert w(["eval", "x.npz", "--warmup", "2"]) == ["eval", "x.npz", "--warmup", "2"]
    assert w(["seeds", "--data", "d"], "seeds") == ["seeds", "clss", "--data", "d"]


def test_classifier_report_scores_heads_rules_and_the_runtime_margin(tmp_path, capsys):
    """`python -m weights_tools classifier` on two tiny labelled sequences: every row of
    both heads is a balanced accuracy in [0, 1] with its confusion counting the same valid
    pixels; the aliasing head's margin row is its argmax (the margin is the ghosting
    head's); the 2x2 bound is at least a constant's 1/3; one sequence is refused."""
    from weights_tools.methods.clss import classifier_report as cr
    paths = []
    for k in range(2):
        p = str(tmp_path / f"s{k}.npz")
        write_tiny_sequence(p, seed=k)
        paths.append(p)
    res = cr.report(paths, None, log=open(os.devnull, "w"))
    for head in ("ghost", "alias"):
        rows = res["heads"][head]
        n = None
        for who in ("classifier", "classifier at margin", "rules", "2x2 bound"):
            ba = rows[who]["balanced_accuracy"]
            assert 0.0 <= ba <= 1.0, (head, who, ba)
            total = int(np.sum(rows[who]["confusion"]))
            n = total if n is None else n
            assert total == n, (head, who)
        assert rows["2x2 bound"]["balanced_accuracy"] >= 1 / 3 - 1e-9
    # the ghosting head against the useful labels, on the same pixels
    u = res["heads"]["useful"]
    for who in ("classifier", "classifier at margin"):
        assert 0.0 <= u[who]["balanced_accuracy"] <= 1.0
        assert int(np.sum(u[who]["confusion"])) == n
    assert abs(sum(u["label_frequency"]) - 1.0) < 1e-9
    # the aliasing head has no margin: its margin row is its argmax
    a = res["heads"]["alias"]
    assert a["classifier at margin"]["confusion"] == a["classifier"]["confusion"]
    text = cr.format_report(res)
    assert "classifier at margin" in text and "2x2 bound" in text and "useful labels" in text
    with pytest.raises(ValueError, match="at least 2 labelled"):
        cr.report(paths[:1], None, log=open(os.devnull, "w"))


def test_visibility_oracle_hooks_and_cli(tmp_path, capsys):
    """weights_tools.methods.clss.visibility_oracle: the generator hook rejects exactly the labelled
    visibility pixels of the current frame; the useful hook exactly where the clipped
    history's squared error exceeds ratio x the upsample's plus the floor; the command
    prints a row per decision and writes them; a huge ratio never rejects, so it scores
    as the mode with its rejections turned off (a depth threshold above 1)."""
    from weights_tools.methods.clss import visibility_oracle as vo
    from weights_tools.methods.clss.twin import TorchUpscaler
    lab = np.array([[[0, 2], [1, 0]]], np.uint8)
    ref = np.full((1, 2, 2, 3), 0.5, np.float32)
    state = {"seq": {"label_ghost": lab, "reference": ref}, "t": 0, "nits": 10000.0}
    reject = torch.zeros(1, 1, 2, 2, dtype=torch.bool)
    assert vo.generator_hook(state)(reject, {}).view(-1).tolist() == [True, False, False, True]
    from weights_tools.methods.clss.twin import pq_encode
    r = pq_encode(torch.from_numpy(ref[0].transpose(2, 0, 1))[None], 10000.0)
    up = r + 0.01
    hist = r + torch.tensor([0.0, 0.01, 0.02, 0.05]).view(1, 1, 2, 2)
    ctx = {"up": up, "hist": hist + 1.0, "hist_clipped": hist}
    got = vo.useful_hook(state, 2.0, 0.0)(reject, ctx).view(-1).tolist()
    assert got == [False, False, True, True]
    assert vo.useful_hook(state, 1.0, 1.0)(reject, ctx).view(-1).tolist() == [False] * 4

    p = str(tmp_path / "s.npz")
    write_tiny_sequence(p, seed=3)
    seqs = vo.load([p])
    never = vo.score(seqs, "rules", None, "useful", ratio=1e9, floor=1e9)
    from weights_tools.evaluate import evaluate_sequence, Pipeline
    up = TorchUpscaler(2.0, "rules", depth_threshold=2.0, device="cpu")
    rec = evaluate_sequence(seqs[0], ["rules"], None, warmup=2, run={"rules": Pipeline(up)},
                            net_trained=True, flip_every=0, log=open(os.devnull, "w"))
    assert never[0] == pytest.approx(rec["methods"]["rules"]["psnr"], abs=1e-9)
    out = str(tmp_path / "o.json")
    assert vo.main([p, "--mode", "rules", "--ratio", "1", "--json", out]) == 0
    text = capsys.readouterr().out
    assert "as-is" in text and "generator" in text and "useful 1" in text
    rows = json.load(open(out))["rows"]
    assert [r["decision"] for r in rows] == ["as-is", "generator", "useful 1"]
    assert all(np.isfinite(r["psnr"]) for r in rows)
    # the picture: four panels (reference, the mode's decision, the labels, useful)
    png = str(tmp_path / "d.png")
    assert vo.main([p, "--mode", "rules", "--picture", png, "--frame", "3"]) == 0
    import OpenImageIO as oiio
    spec = oiio.ImageInput.open(png).spec()
    assert spec.width > 4 * 48 and spec.height > 32
    assert vo.main([p, "--mode", "rules", "--picture", png, "--frame", "99"]) == 1
    assert "--frame 99" in capsys.readouterr().err


def test_data_mix_draws_each_directory_by_its_share(tmp_path, capsys):
    """--data DIR[:SHARE],...: the sequences are listed in proportion to the shares (the
    same arrays, so a conversion runs once per sequence), and a bad mix is one line."""
    from weights_tools import trainloop
    a, b = tmp_path / "gen", tmp_path / "blender"
    a.mkdir(), b.mkdir()
    for i in range(3):
        write_tiny_sequence(str(a / f"g{i}.npz"), n=3, seed=i)
    write_tiny_sequence(str(b / "b0.npz"), n=3, seed=7)
    need = ("color", "reference", "depth", "scale")
    seqs = trainloop.load_sequences(f"{a},{b}:0.25", 1, need)
    names = [s["name"] for s in seqs]
    assert len(seqs) == trainloop.MIX_SLOTS
    assert names.count("b0.npz") == 250 and {names.count(f"g{i}.npz") for i in range(3)} == {250}
    assert len({id(s) for s in seqs}) == 4
    converted = trainloop.per_sequence(seqs, lambda s: {"n": s["name"]})
    assert len({id(c) for c in converted}) == 4 and converted[-1]["n"] == "b0.npz"
    assert [s["name"] for s in trainloop.load_sequences(str(a), 1, need)] == \
        ["g0.npz", "g1.npz", "g2.npz"]
    for bad, says in ((f"{a},{b}:1.5", "between 0 and 1"), (f"{a}:0.5,{b}:0.6", "add up to 1.1"),
                      (f"{a},{b}:x", "must be a number"), (f"{a},{tmp_path}/none", "not a directory")):
        with pytest.raises(trainloop.TrainError, match=says):
            trainloop.load_sequences(bad, 1, need)
    assert main(["train", "nsrr", "--data", f"{a},{b}:2", "--out", str(tmp_path / "o"),
                 "--steps", "1"]) != 0
    err = capsys.readouterr().err
    assert "--data:" in err and "Traceback" not in err


def test_unlabelled_shards_fine_tune_the_composition_only(tiny_data, tmp_path, capsys):
    """Blender shards carry no ghost/alias labels: in a mix they are refused while the
    classifier stage trains (one line saying what to do), and with --cls-steps 0 the
    composition fine-tunes on them (the classifier's weights stay the --init file's)."""
    from clss.networks import save_weights
    from clss.methods.clss.networks import build_classifier, build_composition
    from clss.networks import model_weights
    blend = tmp_path / "blender"
    blend.mkdir()
    z = dict(np.load(os.path.join(tiny_data, "a.npz")))
    np.savez(blend / "b.npz", **{k: v for k, v in z.items() if not k.startswith("label_")})
    mix = f"{tiny_data},{blend}:0.5"
    out = str(tmp_path / "ft")
    assert main(["train", "--data", mix, "--out", out] + ARGS) == 1
    err = capsys.readouterr().err
    assert "lacks label_ghost, label_alias" in err and "--cls-steps 0" in err
    init = {**model_weights(build_classifier()), **model_weights(build_composition())}
    save_weights(init, str(tmp_path / "init.safetensors"))
    args = [a if a != "3" else "0" for a in ARGS]           # --cls-steps 0
    assert main(["train", "--data", mix, "--out", out, "--init",
                 str(tmp_path / "init.safetensors")] + args) == 0
    w = load_weights(os.path.join(out, "weights.safetensors"))
    # (the classifier goes through the normalised basis and back: float rounding only)
    assert all(np.allclose(w[k], v, rtol=1e-4, atol=1e-6) for k, v in init.items()
               if k.startswith("cls."))
    assert any(not np.allclose(w[k], v, rtol=1e-3, atol=1e-5) for k, v in init.items()
               if k.startswith("comp."))
