"""A body pose and the leg frames fixed to it: rotations, transforms, world <-> leg-frame points.

A body pose is (..., 6) = (x, y, z, roll, pitch, yaw) [m, rad]: the body centre in the world and its
orientation R = Rz(yaw) Ry(pitch) Rx(roll) (ZYX, the robots' convention). A robot's leg frames are
given as arguments: frame_pos (L, 3), the origin of leg i's frame in the body frame [m], and
frame_rot (L, 3, 3), whose columns are that frame's axes in body coordinates, so a world point p
maps to leg i's frame by (T_body T_leg_i)^-1 p (seed 003 eq. 11; seed 000 Algorithm 4 steps 4-6).
Quadson's shoulder frames: quadson_mjx.robots.quadson.body. Pure JAX, batched over leading axes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


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


def world_to_frames(pose: jax.Array, points_world: jax.Array, frame_pos, frame_rot) -> jax.Array:
    """pose (..., 6), points_world (..., L, 3) world points [m] -> (..., L, 3) point i in leg frame i [m]."""
    pose = jnp.asarray(pose)
    points_world = jnp.asarray(points_world, pose.dtype)
    rot = body_rotation(pose[..., 3:6])  # (..., 3, 3)
    pos_s, rot_s = jnp.asarray(frame_pos, pose.dtype), jnp.asarray(frame_rot, pose.dtype)
    # body = R^T (world - p); frame_i = R_i^T (body - s_i); row vectors: v R is R^T v.
    points_body = (points_world - pose[..., None, 0:3]) @ rot
    return jnp.einsum("...lj,ljk->...lk", points_body - pos_s, rot_s)


def frames_to_world(pose: jax.Array, points_frames: jax.Array, frame_pos, frame_rot) -> jax.Array:
    """Inverse of `world_to_frames`: pose (..., 6), points (..., L, 3) in their leg frames [m] ->
    (..., L, 3) world points [m]."""
    pose = jnp.asarray(pose)
    points_frames = jnp.asarray(points_frames, pose.dtype)
    rot = body_rotation(pose[..., 3:6])
    pos_s, rot_s = jnp.asarray(frame_pos, pose.dtype), jnp.asarray(frame_rot, pose.dtype)
    points_body = jnp.einsum("ljk,...lk->...lj", rot_s, points_frames) + pos_s
    return points_body @ jnp.swapaxes(rot, -1, -2) + pose[..., None, 0:3]
