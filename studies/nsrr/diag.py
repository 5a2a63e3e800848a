"""Why do the U-Net's units die? A few dozen recipe steps with per-layer ReLU activity
(fraction of units positive on >=1% of pixels; fraction of positive activations),
un.8 bias mean, and the PSNR gain of the output over the base on the batch."""
import sys, argparse, numpy as np, torch, torch.nn.functional as F
sys.path.insert(0, ".")
from clss.methods.nsrr import networks as nets
from weights_tools.methods.nsrr import recipe as T
from weights_tools.methods.nsrr.twin import NsrrNet, TorchStep
from weights_tools.trainloop import load_sequences, ssim
ap = argparse.ArgumentParser()
ap.add_argument("--data", default="out/data/train4"); ap.add_argument("--steps", type=int, default=60)
ap.add_argument("--lr", type=float, default=2e-3); ap.add_argument("--init", default="orig")
ap.add_argument("--every", type=int, default=10); ap.add_argument("--act", default="relu")
a = ap.parse_args()
torch.set_num_threads(1); torch.manual_seed(0); rng = np.random.default_rng(0)
seqs = T._prepare(load_sequences(a.data, 1, T.REQUIRED), torch)
sc = seqs[0]["scale"]; pr = 64 // sc; margin = 4
cfg = nets.make_config("default", 4, residual=True, act=a.act)
w = nets.init_weights(cfg, 0)
if "zero9" in a.init: w["un.9.weight"][:] = 0
if "bias8" in a.init: w["un.8.bias"][:] = 0.1
net = NsrrNet(cfg, w); step = TorchStep(net, sc)
acts = {}
def hook(name):
    def f(m, i, o): acts[name] = o.detach()
    return f
for i, c in enumerate(net.un): c.register_forward_hook(hook(f"un.{i}"))
opt = torch.optim.Adam(net.parameters(), lr=a.lr)
picks = T.choose_patches(seqs, 1000, 0.3, pr, margin, np.random.default_rng(0))
m = margin * sc
for it in range(a.steps):
    rgbd, mot, jit, rst, ref = T.make_batch(seqs, picks, 8, pr, margin, 4, 0.2, rng, torch)
    y = T.forward(step, rgbd, mot, jit, rst)[:, :, m:m + 64, m:m + 64]
    ya, yb = T.ycbcr(y.clamp(0, 1), 4.0), T.ycbcr(ref, 4.0)
    loss = 1 - ssim(ya, yb) + (ya - yb).abs().mean()
    opt.zero_grad(); loss.backward()
    g8 = net.un[8].weight.grad.norm().item(); g0 = net.un[0].weight.grad.norm().item()
    opt.step()
    if it % a.every == 0 or it == a.steps - 1:
        with torch.no_grad():
            base = step.base(rgbd[-1], jit[-1])[:, :, m:m + 64, m:m + 64]
            pb = -10 * torch.log10(((base.clamp(0, 1) - ref) ** 2).mean()).item()
            py = -10 * torch.log10(((y.clamp(0, 1) - ref) ** 2).mean()).item()
        s = []
        for k in (0, 1, 5, 7, 8):
            z = acts[f"un.{k}"]; pos = (z > 0).float()
            s.append(f"un{k} alive {(pos.mean((0, 2, 3)) > 0.01).float().mean():.2f}/{pos.mean():.2f}")
        print(f"{it} loss {loss.item():.4f} dPSNR {py - pb:+.3f} g0 {g0:.2e} g8 {g8:.2e} b8 {net.un[8].bias.mean().item():+.3f} "
              + " ".join(s), flush=True)
