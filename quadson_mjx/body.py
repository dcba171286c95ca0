"""Body kinematics: world feet <-> shoulder-frame feet <-> motor angles (seed 000 Algorithm 4,
seed 003 eq. 11).

A body pose is (..., 6) = (x, y, z, roll, pitch, yaw) [m, rad]: the body centre in the world and
its orientation R = Rz(yaw) Ry(pitch) Rx(roll) (ZYX, the robots' convention; seed 003 names the
angles but does not print T_M). Leg i's shoulder frame sits at constants.SHOULDER_POS[i] in the
body with axes constants.SHOULDER_ROT[i], so a world point p maps to the shoulder frame by
(T_body T_shoulder_i)^-1 p (seed 003 eq. 11; seed 000 Algorithm 4 steps 4-6).
Feet arrays are (..., 4, 3) in leg order constants.LEGS.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import fivebar
from quadson_mjx.robots.quadson import constants as C


def body_rotation(rpy: jax.Array) -> jax.Array:
    """rpy: (..., 3) roll, pitch, yaw [rad] -> (..., 3, 3) body-to-world rotation Rz Ry Rx."""
    rpy = jnp.asarray(rpy)
    cr, sr = jnp.cos(rpy[..., 0]), jnp.sin(rpy[..., 0])
    cp, sp = jnp.cos(rpy[..., 1]), jnp.sin(rpy[..., 1])
    cy, sy = jnp.cos(rpy[..., 2]), jnp.sin(rpy[..., 2])
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def body_transform(pose: jax.Array) -> jax.Array:
    """pose: (..., 6) (x, y, z, roll, pitch, yaw) [m, rad] -> (..., 4, 4) body-to-world transform T_b."""
    pose = jnp.asarray(pose)
    rot = body_rotation(pose[..., 3:6])
    top = jnp.concatenate([rot, pose[..., 0:3, None]], axis=-1)  # (..., 3, 4)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], pose.dtype), top.shape[:-2] + (1, 4))
    return jnp.concatenate([top, bottom], axis=-2)


def _shoulder_geometry(dtype):
    return jnp.asarray(C.SHOULDER_POS, dtype), jnp.asarray(C.SHOULDER_ROT, dtype)


def world_to_shoulder(pose: jax.Array, feet_world: jax.Array) -> jax.Array:
    """Algorithm 4: pose (..., 6), feet_world (..., 4, 3) world points [m] -> (..., 4, 3) each
    foot in its own leg's shoulder frame [m]."""
    pose = jnp.asarray(pose)
    feet_world = jnp.asarray(feet_world, pose.dtype)
    rot = body_rotation(pose[..., 3:6])  # (..., 3, 3)
    pos_s, rot_s = _shoulder_geometry(pose.dtype)
    # body = R^T (world - p); shoulder_i = R_i^T (body - s_i); row vectors: v R is R^T v.
    feet_body = (feet_world - pose[..., None, 0:3]) @ rot
    return jnp.einsum("...lj,ljk->...lk", feet_body - pos_s, rot_s)


def shoulder_to_world(pose: jax.Array, feet_shoulder: jax.Array) -> jax.Array:
    """Inverse of `world_to_shoulder`: pose (..., 6), feet_shoulder (..., 4, 3) [m] -> (..., 4, 3)
    world points [m]."""
    pose = jnp.asarray(pose)
    feet_shoulder = jnp.asarray(feet_shoulder, pose.dtype)
    rot = body_rotation(pose[..., 3:6])
    pos_s, rot_s = _shoulder_geometry(pose.dtype)
    feet_body = jnp.einsum("ljk,...lk->...lj", rot_s, feet_shoulder) + pos_s
    return feet_body @ jnp.swapaxes(rot, -1, -2) + pose[..., None, 0:3]


def body_ik(pose: jax.Array, feet_world: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Motor angles that put the feet at world points for a body pose (seed 003 eq. 11 + leg IK).

    pose (..., 6) [m, rad], feet_world (..., 4, 3) [m] -> (motor angles (..., 4, 3) (t0, t1, t5)
    [rad], valid (..., 4) bool); see `fivebar.leg_ik` for what valid means and what invalid legs get.
    """
    return fivebar.leg_ik(world_to_shoulder(pose, feet_world))


def nominal_feet_world(pose_height: float = C.STANCE_HEIGHT, x_in_leg=0.5 * C.L0) -> np.ndarray:
    """Standing feet for the body at (0, 0, pose_height), level: (4, 3) world points [m], z = 0.

    Each foot sits pose_height below its shoulder, at leg-frame x = x_in_leg [m] (scalar or (4,)
    per leg). The default L0 / 2 puts every foot under the midpoint of its leg's two motors.
    """
    x = np.broadcast_to(np.asarray(x_in_leg, dtype=np.float64), (C.NUM_LEGS,))
    feet_shoulder = np.stack([x, np.full(C.NUM_LEGS, -pose_height), np.zeros(C.NUM_LEGS)], axis=-1)
    feet_body = np.einsum("ljk,lk->lj", C.SHOULDER_ROT, feet_shoulder) + C.SHOULDER_POS
    return feet_body + np.array([0.0, 0.0, pose_height])
