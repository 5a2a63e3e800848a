"""NSRR frame step vs onnxruntime at 270p -> 1080p (4x), fp32 (bench.methods.nsrr.measure),
with clss.Model keeping 2 launch plans (now) and 1 (before), same process."""
import json, sys
import clss.model as cm
from bench.methods.nsrr import measure
prec = sys.argv[1] if len(sys.argv) > 1 else "fp32"
rs, s = ((270, 480), 4.0) if (len(sys.argv) < 3 or sys.argv[2] == "4") else ((540, 960), 2.0)
r = measure(rs, s, prec, frames=3)
print("plans 2", json.dumps(r), flush=True)
cm.PLANS_KEPT = 1
r1 = measure(rs, s, prec, frames=3, ort=False)
print("plans 1", json.dumps(r1), flush=True)
