"""How deep do contacts sink, and how far do the five-bars open, while the committed get-up policy
stands the robot up in MuJoCo C? The same knock-downs as quadson-knockdown (shove, flat ground, the
mirror-trained get-up policy), with sim2sim_plant.Plant.advance wrapped to take, after every
control tick, the deepest contact (MuJoCo's contact distance, negative inside) and the largest
closure residual. It calibrates getup_rollover's physics checks (PENETRATION_MAX_M,
CLOSURE_MAX_M) against motions that do get up.

    python results/getup_h100/knockdown_contact_depth.py 10 > results/getup_h100/knockdown_contact_depth.log
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

from quadson_mjx import export, knockdown
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.robots.quadson import model as quadson_model

n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
trial = {"depth": 0.0, "gap": 0.0}
advance = P.Plant.advance


def watched(self, seconds):
    advance(self, seconds)
    d = self.d
    if d.ncon:
        trial["depth"] = max(trial["depth"], -float(d.contact.dist[: d.ncon].min()))
    trial["gap"] = max(trial["gap"], float(quadson_model.closure_residual(self.m, d).max()))


P.Plant.advance = watched
folder = Path(tempfile.mkdtemp())
walk = export.export_run("results/policy_h100_sensors", folder / "walk.onnx")
getup = export.export_run("results/getup_mirror_h100", folder / "getup.onnx")
print("trial  fell and got up  deepest contact [mm]  largest closure residual [mm]")
rows = []
for i in range(n):
    trial.update(depth=0.0, gap=0.0)
    _, (row,) = knockdown.run_knockdowns(walk, getup, n=1, seed=0, knock="shove", first=i)
    stood = bool(row["detected"] and row["success"])  # knocked down, got up and walked on
    rows.append((stood, trial["depth"], trial["gap"]))
    print(f"{i:5d}  {str(stood):15s}  {1000 * trial['depth']:20.2f}  {1000 * trial['gap']:29.3f}", flush=True)
r = np.array(rows, float)
for name, sel in (("stood", r[:, 0] > 0), ("did not", r[:, 0] == 0)):
    if sel.any():
        print(
            f"{name}: {sel.sum():.0f} trials, deepest contact {1000 * r[sel, 1].max():.2f} mm (median "
            f"{1000 * np.median(r[sel, 1]):.2f}), largest closure residual {1000 * r[sel, 2].max():.3f} mm"
        )
