"""The MuJoCo model an environment steps: the robot's scene with the env config's physics options.

`training_model` loads the robot's flat or rough scene and applies what the config chooses for
speed (no sensor evaluation, feet-only ground contact, no joint-limit rows) and the solver options
(cone, solver, mass-matrix storage); `put_model` hands it to MJX with the chosen implementation.
`name_ids` looks names up once (Python never hard-codes a model index).
"""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import mjx

from quadson_mjx import warp_notice
from quadson_mjx.env_config import CONES, JACOBIANS, SOLVERS

BASE_GEOM = "base_collision"  # the base's box, every robot's


def name_ids(model: mujoco.MjModel, objtype: mujoco.mjtObj, names) -> np.ndarray:
    """Ids of `names` of one object type; KeyError naming the missing ones."""
    ids = np.array([mujoco.mj_name2id(model, objtype, n) for n in names], dtype=np.int64)
    missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
    if missing:
        raise KeyError(f"{objtype.name} {missing} not in the model")
    return ids


def training_model(robot, cfg) -> mujoco.MjModel:
    """robot: quadson_mjx.robots.Robot; cfg: an env config -> a fresh MjModel of its terrain's scene."""
    m = robot.load_model(cfg.terrain, cfg.get("fivebar_model", "full"))
    # Observations and rewards read qpos/qvel directly, so MJX need not evaluate the sensors
    # (measured on one H100: ~7% of a physics step). Rollouts that log sensors use their own model.
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    if not cfg.base_terrain_contact:
        base_geom = int(name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, [BASE_GEOM])[0])
        m.geom_contype[base_geom] = 0
        m.geom_conaffinity[base_geom] = 0
    if not cfg.joint_limits:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    m.opt.cone = CONES[cfg.cone]
    m.opt.solver = SOLVERS[cfg.solver]
    m.opt.jacobian = JACOBIANS[cfg.jacobian]
    return m


def put_model(m: mujoco.MjModel, impl: str):
    """mjx.put_model with the config's implementation; "warp" needs warp-lang and mujoco_warp, and
    their import error is reported here, where it matters, not at every import of mujoco.mjx."""
    if impl == "warp":
        warp_notice.require_warp()
    return mjx.put_model(m, impl=impl)


def base_bottom_points(half_size, n_x: int = 5, n_y: int = 3) -> np.ndarray:
    """(n_x * n_y, 3) grid over the bottom face of a box of half_size (3,) [m], box frame: where a
    tilted box meets a height field first (its lowest points are on that face up to 90 deg of tilt)."""
    hx, hy, hz = half_size
    x, y = np.meshgrid(np.linspace(-hx, hx, n_x), np.linspace(-hy, hy, n_y), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, -hz)], axis=-1)
