"""Whether the knock-down trials in MuJoCo C leave part of the robot inside a stone.

    python benchmarks/knockdown_sink_check.py --walk results/policy_h100_sensors \
        --getup results/getup_mirror_h100 --trials 50 --seed 0

Runs the knock-down trials of `python eval/knockdown.py --knock shove --terrain stones` (the same
supervisor, plant, seeds and trial function, quadson_mjx.knockdown) and every --every ticks takes,
over the plant's geoms that collide with the height field, the deepest centre below the surface
under it (MuJoCo's mj_rayHfield), and whether MuJoCo C reports a contact for that geom. Prints one
line per trial (its success as eval/knockdown.py counts it, the deepest sink and when) and a
summary. benchmarks/landing_sink_check.py found dropped robots landing so.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import mujoco
import numpy as np
from warp_backend import collide

from quadson_mjx import knockdown
from quadson_mjx.cli.knockdown import policy_file


class SinkProbe:
    """A stand-in for the trial's recorder (knockdown._record calls step(k, plant, ...) every tick)."""

    writer = None
    t_ns = 0

    def __init__(self, plant, every: int):
        m = plant.m
        self.floor = next(g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD)
        f = self.floor
        self.parts = [g for g in range(m.ngeom) if g != f and collide(m, g, f)]
        self.every, self.deepest, self.at_tick, self.touching = every, -np.inf, -1, True

    def step(self, k, plant, *_):
        if k % self.every:
            return
        m, d = plant.m, plant.d
        down = np.array([0.0, 0.0, -1.0])
        for g in self.parts:
            p = d.geom_xpos[g]
            surface = 2.0 - mujoco.mj_rayHfield(m, d, self.floor, np.array([p[0], p[1], 2.0]), down)
            if surface - p[2] > self.deepest:
                touching = any(g in (c.geom1, c.geom2) for c in d.contact[: d.ncon])
                self.deepest, self.at_tick, self.touching = surface - p[2], k, touching


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--walk", required=True, help="walking policy: *.onnx or a run directory")
    p.add_argument("--getup", required=True, help="get-up policy: *.onnx or a run directory")
    p.add_argument("--trials", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--every", type=int, default=5, help="ticks between probes")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        walk = policy_file(args.walk, "walk", False, Path(tmp))
        getup = policy_file(args.getup, "getup", True, Path(tmp))
        sup, plant, _ = knockdown.build(walk, getup, "stones")
        rows = []
        for i in range(args.trials):  # seeded as knockdown.run_knockdowns seeds trial i
            plant_ss, trial_ss = np.random.SeedSequence([args.seed, i]).spawn(2)
            plant.rng = np.random.default_rng(plant_ss)
            probe = SinkProbe(plant, args.every)
            row = knockdown.run_trial(
                sup, plant, np.random.default_rng(trial_ss), recorder=probe, knock="shove"
            )
            rows.append((row["success"], probe.deepest, probe.at_tick * sup.dt, probe.touching))
            print(
                f"{i:3d} {'OK    ' if row['success'] else 'failed'} the lowest geom centre relative to the surface "
                f"under it: {-1e3 * probe.deepest:+6.1f} mm at {probe.at_tick * sup.dt:5.2f} s "
                f"({'in contact' if probe.touching else 'no contact'})",
                flush=True,
            )
    deep = [r for r in rows if r[1] > 0.01]
    print(
        f"{sum(r[1] > 0 for r in rows)} of {len(rows)} trials had a geom's centre below the surface at some probe; "
        f"{len(deep)} more than 1 cm inside a stone "
        f"({sum(r[0] for r in deep)} of them successes; {sum(not r[3] for r in deep)} with no contact for it); "
        f"successes {sum(r[0] for r in rows)} of {len(rows)}"
    )


if __name__ == "__main__":
    main()
