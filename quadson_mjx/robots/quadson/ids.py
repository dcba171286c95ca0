"""Names of the Quadson model looked up once (ModelIds), the home keyframe's qpos and ctrl, and the
five-bar closure residual of either leg model (model.FIVEBAR_MODELS); re-exported by model.py."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from quadson_mjx.robots.quadson import constants as C


@dataclass(frozen=True)
class ModelIds:
    """Indices of named model elements, looked up once. Motor arrays are (12,) in LEGS x MOTORS order
    (C.MOTOR_JOINTS), passive arrays (8,) in LEGS x PASSIVE order, feet (4,) in LEGS order."""

    motor_joint: np.ndarray
    motor_qposadr: np.ndarray
    motor_dofadr: np.ndarray
    motor_actuator: np.ndarray
    passive_qposadr: np.ndarray  # (4,) knee2 only in the light variant
    passive_dofadr: np.ndarray
    foot_site: np.ndarray
    closure_site2: np.ndarray  # (4,) site on link 2 at L2
    closure_site4: np.ndarray  # (4,) site on link 4 at L4 (full), on link 5 at p4 (light)
    closure_eq: np.ndarray  # (4,) equality ids
    closure_length_m: float  # distance the closure holds between the two sites: 0 (full), L4 (light)
    base_body: int
    imu_site: int
    root_qposadr: int  # free joint: qpos[adr:adr+7] = (x, y, z, qw, qx, qy, qz)
    root_dofadr: int
    sensor_adr: dict  # sensor name -> (adr, dim)


def _id(model, objtype, name: str) -> int:
    i = mujoco.mj_name2id(model, objtype, name)
    if i < 0:
        raise KeyError(f"{objtype.name} {name!r} not in the model")
    return i


def model_ids(model: mujoco.MjModel) -> ModelIds:
    """Looks every name of `constants` up in the model (raises KeyError on a missing one)."""
    J, A, S, B = (
        mujoco.mjtObj.mjOBJ_JOINT,
        mujoco.mjtObj.mjOBJ_ACTUATOR,
        mujoco.mjtObj.mjOBJ_SITE,
        mujoco.mjtObj.mjOBJ_BODY,
    )
    mj = np.array([_id(model, J, n) for n in C.MOTOR_JOINTS])
    eq = np.array([_id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"{leg}_closure") for leg in C.LEGS])
    light = bool(np.all(model.eq_type[eq] == mujoco.mjtEq.mjEQ_TENDON))
    passive = [n for n in C.PASSIVE_JOINTS if not (light and n.endswith("knee4_joint"))]
    pj = np.array([_id(model, J, n) for n in passive])
    base = _id(model, B, C.ROOT_BODY)
    root = int(model.body_jntadr[base])
    sensors = {}
    for i in range(model.nsensor):
        sensors[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i)] = (
            int(model.sensor_adr[i]),
            int(model.sensor_dim[i]),
        )
    return ModelIds(
        motor_joint=mj,
        motor_qposadr=model.jnt_qposadr[mj].copy(),
        motor_dofadr=model.jnt_dofadr[mj].copy(),
        motor_actuator=np.array([_id(model, A, n) for n in C.ACTUATORS]),
        passive_qposadr=model.jnt_qposadr[pj].copy(),
        passive_dofadr=model.jnt_dofadr[pj].copy(),
        foot_site=np.array([_id(model, S, n) for n in C.FEET]),
        closure_site2=np.array([_id(model, S, f"{leg}_closure2") for leg in C.LEGS]),
        closure_site4=np.array([_id(model, S, f"{leg}_closure4") for leg in C.LEGS]),
        closure_eq=eq,
        closure_length_m=C.L4 if light else 0.0,
        base_body=base,
        imu_site=_id(model, S, C.IMU_SITE),
        root_qposadr=int(model.jnt_qposadr[root]),
        root_dofadr=int(model.jnt_dofadr[root]),
        sensor_adr=sensors,
    )


def _key(model: mujoco.MjModel) -> int:
    return _id(model, mujoco.mjtObj.mjOBJ_KEY, C.HOME_KEYFRAME)


def home_qpos(model: mujoco.MjModel) -> np.ndarray:
    """(nq,) qpos of the `home` keyframe (closure satisfied, feet on the flat floor)."""
    return model.key_qpos[_key(model)].copy()


def home_ctrl(model: mujoco.MjModel) -> np.ndarray:
    """(nu,) ctrl of the `home` keyframe: the motor angles that hold the home pose [rad]."""
    return model.key_ctrl[_key(model)].copy()


# --- closure residual -------------------------------------------------------------------------------


def closure_residual(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """(4,) gap [m] of each leg's loop (0 when the five-bar is closed): the distance between the two
    p3 sites (full), or |p3 - p4| - L4 in absolute value (light). Reads data.site_xpos: call after
    mj_kinematics / mj_step."""
    ids = model_ids(model)
    d = data.site_xpos[ids.closure_site2] - data.site_xpos[ids.closure_site4]
    return np.abs(np.linalg.norm(d, axis=-1) - ids.closure_length_m)


def closure_residual_mjx(site_xpos: jax.Array, ids: ModelIds) -> jax.Array:
    """(..., 4) gap [m] of each leg's loop (closure_residual), from mjx.Data.site_xpos (..., nsite, 3)."""
    d = site_xpos[..., ids.closure_site2, :] - site_xpos[..., ids.closure_site4, :]
    return jnp.abs(jnp.sqrt(jnp.sum(d * d, axis=-1)) - ids.closure_length_m)
