"""Gain of the net over its residual base on whole held-out frames, in PQ (the training
metric) and tonemapped (eval's), torch twin: is the batch gain real on held-out?"""
import sys, glob, numpy as np, torch
from clss.methods.nsrr import networks as nets
from clss import metrics
from weights_tools.methods.nsrr.twin import NsrrNet, TorchStep, rgbd_of, pq_decode, pq_encode
from clss.pipeline.contract import to_internal, validate_frame
torch.set_num_threads(1)
ck, pattern = sys.argv[1], sys.argv[2]
if ck.endswith(".safetensors"):
    cfg, w = nets.load(ck)
else:
    st = torch.load(ck, weights_only=False); cfg = nets.make_config("default", act="leaky")
    w = {k: v.numpy() for k, v in st["net"].items()}; print("step", st["step"])
net = NsrrNet(cfg, w)
acts = []
net.un[8].register_forward_hook(lambda m, i, o: acts.append(((o > 0).float().mean((0, 2, 3)))))
for p in sorted(glob.glob(pattern))[:int(sys.argv[3]) if len(sys.argv) > 3 else 3]:
    z = np.load(p); sc = float(z["scale"]); st_ = TorchStep(net, sc); hist = None; r = []
    for t in range(len(z["color"])):
        x = to_internal(validate_frame(z["color"][t], z["depth"][t], z["motion"][t], tuple(z["jitter"][t])))
        rgbd = rgbd_of(torch.from_numpy(x["color"]), torch.from_numpy(x["depth"]))
        with torch.no_grad():
            y, hist = st_.step(rgbd, torch.from_numpy(x["motion"]), [x["jitter"]], hist, torch.tensor([bool(z["reset"][t]) or t == 0]))
            b = st_.base(rgbd, [x["jitter"]])
        ref = z["reference"][t].astype(np.float32)
        refp = pq_encode(torch.from_numpy(ref).permute(2, 0, 1)[None])
        if t >= 4:
            pp = lambda a: -10 * np.log10(float(((a.clamp(0, 1) - refp) ** 2).mean()))
            tm = lambda a: metrics.psnr(pq_decode(a.clamp(0, 1))[0].permute(1, 2, 0).numpy(), ref)
            r.append((pp(y), pp(b), tm(y), tm(b)))
    r = np.array(r).mean(0)
    a = torch.stack(acts).mean(0); acts.clear()
    print(f"  un.8 alive (positive on >=1% of pixels) {float((a >= 0.01).float().mean()):.3f}, positive {float(a.mean()):.3f}")
    print(p, f"PQ net {r[0]:.3f} base {r[1]:.3f} ({r[0]-r[1]:+.3f}) | tonemapped net {r[2]:.3f} base {r[3]:.3f} ({r[2]-r[3]:+.3f})", flush=True)
