"""Serial 3-DoF leg (hip roll, femur pitch, knee pitch) with a lateral hip offset.

Forward kinematics by Denavit-Hartenberg transforms (seed 002), closed-form inverse kinematics with the
hip offset (seed 003 eq. 5-10, the law of cosines of seed 001), for the serial legs of the seed documents:
Caramel (seed 003) and Weefee's dimensions (seed 001). Quadson's own five-bar leg is in `fivebar.py`.

Hip frame (the project's body convention): origin on the abduction (roll) axis, x forward along that
axis, y left, z up. Joint angles q = (q1, q2, q3) [rad], each a right-handed rotation:
  * q1, hip roll about +x: positive swings the foot toward +y (left).
  * q2, femur pitch about the rolled +y axis: positive swings the femur backward (toward -x).
  * q3, knee pitch about the same axis, relative to the femur; q3 = 0 is a straight leg.
Zero pose: femur and tibia hang straight down in the leg plane, which lies `side * hip_offset` from the
roll axis: foot at (0, side L1, -(L2 + L3)).
side: +1 left leg (offset toward +y), -1 right leg; this is seed 003's `reflect` (left +1, right -1).
Weefee (seed 001) has +y pointing right: its right legs are side = -1 here, and a Weefee target
(x, y, z) is (x, -y, z) in this frame.

DH table (standard DH, T_i = Rz(theta) Tz(d) Tx(a) Rx(alpha), chained as seed 002 does), after the
fixed base rotation T_base = Ry(+pi/2), which is seed 002's T_0^1 and turns the DH z axis onto hip +x:

    i | theta | d          | a  | alpha
    1 | q1    | 0          | 0  | -pi/2     roll about hip x; z1 = rolled +y, x1 = rolled -z (down)
    2 | q2    | side * L1  | L2 | 0         femur joint side*L1 along z1, femur along x2
    3 | q3    | 0          | L3 | 0         knee, tibia along x3 to the foot

The offset is a DH d along the pitch axis, because it is perpendicular to the leg plane. Seed 002 puts
its coxa La in a (with alpha = 90 deg), which makes it a link in the leg plane, while its own IK
(alpha_2 = asin(La / A)) treats La as a lateral offset; we follow the IK. Seed 002's T_1^2 also prints
a 1 where its (2, 2) entry must be 0.

Knee branch: knee backward (q3 <= 0), Caramel's "full-elbow" legs, the branch of seed 003 eq. 7.
Closed form, with L1, L2, L3 = hip_offset, femur, tibia and s = side:
    D  = sqrt(y^2 + z^2 - L1^2)            depth of the foot below the femur axis, in the leg plane
    q1 = atan2(D y + s L1 z, s L1 y - D z) = atan2(y, -z) - atan2(s L1, D), wrapped to (-pi, pi]
    c3 = (x^2 + D^2 - L2^2 - L3^2) / (2 L2 L3) = cos q3,   q3 = -atan2(sqrt(1 - c3^2), c3)
    q2 = atan2(D ks - x kc, D kc + x ks) = atan2(ks, kc) - atan2(x, D),  kc = L2 + L3 c3, ks = L3 sin|q3|
         (the femur-tibia triangle's angle at the femur joint, seed 003's acos(A), minus the direction
         of the femur-foot line measured from straight down toward +x).
One atan2 each: every quadrant of the target (ahead/behind, above/below, either side; seed 002's four
cases) comes out without case analysis. q1 and q2 lie in (-pi, pi], q3 in (-pi, 0).

Mapping to the seeds:
  * seed 003 (theta1, theta2, theta3) = (q1, -q2, -q3): its theta2 is the femur angle from straight
    down, positive forward; theta3 the knee bend. Caramel's joint commands (its code, robots.md):
    roll = theta1, pitch = -(theta2 + pi/4) = q2 - pi/4, knee = -(theta3 - pi/2) = q3 + pi/2.
    The published Caramel IK vectors are these commands (see `caramel_commands`).
    Seed 003 prints eq. 6-10 in a frame with x down and z forward (a = sqrt(x^2 + y^2 - L1^2),
    atan2(a, z)); eq. 5 is garbled there (arctan(x / y): inverted ratio, and no side sign on L1). The
    robot's code (x forward, y left, z up, as here; the frame of the published vectors) reads theta1 = atan2(y, -z) - atan2(s L1, a), a = sqrt(y^2 + z^2
    - L1^2), theta2 = pi/2 - atan2(a, x) - acos(A), theta3 = atan2(sqrt(1 - B^2), B). Eq. 7's
    single-argument arctan would put theta3 in the wrong quadrant for B < 0 (knee bent past 90 deg).
  * seed 001 (Weefee): its theta3 = 180 deg - beta is the knee bend, -q3. Its coxa yaws about the
    vertical axis, unlike this roll axis; only its lengths are used here (coxa as hip offset). Its
    FK measures the femur below the horizontal, its IK (90 deg - (gamma + alpha)) from straight up,
    so its FK does not invert its IK (robots.md); tests use this module's FK.
  * seed 002: its theta1 (in [0, 2 pi), four cases) is q1 mod 2 pi for left legs, reading its printed
    ratio y/z as z/y; its theta3 = pi - R3 is the knee bend, -q3.

Non-finite targets (NaN, inf) never give NaN inside jit either: they are solved as the home target
(foot at (0, s L1, -max(L2, L3)), knee bent) with `valid` False and a zero gradient; finite targets
are clipped to +-CLIP_REACH leg lengths per coordinate first (out of reach either way), so that
1e30 m does not square to inf. Unreachable targets never give NaN inside jit: D^2 is floored at (eps (L2 + L3))^2 through a `where`
(foot put on the hip-offset cylinder) and c3 is clipped to [-1 + eps, 1 - eps] (leg straight or
folded toward the target), with `valid` False; eps is the dtype's. The clip also costs a reachable
straight-leg target about sqrt(2 eps) rad of knee angle (5e-4 rad in float32) for a foot error of
~eps L; only a leg with L2 = L3 folded flat keeps a foot error of L sqrt(2 eps) (59 um for Caramel
in float32). Gradients stay finite on every boundary (they are the clamped map's: zero across a clip).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

MM = 1e-3  # Weefee publishes millimetres; converted once here


class SerialLeg(NamedTuple):
    """Lengths of a serial roll-pitch-pitch leg [m]; a pytree, so it can be batched or randomized."""

    hip_offset: float  # L1: roll axis to the leg plane, along the pitch axis
    femur: float  # L2: femur joint to knee
    tibia: float  # L3: knee to foot


# Caramel (seed 003; robots.md): L1 = 0.048 m, L2 = L3 = 0.120 m.
CARAMEL = SerialLeg(hip_offset=0.048, femur=0.120, tibia=0.120)
# Weefee (seed 001; robots.md): coxa/femur/tibia 30/50/60 mm and 30/70/90 mm in its code.
WEEFEE_SMALL = SerialLeg(hip_offset=30 * MM, femur=50 * MM, tibia=60 * MM)
WEEFEE_LARGE = SerialLeg(hip_offset=30 * MM, femur=70 * MM, tibia=90 * MM)

CLIP_REACH = 100.0  # targets are clipped to +-100 (L1 + L2 + L3) per coordinate before solving

LEFT = 1.0
RIGHT = -1.0
JOINTS: tuple[str, ...] = ("hip_roll", "hip_pitch", "knee")

# Caramel's joint commands are the angles q shifted: command = q + CARAMEL_COMMAND_OFFSET (its code:
# pitch = -(theta2 + pi/4), knee = -(theta3 - pi/2), with theta2 = -q2, theta3 = -q3).
CARAMEL_COMMAND_OFFSET = np.array([0.0, -math.pi / 4, math.pi / 2])
# Caramel's joint limits in command space (robots.md): roll +-pi/4, pitch +-pi/3, knee +-pi/5 ...
CARAMEL_COMMAND_LIMITS = np.array(
    [[-math.pi / 4, math.pi / 4], [-math.pi / 3, math.pi / 3], [-math.pi / 5, math.pi / 5]]
)
# ... and in this module's angles, rows (lo, hi) for q1, q2, q3: q2 in [-pi/12, 7 pi/12],
# q3 in [-7 pi/10, -3 pi/10].
CARAMEL_LIMITS = CARAMEL_COMMAND_LIMITS - CARAMEL_COMMAND_OFFSET[:, None]

# Seed 002's T_0^1 = Ry(+pi/2): DH z0 along hip +x (the roll axis), DH x0 along hip -z.
_T_BASE = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def caramel_commands(angles: jax.Array) -> jax.Array:
    """(..., 3) angles q [rad] -> (..., 3) Caramel joint commands (roll, pitch, knee) [rad]."""
    return angles + jnp.asarray(CARAMEL_COMMAND_OFFSET, jnp.result_type(angles, float))


def caramel_angles(commands: jax.Array) -> jax.Array:
    """(..., 3) Caramel joint commands [rad] -> (..., 3) angles q [rad]; inverse of caramel_commands."""
    return commands - jnp.asarray(CARAMEL_COMMAND_OFFSET, jnp.result_type(commands, float))


def dh_transform(theta, d, a, alpha) -> jax.Array:
    """Standard DH link transform Rz(theta) Tz(d) Tx(a) Rx(alpha) -> (..., 4, 4); inputs broadcast."""
    theta, d, a, alpha = jnp.broadcast_arrays(*(jnp.asarray(v) for v in (theta, d, a, alpha)))
    ct, st, ca, sa = jnp.cos(theta), jnp.sin(theta), jnp.cos(alpha), jnp.sin(alpha)
    zero, one = jnp.zeros_like(ct), jnp.ones_like(ct)
    rows = (
        (ct, -st * ca, st * sa, a * ct),
        (st, ct * ca, -ct * sa, a * st),
        (zero, sa, ca, d),
        (zero, zero, zero, one),
    )
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def _lengths(leg: SerialLeg, side, dtype):
    l1, l2, l3 = (jnp.asarray(v, dtype) for v in leg)
    return l1, l2, l3, jnp.asarray(side, dtype)


def serial_fk_chain(angles: jax.Array, leg: SerialLeg, side=LEFT) -> jax.Array:
    """Joint origins and foot by the DH chain of the module docstring.

    angles: (..., 3) q [rad]; leg: lengths [m]; side: +1 left / -1 right (broadcasts with the batch)
    -> (..., 4, 3) points in the hip frame [m]: roll-axis origin, femur joint, knee, foot.
    """
    angles = jnp.asarray(angles)
    dtype = jnp.result_type(angles, float)
    angles = angles.astype(dtype)
    l1, l2, l3, s = _lengths(leg, side, dtype)
    d2 = s * l1
    t1 = jnp.asarray(_T_BASE, dtype) @ dh_transform(angles[..., 0], 0.0, 0.0, -math.pi / 2)
    t2 = t1 @ dh_transform(angles[..., 1], d2, l2, 0.0)
    t3 = t2 @ dh_transform(angles[..., 2], 0.0, l3, 0.0)
    femur_joint = t1[..., :3, 3] + d2[..., None] * t1[..., :3, 2]  # d of row 2, along z1
    return jnp.stack([t1[..., :3, 3], femur_joint, t2[..., :3, 3], t3[..., :3, 3]], axis=-2)


def serial_fk(angles: jax.Array, leg: SerialLeg, side=LEFT) -> jax.Array:
    """(..., 3) q [rad] -> (..., 3) foot in the hip frame [m] (DH chain, seed 002)."""
    return serial_fk_chain(angles, leg, side)[..., -1, :]


def _safe_atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """atan2 with a finite gradient at (0, 0) (where it returns 0)."""
    bad = (x == 0) & (y == 0)
    return jnp.arctan2(jnp.where(bad, 0.0, y), jnp.where(bad, 1.0, x))


def _ik(target: jax.Array, leg: SerialLeg, side, limits=None):
    """Angles and the individual reach checks; see serial_ik."""
    target = jnp.asarray(target)
    dtype = jnp.result_type(target, float)
    target = target.astype(dtype)
    l1, l2, l3, s = _lengths(leg, side, dtype)
    # A NaN or infinite target is solved as the home target (foot below the femur joint at depth
    # max(L2, L3), well inside the reach) and flagged; finite targets are clipped to +-CLIP_REACH
    # leg lengths, out of reach either way, so that their squares cannot overflow to inf.
    finite = jnp.all(jnp.isfinite(target), axis=-1)
    home = jnp.stack(jnp.broadcast_arrays(jnp.zeros_like(s), s * l1, -jnp.maximum(l2, l3)), axis=-1)
    clip = CLIP_REACH * (l1 + l2 + l3)
    target = jnp.clip(jnp.where(finite[..., None], target, home), -clip[..., None], clip[..., None])
    x, y, z = target[..., 0], target[..., 1], target[..., 2]
    eps = jnp.finfo(dtype).eps
    tol = 64 * eps  # rounding slack of the checks, relative

    depth_sq = y * y + z * z - l1 * l1
    floor = jnp.square(eps * (l2 + l3))
    # where, not maximum: sqrt' is infinite at 0, and 0 * inf would leak NaN into the gradient.
    depth = jnp.sqrt(jnp.where(depth_sq > floor, depth_sq, floor))
    q1 = _safe_atan2(depth * y + s * l1 * z, s * l1 * y - depth * z)

    cos_knee = (x * x + depth * depth - l2 * l2 - l3 * l3) / (2 * l2 * l3)
    c3 = jnp.clip(cos_knee, -1 + eps, 1 - eps)
    s3 = jnp.sqrt((1 - c3) * (1 + c3))  # > 0 after the clip: finite gradient at full stretch
    q3 = -jnp.arctan2(s3, c3)
    # Femur: angle of the femur-foot line from straight down, atan2(x, D), minus the hip angle of the
    # femur-tibia triangle, atan2(L3 s3, L2 + L3 c3) (seed 003 eq. 6 written without acos), negated.
    kc, ks = l2 + l3 * c3, l3 * s3
    q2 = jnp.arctan2(depth * ks - x * kc, depth * kc + x * ks)  # (depth, x) != 0: depth >= floor > 0
    angles = jnp.stack([q1, q2, q3], axis=-1)

    checks = {
        "finite": finite,
        "outside_cylinder": depth_sq >= -tol * (y * y + z * z),
        "within_reach": cos_knee <= 1 + tol,
        "not_too_close": cos_knee >= -1 - tol,
    }
    if limits is not None:
        limits = jnp.asarray(limits, dtype)
        checks["within_limits"] = (angles >= limits[:, 0]) & (angles <= limits[:, 1])  # (..., 3)
    return angles, checks


def serial_ik(target: jax.Array, leg: SerialLeg, side=LEFT, limits=None) -> tuple[jax.Array, jax.Array]:
    """Closed-form IK, knee backward (seed 003 eq. 5-10, single law-of-cosines branch).

    target: (..., 3) foot in the hip frame [m]; leg: lengths [m]; side: +1 left / -1 right;
    limits: optional (3, 2) rows (lo, hi) [rad] for q1, q2, q3 in this module's convention
    (e.g. CARAMEL_LIMITS), compared with angles in (-pi, pi].
    -> angles (..., 3) [rad], valid (...,) bool: False when the target is not finite (NaN or inf),
    inside the hip-offset cylinder (y^2 + z^2 < L1^2), beyond L2 + L3 or within |L2 - L3| of the
    femur joint, or when an angle is beyond `limits`. Invalid targets get clamped, finite angles (a
    non-finite target the home angles: foot at (0, side L1, -max(L2, L3))); jit- and grad-safe,
    with finite gradients (zero for a non-finite target).
    """
    angles, checks = _ik(target, leg, side, limits)
    valid = checks["finite"] & checks["outside_cylinder"] & checks["within_reach"] & checks["not_too_close"]
    if limits is not None:
        valid = valid & jnp.all(checks["within_limits"], axis=-1)
    return angles, valid


def serial_ik_checked(target, leg: SerialLeg, side=LEFT, limits=None) -> np.ndarray:
    """Eager IK that raises on bad targets: (..., 3) [m] -> numpy (..., 3) [rad] (jax default float).

    Raises ValueError naming the first failing target (in m) and the reason. Not for use in jit.
    """
    target = np.asarray(target, dtype=float)
    if target.shape[-1:] != (3,):
        raise ValueError(f"target must have shape (..., 3), got {target.shape}")
    angles, checks = jax.device_get(_ik(target, leg, side, limits))
    batch = angles.shape[:-1]
    flat_target = np.broadcast_to(target, batch + (3,)).reshape(-1, 3)
    flat_angles = angles.reshape(-1, 3)
    ok = {k: np.broadcast_to(v, batch).reshape(-1) for k, v in checks.items() if k != "within_limits"}
    if limits is not None:
        ok_limits = np.broadcast_to(checks["within_limits"], batch + (3,)).reshape(-1, 3)
    l1, l2, l3 = (float(v) for v in leg)
    for i, (x, y, z) in enumerate(flat_target):
        reason = None
        with np.errstate(all="ignore"):  # only formatted where the target is finite
            r = math.hypot(y, z)
            reach = math.sqrt(max(y * y + z * z - l1 * l1, 0.0) + x * x)
        if not ok["finite"][i]:
            reason = "not a finite number (NaN or infinite coordinate)"
        elif not ok["outside_cylinder"][i]:
            reason = f"inside the hip-offset cylinder: sqrt(y^2 + z^2) = {r:.6g} m < hip_offset = {l1:.6g} m"
        elif not ok["within_reach"][i]:
            reason = f"out of reach: femur joint to foot {reach:.6g} m > femur + tibia = {l2 + l3:.6g} m"
        elif not ok["not_too_close"][i]:
            reason = f"too close: femur joint to foot {reach:.6g} m < |femur - tibia| = {abs(l2 - l3):.6g} m"
        elif limits is not None and not ok_limits[i].all():
            j = int(np.argmin(ok_limits[i]))
            lo, hi = np.asarray(limits, dtype=float)[j]
            reason = (
                f"beyond joint limits: {JOINTS[j]} = {flat_angles[i, j]:.6g} rad not in [{lo:.6g}, {hi:.6g}]"
            )
        if reason is not None:
            raise ValueError(f"serial IK: target ({x:.6g}, {y:.6g}, {z:.6g}) m is unreachable: {reason}")
    return np.asarray(angles)
