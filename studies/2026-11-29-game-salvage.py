"""One-off (2026-11-29): the shards of a killed `make validation-data-game` render from the
EXRs it had written, so that the game family could be scored (docs/evaluation.md, "A
game-like held-out family"). The render (4 sequences of 32 frames) was paused by SIGSTOP for
most of its 90 minutes; sequences 200000 and 200001 had 17 and 18 complete frames. A frame
is complete when its lr, twin0 (jitter-free), twin1 (4x), ref and hr EXRs exist; frames.json
(written only at a render's end) is rebuilt from the scene (bpy, no render: the camera's
rotation per frame, the family's cuts) and shards.shard_jitter's draws, exactly as the
32-frame render would have recorded them, so these shards are the first frames of the
shards `make validation-data-game` writes. They go to out/data/game-salvage/<set>/test/.

    .venv/bin/python studies/2026-11-29-game-salvage.py 200000 200001
"""
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from weights_tools import jitter_mix, scenegen  # noqa: E402
from weights_tools.blender import convert, shards  # noqa: E402
from weights_tools.blender import families as fam  # noqa: E402
from weights_tools.blender import render_validation as rv  # noqa: E402
D = "out/data"
MAIN, TW = f"{D}/blender-game", [f"{D}/blender-game-zero", f"{D}/blender-game4"]
opts = dict(shards.DEFAULTS, jitter_mix="halton",
            twins=[shards.parse_twin(f"{TW[0]}:zero", (90, 160), 2.0),
                   shards.parse_twin(f"{TW[1]}:halton:45x80", (90, 160), 2.0)])
FRAMES = 32
for seed in map(int, sys.argv[1:]):
    job = ("test", "game", seed, f"{MAIN}/test/game_{seed:06d}.npz")
    exr = f"{MAIN}/.exr/test_game_{seed:06d}"
    n = 0
    while all(os.path.isfile(f"{exr}/{k}_{n:04d}.exr") for k in ("lr", "twin0", "twin1", "ref", "hr")):
        n += 1
    scene = rv.new_scene(1)
    desc, cuts = fam.builder("game", seed)(scene, FRAMES)
    drawn = shards.shard_jitter(job, opts)
    tdrawn = [shards.shard_jitter(job, dict(opts, jitter_mix=t["mix"])) for t in opts["twins"]]
    jit = jitter_mix.sequence_jitter(drawn, FRAMES, 2.0).tolist()
    tj = [jitter_mix.sequence_jitter(d, FRAMES, t["scale"]).tolist() for d, t in zip(tdrawn, opts["twins"])]
    rec = dict(scene="game", description=desc, render_size=[90, 160], output_size=[180, 320],
               scale=2.0, near=rv.NEAR, spp=16, ref_spp=32, blender=rv.bpy.app.version_string,
               twins={"twin0": dict(render_size=[90, 160], scale=2.0),
                      "twin1": dict(render_size=[45, 80], scale=4.0)},
               seconds={}, frames=[], salvaged=f"{n} of {FRAMES} frames")
    for f in range(n):
        scene.frame_set(f + 1)
        rec["frames"].append(dict(lr=f"lr_{f:04d}.exr", ref=f"ref_{f:04d}.exr", hr=f"hr_{f:04d}.exr",
                                  jitter=[float(v) for v in jit[f]], reset=f == 0 or f in cuts,
                                  camera_rotation=rv.camera_rotation(scene.camera),
                                  twins={f"twin{k}": dict(lr=f"twin{k}_{f:04d}.exr", jitter=[float(v) for v in tj[k][f]])
                                         for k in range(2)}))
    json.dump(rec, open(f"{exr}/frames.json", "w"), indent=1)
    outs = [(job[3], None, drawn, "halton")] + [
        (p, f"twin{k}", d, t["mix"]) for k, (p, t, d) in enumerate(zip(shards.twin_paths(job, opts), opts["twins"], tdrawn))]
    for out_path, twin, j, mix in outs:
        out_path = out_path.replace(f"{D}/", f"{D}/game-salvage/")
        data = convert.convert_scene(exr, twin=twin)
        meta = json.loads(str(data["meta"]))
        meta.update(generator="weights_tools.blender.shards", family="game", seed=seed, split="test",
                    frames=n, jitter=j, jitter_mix=mix, salvaged=f"frames 0-{n - 1} of a {FRAMES}-frame render (killed)")
        if twin:
            meta["twin_of"] = f"blender-game/test/game_{seed:06d}.npz"
        data["meta"] = np.array(json.dumps(meta))
        os.makedirs(os.path.dirname(out_path), exist_ok=True)
        scenegen.write_sequence(out_path, data)
        print(out_path, n, "frames, resets", np.nonzero(data["reset"])[0].tolist())
