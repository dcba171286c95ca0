"""Kinematics of one Quadson leg, a closed five-bar linkage with an abduction motor (seed 000).

Frames and angle conventions are those of `constants`: the shoulder frame has its origin at p1,
x toward p5, y up; the motor angles (t0, t1, t5) are measured as in seed Algorithm 1 (t1, t5
clockwise from +x in the leg plane, seen from +z; t0 rotates the plane about +x). In-plane points
use the "clockwise" angle measure phi: a link of length L at angle phi spans L (cos phi, -sin phi).

Rotation sign (robots.md): FK maps the planar foot (x, y) to (x, y cos t0, y sin t0) and IK uses
t0 = -atan2(z, -y). Algorithm 1 step 5 as printed (R(-t0) times a column vector) has the
opposite sign; the robot's own code multiplies a row vector, which gives the form used here.

All functions take arrays of any batch shape (...) and keep the input dtype; they are pure and
jit/vmap friendly.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from quadson_mjx import constants as C


class LegPoints(NamedTuple):
    """Joint positions of one leg in the shoulder frame [m], each (..., 3), and link angles [rad].

    theta2, theta4: absolute in-plane angles of links p2->p3 and p4->p3, measured like t1
    (p3 = p2 + L2 (cos theta2, -sin theta2) in the leg plane). knee2 = theta2 - t1 and
    knee4 = theta4 - t5, wrapped to (-pi, pi]: the angles that passive hinges at p2 and p4 with
    axis -z read when the motor hinges also have axis -z and every link lies along +x at zero.
    """

    p1: jax.Array
    p2: jax.Array
    p3: jax.Array
    p4: jax.Array
    p5: jax.Array
    foot: jax.Array
    theta2: jax.Array
    theta4: jax.Array
    knee2: jax.Array
    knee4: jax.Array


# --- numerically safe primitives -------------------------------------------------------------


@jax.custom_jvp
def safe_acos(x: jax.Array) -> jax.Array:
    """acos(clip(x, -1, 1)) with a finite derivative everywhere.

    The true derivative -1/sqrt(1 - x^2) is infinite at x = +-1 (the workspace boundary and the
    stretched-leg singularity); here it is capped at -1/sqrt(eps) and is zero outside [-1, 1],
    where the value is clamped.
    """
    return jnp.arccos(jnp.clip(x, -1.0, 1.0))


@safe_acos.defjvp
def _safe_acos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    eps = jnp.finfo(jnp.result_type(x)).eps
    inside = jnp.abs(x) < 1.0
    d = -jax.lax.rsqrt(jnp.maximum(1.0 - jnp.clip(x, -1.0, 1.0) ** 2, eps))
    return safe_acos(x), jnp.where(inside, d, 0.0) * dx


def _safe_norm(v: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis, with a finite gradient at v = 0."""
    sq = jnp.sum(v * v, axis=-1)
    tiny = jnp.finfo(jnp.result_type(v)).tiny
    return jnp.sqrt(jnp.maximum(sq, tiny))


def _cw_angle(v: jax.Array) -> jax.Array:
    """Clockwise angle phi of planar vectors v (..., 2): v = |v| (cos phi, -sin phi)."""
    return jnp.arctan2(-v[..., 1], v[..., 0])


def _cw_dir(phi: jax.Array) -> jax.Array:
    """Unit planar vector (..., 2) at clockwise angle phi."""
    return jnp.stack([jnp.cos(phi), -jnp.sin(phi)], axis=-1)


def _wrap(a: jax.Array) -> jax.Array:
    """Wrap angles to (-pi, pi]."""
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def _to_3d(p: jax.Array, t0: jax.Array) -> jax.Array:
    """Planar points (..., 2) -> shoulder frame (..., 3): (x, y) -> (x, y cos t0, y sin t0)."""
    c, s = jnp.cos(t0)[..., None], jnp.sin(t0)[..., None]
    x, y = p[..., 0:1], p[..., 1:2]
    return jnp.concatenate([x, y * c, y * s], axis=-1)


# --- forward kinematics (seed 000, Algorithm 1) -----------------------------------------------


def _planar_points(t1: jax.Array, t5: jax.Array):
    """Planar five-bar solution: p2, p3, p4, foot (..., 2) and theta2, theta4 (...)."""
    p2 = C.L1 * _cw_dir(t1)
    p5 = jnp.stack([jnp.full_like(t1, C.L0), jnp.zeros_like(t1)], axis=-1)
    p4 = p5 + C.L5 * _cw_dir(t5)
    d24 = p4 - p2
    l24 = _safe_norm(d24)
    # Angle at p2 between p2->p4 and p2->p3 (triangle p2 p3 p4, law of cosines). Algorithm 1 writes
    # theta2 = acos(.) + acos(angle p1-p2-p4) - (pi - t1): that sum equals the clockwise angle of
    # p2->p4 only while p4 lies clockwise of p2->p1; atan2 gives that angle on every pose.
    alpha = safe_acos((C.L2**2 + l24**2 - C.L4**2) / (2.0 * C.L2 * l24))
    theta2 = _cw_angle(d24) + alpha
    u2 = _cw_dir(theta2)
    p3 = p2 + C.L2 * u2
    foot = p2 + (C.L2 + C.L3) * u2
    theta4 = _cw_angle(p3 - p4)
    return p2, p3, p4, foot, theta2, theta4


def leg_points(angles: jax.Array) -> LegPoints:
    """All joints of one leg. angles: (..., 3) motor angles (t0, t1, t5) [rad] -> LegPoints, points
    (..., 3) in the shoulder frame [m] (after the t0 rotation), angles (...) [rad]."""
    angles = jnp.asarray(angles)
    if not jnp.issubdtype(angles.dtype, jnp.floating):
        angles = angles.astype(jnp.result_type(float))
    t0, t1, t5 = angles[..., 0], angles[..., 1], angles[..., 2]
    p2, p3, p4, foot, theta2, theta4 = _planar_points(t1, t5)
    zeros = jnp.zeros_like(angles)
    p5 = zeros.at[..., 0].set(C.L0)
    return LegPoints(
        p1=zeros,
        p2=_to_3d(p2, t0),
        p3=_to_3d(p3, t0),
        p4=_to_3d(p4, t0),
        p5=p5,
        foot=_to_3d(foot, t0),
        theta2=theta2,
        theta4=theta4,
        knee2=_wrap(theta2 - t1),
        knee4=_wrap(theta4 - t5),
    )


def leg_fk(angles: jax.Array) -> jax.Array:
    """Foot position (seed 000, Algorithm 1).

    angles: (..., 3) motor angles (t0, t1, t5) [rad] -> (..., 3) foot in the shoulder frame [m].
    """
    angles = jnp.asarray(angles)
    if not jnp.issubdtype(angles.dtype, jnp.floating):
        angles = angles.astype(jnp.result_type(float))
    *_, foot, _, _ = _planar_points(angles[..., 1], angles[..., 2])
    return _to_3d(foot, angles[..., 0])
