"""Quaternions (wxyz, MuJoCo's order), one set of helpers for numpy and JAX arrays.

Each function works on numpy arrays (the deploy loop, the MCAP writer, MuJoC C rollouts) and on JAX
arrays and tracers (the environment, under jit and vmap), with the namespace of its input
(`quadson_mjx.arrays.namespace`), so this module never imports jax itself: the robot's control
loop runs without it. Batched: a quaternion is (..., 4), a vector (..., 3).
"""

from __future__ import annotations

import math

import numpy as np

from quadson_mjx.arrays import namespace

_CONJ = (1.0, -1.0, -1.0, -1.0)


def quat_to_rpy(quat):
    """quat (..., 4) wxyz -> (..., 3) roll, pitch, yaw [rad], ZYX convention (R = Rz Ry Rx)."""
    xp = namespace(quat)
    quat = xp.asarray(quat)
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    roll = xp.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = xp.asin(xp.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = xp.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return xp.stack([roll, pitch, yaw], axis=-1)


def _cross(xp, a, b):
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return xp.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_rotate(quat, vec):
    """Rotates vec (..., 3) from the frame of quat (..., 4, wxyz) into the parent (world) frame."""
    xp = namespace(quat, vec)
    quat, vec = xp.asarray(quat), xp.asarray(vec)
    w, u = quat[..., :1], quat[..., 1:]
    t = 2.0 * _cross(xp, u, vec)
    return vec + w * t + _cross(xp, u, t)


def quat_conj(quat):
    """The conjugate (inverse of a unit quaternion) of quat (..., 4, wxyz): the vector part negated,
    which is exact in floating point."""
    xp = namespace(quat)
    quat = xp.asarray(quat)
    return quat * xp.asarray(_CONJ, dtype=quat.dtype)


def quat_rotate_inverse(quat, vec):
    """Rotates world-frame vec (..., 3) into the frame of quat (..., 4, wxyz)."""
    return quat_rotate(quat_conj(quat), vec)


def quat_mul(a, b):
    """Hamilton product a * b of wxyz quaternions (..., 4): rotate by b, then by a."""
    xp = namespace(a, b)
    a, b = xp.asarray(a), xp.asarray(b)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def tilt_quat(roll_pitch):
    """(..., 2) roll, pitch [rad] -> (..., 4) wxyz quaternion of R = Ry(pitch) Rx(roll) (ZYX, no
    yaw): an IMU's mounting tilt (quadson_mjx.sensors draws it, quadson_mjx.deploy_imu removes it)."""
    xp = namespace(roll_pitch)
    roll_pitch = xp.asarray(roll_pitch)
    r, p = roll_pitch[..., 0] / 2, roll_pitch[..., 1] / 2
    cr, sr, cp, sp = xp.cos(r), xp.sin(r), xp.cos(p), xp.sin(p)
    return xp.stack([cp * cr, cp * sr, sp * cr, -sp * sr], axis=-1)


def axis_quat(axis: int, angle: float) -> np.ndarray:
    """wxyz rotation (numpy, float64) by angle [rad] about body axis 0 (x), 1 (y) or 2 (z)."""
    q = np.zeros(4)
    q[0], q[1 + axis] = math.cos(angle / 2), math.sin(angle / 2)
    return q
