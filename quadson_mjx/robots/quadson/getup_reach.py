"""Can Quadson roll off its back? What its legs can reach, lying flat on the back, inside the real
motor limits.

    report = back_reach(mj_model, samples=20000)   # quadson_mjx.robots.quadson.model.load_model("flat")

A robot lying flat on its back rests on the base box's top face (body z = +BASE_HALF_SIZE[2]; the
ground is on the body's +z side). It can leave that pose in two ways only:
  * push: a leg's collision geometry (hip box, link capsules, foot sphere) reaches past the top
    face, into the ground, and pushes the body over;
  * tip: the legs move the centre of mass past an edge of the face it rests on (|y| > the box's
    half width across, |x| > its half length along), where gravity rolls the body over that edge.
back_reach samples motor angles uniformly in the limits, keeps those that pass getup_start's checks
of one leg (limits, toe-in guard, chain margin, assembly branch, clear of the base box), and
reports per leg the farthest reach toward the ground [m] beyond the top face (negative: the leg
cannot touch it) and the range of the leg's mass moment m * y and m * x [kg m] (MuJoCo C's body
masses and frames, the passive knees from the five-bar FK); the legs are independent, so the
largest sideways shift of the whole robot's centre of mass is the base's plus every leg's largest
moment, over the total mass. Quasi-static only: a fast swing of the legs can rock the body
(reaction torques), which this bound does not cover; the trained policy and its evaluation do.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar, getup_start
from quadson_mjx.robots.quadson import model as quadson_model


def _leg_bodies(m: mujoco.MjModel) -> list[list[int]]:
    """Per leg (LEGS order), the bodies of that leg (every body below the base whose name starts
    with the leg's prefix)."""
    out = []
    for leg in C.LEGS:
        out.append([b for b in range(m.nbody) if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or "").startswith(f"{leg}_")])  # fmt: skip
    return out


def back_reach(mj_model: mujoco.MjModel, samples: int = 20000, seed: int = 0) -> dict:
    """The module docstring's report for `samples` uniform draws per leg (rng `seed`) -> dict:
    valid_share (of the draws passing the checks), reach_m (4,) per leg the farthest any of its
    geoms gets past the top face toward the ground [m], com_y_m (lo, hi) and com_x_m (lo, hi) the
    range of the whole robot's centre of mass in the body frame [m], box_half_m (3,) the base box's
    half sizes [m], and can_push / can_tip_sideways / can_tip_lengthwise (bool)."""
    if samples < 1:
        raise ValueError(f"back_reach: samples {samples}: need at least 1")
    rng = np.random.default_rng(seed)
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    draws = rng.uniform(lo, hi, (samples, 4, 3)).astype(np.float32)  # independent draws per leg
    config = getup_start.StartConfig()
    ok = np.asarray(jax.jit(jax.vmap(lambda a: getup_start.legs_ok(a, config)))(jnp.asarray(draws)))

    def reach(a):  # (4, 3) -> (4,) the highest body z of each leg's geoms
        seg_a, seg_b, radii, hip_c, hip_r, hip_h = getup_start.leg_geometry(a)
        caps = jnp.max(jnp.maximum(seg_a[..., 2], seg_b[..., 2]) + radii, axis=-1)
        hips = hip_c[:, 2] + jnp.sum(jnp.abs(hip_r[:, 2, :]) * hip_h, axis=-1)
        return jnp.maximum(caps, hips)

    top = np.asarray(jax.jit(jax.vmap(reach))(jnp.asarray(draws)))  # (S, 4)
    half = np.asarray(C.BASE_HALF_SIZE, np.float64)
    reach_m = np.where(ok, top, -np.inf).max(axis=0) - half[2]

    ids = quadson_model.model_ids(mj_model)
    motor_adr = ids.motor_qposadr.reshape(4, 3)
    knee_adr = ids.passive_qposadr.reshape(4, -1)
    pts = fivebar.leg_points(jnp.asarray(draws))
    knees = np.stack([np.asarray(pts.knee2), np.asarray(pts.knee4)], -1)[..., : knee_adr.shape[1]]
    d = mujoco.MjData(mj_model)
    bodies = _leg_bodies(mj_model)
    moment = np.zeros((samples, 4, 2))  # per draw and leg: sum of m * (x, y) over the leg's bodies
    for s in range(samples):
        d.qpos[:] = 0.0
        d.qpos[3] = 1.0
        d.qpos[motor_adr.ravel()] = draws[s].ravel()
        d.qpos[knee_adr.ravel()] = knees[s].ravel()
        mujoco.mj_kinematics(mj_model, d)
        for leg, bs in enumerate(bodies):
            moment[s, leg] = (mj_model.body_mass[bs, None] * d.xipos[bs, :2]).sum(axis=0)
    base = [b for b in range(1, mj_model.nbody) if not any(b in bs for bs in bodies)]
    base_moment = (mj_model.body_mass[base, None] * d.xipos[base, :2]).sum(axis=0)  # frames fixed
    total = float(mj_model.body_mass[1:].sum())
    masked = np.where(ok[..., None], moment, np.nan)
    low = (base_moment + np.nansum(np.nanmin(masked, axis=0), axis=0)) / total  # (x, y)
    high = (base_moment + np.nansum(np.nanmax(masked, axis=0), axis=0)) / total
    return {
        "samples_per_leg": samples,
        "valid_share": float(ok.mean()),
        "reach_m": reach_m.tolist(),
        "com_x_m": [float(low[0]), float(high[0])],
        "com_y_m": [float(low[1]), float(high[1])],
        "box_half_m": half.tolist(),
        "can_push": bool(np.max(reach_m) > 0.0),
        "can_tip_sideways": bool(max(-low[1], high[1]) > half[1]),
        "can_tip_lengthwise": bool(max(-low[0], high[0]) > half[0]),
    }


if __name__ == "__main__":  # python -m quadson_mjx.robots.quadson.getup_reach [SAMPLES] > report.json
    import json
    import sys

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20000
    print(json.dumps(back_reach(quadson_model.load_model("flat"), samples=n), indent=1))
