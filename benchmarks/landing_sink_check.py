"""How often MuJoCo C lands a dropped robot on the stone field with part of it inside a stone.

    python benchmarks/landing_sink_check.py --drops 128 --timesteps 0.004 0.002 0.001

The get-up task's drops (GetupEnv.reset on the stones: 0.2-0.5 m, random orientation and motor
angles) are held 1 s at their start targets in MuJoCo C (mj_step) at each physics timestep and
number of constraint-solver iterations (the training physics runs 1, the sim-to-sim plant 100). For
every landed robot: the deepest ground-colliding geom's centre below the ground under it (the
project's height query, tested against MuJoCo's ray casts), and for that geom MuJoCo's own
mj_rayHfield surface height under its centre and how many contacts MuJoCo C reports for it. A
geom whose centre lies below the surface with no contact reported is inside a stone, unseen by
MuJoCo C's height-field collision (benchmarks/warp_backend.py found such starts: both MJX
implementations meet those geoms as contacts centimetres deep).
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np
from warp_backend import collide, mujoco_c, starts, sunk_m


def deepest(m: mujoco.MjModel, q: np.ndarray) -> tuple[int, float, float, int]:
    """-> (geom, its centre's z, the height field's surface under it by mj_rayHfield, MuJoCo C's
    contacts of that geom) for the deepest ground-colliding geom of one landed robot."""
    floor = next(g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    worst, geom = -np.inf, -1
    for g in range(m.ngeom):
        if g == floor or not collide(m, g, floor):
            continue
        p = d.geom_xpos[g]
        top = 1.0
        surface = top - mujoco.mj_rayHfield(
            m, d, floor, np.array([p[0], p[1], top]), np.array([0.0, 0.0, -1.0])
        )
        if surface - p[2] > worst:
            worst, geom = surface - p[2], g
    contacts = sum(1 for c in d.contact[: d.ncon] if geom in (c.geom1, c.geom2))
    return geom, float(d.geom_xpos[geom][2]), float(d.geom_xpos[geom][2] + worst), contacts


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--drops", type=int, default=128)
    p.add_argument("--timesteps", type=float, nargs="+", default=[0.004, 0.002, 0.001])
    p.add_argument(
        "--iterations",
        type=int,
        nargs="+",
        default=[1, 100],
        help="constraint-solver iterations (training: 1)",
    )
    args = p.parse_args(argv)
    m, q0, u = starts("getup_stones", None, args.drops)
    for iterations, dt in ((i, t) for i in args.iterations for t in args.timesteps):
        m.opt.timestep, m.opt.iterations = dt, iterations
        q = mujoco_c(m, q0, u, 50)["qpos"]  # 50 control steps of 0.02 s: 1 s
        s = sunk_m(m, q)
        print(
            f"{iterations} solver iterations, timestep {dt * 1e3:g} ms: {np.sum(s > 0)} of {len(s)} landed drops with a geom's centre below the "
            f"ground under it ({np.sum(s > 0.005)} by > 5 mm, {np.sum(s > 0.01)} by > 1 cm, deepest {1e3 * s.max():.1f} mm)"
        )
        g, z, surface, contacts = deepest(m, q[int(np.argmax(s))])
        print(
            f"  the deepest: geom {g} ({mujoco.mjtGeom(m.geom_type[g]).name.removeprefix('mjGEOM_').lower()}, "
            f"radius {1e3 * m.geom_size[g][0]:.0f} mm), centre z {1e3 * z:.1f} mm, surface under it by ray "
            f"{1e3 * surface:.1f} mm, contacts of it in MuJoCo C: {contacts}",
            flush=True,
        )


if __name__ == "__main__":
    main()
