"""Quadson's body kinematics: world feet <-> shoulder-frame feet <-> motor angles (seed 000
Algorithm 4, seed 003 eq. 11), on the generic pose functions of quadson_mjx.pose.

A body pose is (..., 6) = (x, y, z, roll, pitch, yaw) [m, rad] (quadson_mjx.pose; seed 003 names the
angles but does not print T_M). Leg i's shoulder frame sits at constants.SHOULDER_POS[i] in the
body with axes constants.SHOULDER_ROT[i], so a world point p maps to the shoulder frame by
(T_body T_shoulder_i)^-1 p (seed 003 eq. 11; seed 000 Algorithm 4 steps 4-6).
Feet arrays are (..., 4, 3) in leg order constants.LEGS.
"""

from __future__ import annotations

import jax
import numpy as np

from quadson_mjx.pose import body_rotation, body_transform, frames_to_world, world_to_frames  # noqa: F401
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar


def world_to_shoulder(pose: jax.Array, feet_world: jax.Array) -> jax.Array:
    """Algorithm 4: pose (..., 6), feet_world (..., 4, 3) world points [m] -> (..., 4, 3) each
    foot in its own leg's shoulder frame [m]."""
    return world_to_frames(pose, feet_world, C.SHOULDER_POS, C.SHOULDER_ROT)


def shoulder_to_world(pose: jax.Array, feet_shoulder: jax.Array) -> jax.Array:
    """Inverse of `world_to_shoulder`: pose (..., 6), feet_shoulder (..., 4, 3) [m] -> (..., 4, 3)
    world points [m]."""
    return frames_to_world(pose, feet_shoulder, C.SHOULDER_POS, C.SHOULDER_ROT)


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
