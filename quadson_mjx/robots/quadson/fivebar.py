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
import numpy as np

from quadson_mjx.robots.quadson import constants as C


class LegPoints(NamedTuple):
    """Joint positions of one leg in the shoulder frame [m], each (..., 3), and link angles [rad].

    theta2, theta4: absolute in-plane angles of links p2->p3 and p4->p3 in (-pi, pi], measured
    like t1 (p3 = p2 + L2 (cos theta2, -sin theta2) in the leg plane). knee2 = theta2 - t1 and
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
def _sin_acos(x: jax.Array) -> jax.Array:
    """sin(acos(x)) = sqrt(1 - x^2) for x clamped to [-1, 1], with a finite derivative everywhere.

    Together with cos = clip(x, -1, 1) it turns a law-of-cosines angle into a rotation without
    evaluating acos, sin or cos: the kinematics needs one atan2 per output angle and no other
    transcendental (about twice the CPU throughput of acos + atan2 + sin/cos). The derivative
    -x / sqrt(1 - x^2) is infinite at x = +-1 (the workspace boundary, the stretched leg, the
    chain's lock-up); here it is capped at 1/sqrt(eps) there and is zero outside [-1, 1], where
    the value is clamped.
    """
    x = jnp.clip(x, -1.0, 1.0)
    return jnp.sqrt(jnp.maximum(1.0 - x * x, 0.0))


@_sin_acos.defjvp
def _sin_acos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    eps = jnp.finfo(jnp.result_type(x)).eps
    xc = jnp.clip(x, -1.0, 1.0)
    d = -xc * jax.lax.rsqrt(jnp.maximum(1.0 - xc**2, eps))
    return _sin_acos(x), jnp.where(jnp.abs(x) < 1.0, d, 0.0) * dx


def _safe_norm(v: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis, floored at eps * 1 m, with a finite gradient at v = 0.

    The floor is applied to the squared norm with a `where` (zero gradient below it), not with
    `maximum`: at v = 0 the squared norm ties with a floor of `tiny`, maximum sends half the
    gradient through sqrt' = 1 / (2 sqrt(tiny)), and a later 1 / norm^2 (the law of cosines)
    overflows to inf and gives NaN (leg_ik's gradient at the foot target (0, 0, 0)). eps * 1 m
    (1.2e-7 m in float32) lies below the rounding step of the leg's coordinates (~0.1 m * eps), so
    the values of every norm the kinematics can resolve are unchanged.
    """
    sq = jnp.sum(v * v, axis=-1)
    floor = jnp.square(jnp.finfo(jnp.result_type(v)).eps).astype(sq.dtype)
    return jnp.sqrt(jnp.where(sq > floor, sq, floor))


def _safe_atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """atan2(y, x), 0 at the origin, with a finite (zero) gradient there instead of NaN.

    "The origin" includes vectors whose squared length underflows (below the dtype's `tiny`,
    |v| < 1e-19 m in float32): atan2's derivative 1 / |v| is computed through |v|^2 and would be
    inf / NaN there."""
    ok = x * x + y * y >= jnp.finfo(jnp.result_type(x, y)).tiny
    return jnp.where(ok, jnp.arctan2(jnp.where(ok, y, 0.0), jnp.where(ok, x, 1.0)), 0.0)


def _cw_angle(v: jax.Array) -> jax.Array:
    """Clockwise angle phi of planar vectors v (..., 2): v = |v| (cos phi, -sin phi)."""
    return _safe_atan2(-v[..., 1], v[..., 0])


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
    """Planar five-bar solution: p2, p3, p4, foot (..., 2) and (cos, sin) of theta2 (...)."""
    c1, s1 = jnp.cos(t1), jnp.sin(t1)
    c5, s5 = jnp.cos(t5), jnp.sin(t5)
    p2 = C.L1 * jnp.stack([c1, -s1], axis=-1)
    p4 = jnp.stack([C.L0 + C.L5 * c5, -C.L5 * s5], axis=-1)
    d24 = p4 - p2
    l24 = _safe_norm(d24)
    # theta2 = (clockwise angle of p2->p4) + alpha, alpha the angle at p2 of the triangle p2 p3 p4
    # (law of cosines). Algorithm 1 writes theta2 = acos(.) + acos(angle p1-p2-p4) - (pi - t1):
    # that sum is the angle of p2->p4 only while p4 lies clockwise of p2->p1 (it breaks for
    # t1 > ~3.64 at t5 = 1, inside the limits); the direction of p2->p4 holds on every pose.
    # The sum of angles is taken as a rotation: cos/sin of the sum from those of the parts.
    cd, sd = d24[..., 0] / l24, -d24[..., 1] / l24
    ca_raw = (C.L2**2 + l24**2 - C.L4**2) / (2.0 * C.L2 * l24)
    ca, sa = jnp.clip(ca_raw, -1.0, 1.0), _sin_acos(ca_raw)
    c2, s2 = cd * ca - sd * sa, sd * ca + cd * sa
    u2 = jnp.stack([c2, -s2], axis=-1)
    p3 = p2 + C.L2 * u2
    foot = p2 + (C.L2 + C.L3) * u2
    return p2, p3, p4, foot, c2, s2


def leg_points(angles: jax.Array) -> LegPoints:
    """All joints of one leg. angles: (..., 3) motor angles (t0, t1, t5) [rad] -> LegPoints, points
    (..., 3) in the shoulder frame [m] (after the t0 rotation), angles (...) [rad]."""
    angles = jnp.asarray(angles)
    if not jnp.issubdtype(angles.dtype, jnp.floating):
        angles = angles.astype(jnp.result_type(float))
    t0, t1, t5 = angles[..., 0], angles[..., 1], angles[..., 2]
    p2, p3, p4, foot, c2, s2 = _planar_points(t1, t5)
    theta2 = jnp.arctan2(s2, c2)
    theta4 = _cw_angle(p3 - p4)
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


def chain_closes(angles: jax.Array) -> jax.Array:
    """Whether the five-bar can be assembled at these motor angles: |L4 - L2| <= |p4 - p2| <= L2 + L4.

    angles: (..., 3) (t0, t1, t5) [rad] -> (...) bool. Where it is False, `leg_fk` returns the
    clamped (links p2-p3 and p3-p4 folded or stretched) configuration.
    """
    angles = jnp.asarray(angles)
    p2 = C.L1 * _cw_dir(angles[..., 1])
    p4 = jnp.stack([jnp.full_like(angles[..., 2], C.L0), jnp.zeros_like(angles[..., 2])], -1)
    p4 = p4 + C.L5 * _cw_dir(angles[..., 2])
    l24 = jnp.linalg.norm(p4 - p2, axis=-1)
    return (l24 <= C.L2 + C.L4) & (l24 >= abs(C.L4 - C.L2))


def within_limits(angles: jax.Array) -> jax.Array:
    """Joint limits of the real robot (constants.MOTOR_RANGES) and the toe-in guard t5 - t1 <= TOE_IN_MAX.

    angles: (..., 3) (t0, t1, t5) [rad] -> (...) bool.
    """
    angles = jnp.asarray(angles)
    lo = jnp.asarray(C.MOTOR_RANGES[:, 0], angles.dtype)
    hi = jnp.asarray(C.MOTOR_RANGES[:, 1], angles.dtype)
    in_range = jnp.all((angles >= lo) & (angles <= hi), axis=-1)
    return in_range & (angles[..., 2] - angles[..., 1] <= C.TOE_IN_MAX)


# --- inverse kinematics (seed 000, Algorithm 2) -----------------------------------------------

# Why an IK target is rejected, in the order `leg_ik_checked` reports them.
IK_CHECKS: tuple[str, ...] = (
    "not a finite number (NaN or infinite coordinate)",
    "out of reach of the p1-p2-foot chain",
    "out of reach of the p5-p4-p3 chain",
    "t0 beyond its joint limit",
    "t1 beyond its joint limit",
    "t5 beyond its joint limit",
    "toe-in guard t5 - t1 > TOE_IN_MAX",
    "off the robot's assembly branch",
)


# Targets are clipped to +-IK_CLIP_M per coordinate before solving: the leg reaches
# L1 + L2 + L3 = 0.26 m, so a clipped target is out of reach either way, and its squares stay far
# from float32 overflow (a 1e30 m target would square to inf and give NaN angles).
IK_CLIP_M = 1.0


def _ik_solve(foot: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Algorithm 2 with its failure flags: foot (..., 3) [m] -> angles (..., 3), ok (..., len(IK_CHECKS)).

    A non-finite target is solved as the home stance's foot (finite angles, flagged not ok).
    """
    if foot.shape[-1:] != (3,):
        raise ValueError(f"foot must have shape (..., 3) [m], got {foot.shape}")
    finite = jnp.all(jnp.isfinite(foot), axis=-1)
    home = leg_fk(jnp.asarray(C.INITIAL_MOTOR_ANGLES, foot.dtype))
    foot = jnp.clip(jnp.where(finite[..., None], foot, home), -IK_CLIP_M, IK_CLIP_M)
    x, y, z = foot[..., 0], foot[..., 1], foot[..., 2]
    # Step 1-2: the sign of robots.md. With t0 = -atan2(z, -y), the in-plane
    # y' = y cos t0 + z sin t0 is exactly -sqrt(y^2 + z^2): the foot below the motor axis.
    t0 = -_safe_atan2(z, -y)
    r = _safe_norm(foot[..., 1:])
    pe = jnp.stack([x, -r], axis=-1)
    # Step 3: motor 1 from the triangle p1, p2, foot (L1, L2 + L3, |pe|):
    # t1 = (clockwise angle of p1->foot) + acos(c12), taken as a rotation (see `_sin_acos`).
    l1e = _safe_norm(pe)
    l23 = C.L2 + C.L3
    c12 = (C.L1**2 + l1e**2 - l23**2) / (2.0 * C.L1 * l1e)
    ce, se = x / l1e, r / l1e
    cb, sb = jnp.clip(c12, -1.0, 1.0), _sin_acos(c12)
    c1, s1 = ce * cb - se * sb, se * cb + ce * sb
    # Both parts lie in [0, pi], so t1 is in [0, 2 pi), where the limits [0.25 pi, 1.2 pi] live.
    t1 = jnp.arctan2(s1, c1)
    t1 = jnp.where(t1 < 0.0, t1 + 2.0 * jnp.pi, t1)
    # Step 4: p3 divides p2 -> foot in the ratio L2 : L3.
    p2 = C.L1 * jnp.stack([c1, -s1], axis=-1)
    p3 = (pe * C.L2 + p2 * C.L3) / l23
    # Step 5: motor 5 from the triangle p5, p4, p3 (L5, L4, |p3 - p5|). The seed's
    # theta5 = pi - (theta350 + theta354) is the clockwise angle of p5->p3 minus theta354.
    p5 = jnp.stack([jnp.full_like(x, C.L0), jnp.zeros_like(x)], axis=-1)
    d53 = p3 - p5
    l35 = _safe_norm(d53)
    c354 = (l35**2 + C.L5**2 - C.L4**2) / (2.0 * l35 * C.L5)
    cd, sd = d53[..., 0] / l35, -d53[..., 1] / l35
    cb, sb = jnp.clip(c354, -1.0, 1.0), _sin_acos(c354)
    c5, s5 = cd * cb + sd * sb, sd * cb - cd * sb
    t5 = jnp.arctan2(s5, c5)  # in (-pi, pi]
    angles = jnp.stack([t0, t1, t5], axis=-1)

    lo = jnp.asarray(C.MOTOR_RANGES[:, 0], foot.dtype)
    hi = jnp.asarray(C.MOTOR_RANGES[:, 1], foot.dtype)
    in_range = (angles >= lo) & (angles <= hi)
    # FK (Algorithm 1) puts p3 clockwise of p2 -> p4; a solution with p3 on the other side is a
    # pose of the other assembly mode, which the robot never reaches.
    p4 = p5 + C.L5 * jnp.stack([c5, -s5], axis=-1)
    d24, d23 = p4 - p2, p3 - p2
    cross = d24[..., 0] * d23[..., 1] - d24[..., 1] * d23[..., 0]
    tol = 64 * jnp.finfo(foot.dtype).eps * C.L2 * (C.L2 + C.L4)
    ok = jnp.stack(
        [
            finite,
            jnp.abs(c12) <= 1.0,
            jnp.abs(c354) <= 1.0,
            in_range[..., 0],
            in_range[..., 1],
            in_range[..., 2],
            t5 - t1 <= C.TOE_IN_MAX,
            cross <= tol,
        ],
        axis=-1,
    )
    return angles, ok


def leg_ik(foot: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Motor angles for a foot position, on the robot's branch (seed 000, Algorithm 2).

    foot: (..., 3) foot in the shoulder frame [m] -> (angles (..., 3) (t0, t1, t5) [rad],
    valid (...) bool). valid is False where the target is out of reach, beyond a joint limit
    (constants.MOTOR_RANGES), violates the toe-in guard or would need the other assembly mode.

    Never NaN: acos arguments are clamped to [-1, 1], so an out-of-reach target gets the nearest
    clamped configuration (the chain stretched or folded toward it); coordinates beyond
    +-IK_CLIP_M are clipped first (out of reach anyway); a NaN or infinite target gets the home
    stance's angles (constants.INITIAL_MOTOR_ANGLES). All of these are valid=False. Angles beyond a
    joint limit are returned as computed, not clipped. Gradients are finite everywhere (see
    `_sin_acos`). A last axis other than 3 raises ValueError (shapes are static, also under jit).
    """
    foot = jnp.asarray(foot)
    if not jnp.issubdtype(foot.dtype, jnp.floating):
        foot = foot.astype(jnp.result_type(float))
    angles, ok = _ik_solve(foot)
    return angles, jnp.all(ok, axis=-1)


_ik_solve_jit = jax.jit(_ik_solve)


def leg_ik_checked(foot) -> np.ndarray:
    """Eager IK that raises on bad targets: numpy (..., 3) [m] -> numpy (..., 3) [rad], float64.

    Raises ValueError naming the first failing target (in m) and the reason. Not for use in jit.
    """
    foot = np.asarray(foot, dtype=np.float64)
    if foot.shape[-1:] != (3,):
        raise ValueError(f"foot must have shape (..., 3), got {foot.shape}")
    with jax.enable_x64(True):
        angles, ok = _ik_solve_jit(jnp.asarray(foot))
        angles, ok = np.asarray(angles), np.asarray(ok)
    bad = ~np.all(ok, axis=-1)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        reasons = [r for r, good in zip(IK_CHECKS, ok[idx], strict=True) if not good]
        where = f" (index {idx})" if idx else ""
        raise ValueError(
            f"leg IK target {foot[idx].tolist()} m{where} is invalid: {'; '.join(reasons)}"
            f" (angles would be {angles[idx].tolist()} rad)"
        )
    return angles


# --- differential kinematics (seed 000, Algorithm 3) ------------------------------------------


def leg_jacobian(angles: jax.Array) -> jax.Array:
    """Exact foot Jacobian d foot / d angles by forward-mode autodiff.

    angles: (..., 3) (t0, t1, t5) [rad] -> (..., 3, 3) [m/rad], J[..., i, j] = d foot_i / d t_j.
    Finite everywhere; at the chain's lock-up pose (p2, p3, p4 collinear) the true derivative is
    infinite and this one is large (capped by `_sin_acos`).
    """
    angles = jnp.asarray(angles)
    return jnp.vectorize(jax.jacfwd(leg_fk), signature="(3)->(3,3)")(angles)


def leg_jacobian_fd(angles: jax.Array, delta: float = 1e-6) -> jax.Array:
    """The seed's numerical Jacobian: forward differences (f(t + delta e_i) - f(t)) / delta.

    angles: (..., 3) [rad] -> (..., 3, 3) [m/rad]. Truncation error O(delta); in float32 the
    default delta is near the angles' rounding step, so use float64 (or a larger delta) there.
    """
    angles = jnp.asarray(angles)
    eye = jnp.eye(3, dtype=angles.dtype) * delta
    f0 = leg_fk(angles)[..., :, None]  # (..., 3, 1)
    f1 = leg_fk(angles[..., None, :] + eye)  # (..., 3 perturbations, 3 coords)
    return (jnp.swapaxes(f1, -1, -2) - f0) / delta


def joint_velocities(angles: jax.Array, foot_vel: jax.Array, damping: float = 1e-3) -> jax.Array:
    """Motor velocities for a foot velocity by damped least squares (seed 000, Algorithm 3).

    angles: (..., 3) [rad], foot_vel: (..., 3) [m/s] in the shoulder frame -> (..., 3) [rad/s],
    J^T (J J^T + damping^2 I)^-1 v. damping [m/rad] keeps the result finite and bounded by
    |v| / (2 damping) at singular poses (e.g. the leg fully stretched); away from them it
    changes the answer by a relative O((damping / sigma_min)^2), about 1e-4 for sigma_min = 0.1.
    """
    angles = jnp.asarray(angles)
    foot_vel = jnp.asarray(foot_vel, angles.dtype)
    jac = leg_jacobian(angles)
    jjt = jac @ jnp.swapaxes(jac, -1, -2) + damping**2 * jnp.eye(3, dtype=angles.dtype)
    y = jnp.linalg.solve(jjt, foot_vel[..., None])
    return (jnp.swapaxes(jac, -1, -2) @ y)[..., 0]
