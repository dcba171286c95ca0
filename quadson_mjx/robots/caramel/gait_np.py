"""Numpy versions of what the environment does between an action and Caramel's joint targets: the
steady-state discontinuous trot (gait.foot_targets), the leg phases (quadson_mjx.gait.leg_phases) and
the serial-leg IK with its clip (quadson_mjx.serial.serial_ik, gait.joint_targets). For the robot's
computer: numpy only, no jax (tests/test_deploy_caramel.py checks them against the JAX code the
simulator runs, in float64).

Caramel's numbers come as a `Geometry`: `geometry()` reads them from constants.py (which imports the
JAX kinematics, so only where jax is installed); the export writes `geometry()._asdict()` into the
policy file's metadata and the robot's loop rebuilds it with `Geometry.from_dict`.

Frames and shapes as in gait.py: feet (..., 4, 3) in the body frame [m] (x forward, y left, z up,
origin at the hips' centre), joint angles (..., 4, 3) serial.py's q [rad], leg order LEGS. float64.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

PHASES_PER_CYCLE = 4  # swing A, shift, swing B, shift (gait.PHASES_PER_CYCLE)


class Geometry(NamedTuple):
    """Caramel's numbers the numpy gait and IK need (constants.py)."""

    legs: tuple  # ("FL", "FR", "RL", "RR")
    joints: tuple  # ("hip_roll", "hip_pitch", "knee"): q1, q2, q3
    hip_pos: np.ndarray  # (4, 3) hips in the body frame [m]
    side: np.ndarray  # (4,) +1 left, -1 right
    leg: tuple  # (hip_offset, femur, tibia) [m]
    joint_limits: np.ndarray  # (3, 2) rows (lo, hi) of q1, q2, q3 [rad]
    stance_height_m: float
    tick_s: float  # seed 003's 20 ms planner tick
    pair_b: np.ndarray  # (4,) bool: the legs of the second trot pair
    servo_speed_rps: float  # the servo's speed [rad/s]

    def to_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self._asdict().items()}

    @classmethod
    def from_dict(cls, d: dict) -> Geometry:
        return cls(
            legs=tuple(d["legs"]),
            joints=tuple(d["joints"]),
            hip_pos=np.asarray(d["hip_pos"], np.float64).reshape(4, 3),
            side=np.asarray(d["side"], np.float64).reshape(4),
            leg=tuple(float(v) for v in d["leg"]),
            joint_limits=np.asarray(d["joint_limits"], np.float64).reshape(3, 2),
            stance_height_m=float(d["stance_height_m"]),
            tick_s=float(d["tick_s"]),
            pair_b=np.asarray(d["pair_b"], bool).reshape(4),
            servo_speed_rps=float(d["servo_speed_rps"]),
        )


def geometry() -> Geometry:
    """Caramel's Geometry from constants.py (imports jax through quadson_mjx.serial)."""
    from quadson_mjx.robots.caramel import constants as C

    return Geometry(
        legs=tuple(C.LEGS),
        joints=tuple(C.JOINTS),
        hip_pos=np.asarray(C.HIP_POS, np.float64),
        side=np.asarray(C.SIDE, np.float64),
        leg=tuple(float(v) for v in C.LEG),
        joint_limits=np.asarray(C.JOINT_LIMITS, np.float64),
        stance_height_m=float(C.STANCE_HEIGHT),
        tick_s=float(C.TICK_S),
        pair_b=np.array([leg in C.TROT_PAIRS[1] for leg in C.LEGS]),
        servo_speed_rps=float(C.VELOCITY_LIMIT),
    )


class Gait(NamedTuple):
    """The trot as gait.GaitParams holds it, numpy values (gait.TROT with the env's gait_scale)."""

    phase_offset: np.ndarray  # (4,)
    cycle_s: float
    duty: float
    step_height_m: float
    step_length_m: float
    p_t: float
    p_n: float


def gait_params(params: dict) -> Gait:
    """A Gait from a GaitParams-like mapping (the fields of gait.gait_params(...)._asdict())."""
    return Gait(
        phase_offset=np.asarray(params["phase_offset"], np.float64),
        **{k: float(params[k]) for k in ("cycle_s", "duty", "step_height_m", "step_length_m", "p_t", "p_n")},
    )


def seed_speed(g: Gait) -> float:
    """quadson_mjx.gait.seed_speed of the discontinuous trot: step length per cycle [m/s]."""
    return g.step_length_m / g.cycle_s


def leg_phases(t, g: Gait) -> np.ndarray:
    """quadson_mjx.gait.leg_phases: t (...) [s] -> (..., 4) phase of each leg in [0, 1)."""
    x = np.asarray(t, np.float64)[..., None] / g.cycle_s + g.phase_offset
    phase = x - np.floor(x)
    return np.where(phase >= 1.0, 0.0, phase)


def nominal_feet(geo: Geometry) -> np.ndarray:
    """(4, 3) gait.nominal_feet: (hip x, hip y + side L1, -stance height) [m]."""
    off = np.stack([np.zeros(4), geo.side * geo.leg[0], np.full(4, -geo.stance_height_m)], axis=-1)
    return geo.hip_pos + off


def cycloid_tick_times(period_s: float, p_t: float, p_n: float, tick_s: float) -> np.ndarray:
    """swing.cycloid_tick_times: trajectory time [s] of each of the N = period / tick points."""
    n = round(period_s / tick_s)
    if n < 2 or abs(n * tick_s - period_s) > 1e-9:
        raise ValueError(f"period {period_s} s is not a multiple (>= 2) of the tick {tick_s} s")
    n1 = int(n * p_n + 1e-9)
    t_break = p_t * period_s
    first = np.linspace(0.0, t_break, n1) if n1 > 0 else np.zeros(0)
    n2 = n - n1
    rest = t_break + (period_s - t_break) * np.arange(1, n2 + 1) / max(n2, 1)
    return np.concatenate([first, rest])


def _rot_z_apply(theta, f) -> np.ndarray:
    """Rz(theta) (...) applied to each foot of f (..., 4, 3)."""
    c, s = np.cos(theta)[..., None], np.sin(theta)[..., None]
    x, y = f[..., 0], f[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, np.broadcast_to(f[..., 2], np.shape(c * x))], axis=-1)


def foot_targets(t, command, g: Gait, geo: Geometry) -> np.ndarray:
    """gait.foot_targets: the steady-state trot at gait time t (...) [s] (rounded to the tick) for
    command (..., 3) (vx, vy [m/s], yaw rate [rad/s]) -> (..., 4, 3) feet in the body frame [m]."""
    period_s = g.cycle_s / PHASES_PER_CYCLE
    tick_times = cycloid_tick_times(period_s, g.p_t, g.p_n, geo.tick_s)
    n = len(tick_times)
    u_table = tick_times / period_s
    along_table = u_table - np.sin(2.0 * np.pi * u_table) / (2.0 * np.pi)
    t = np.asarray(t, np.float64)
    command = np.asarray(command, np.float64)
    tick = np.mod(np.round(t / geo.tick_s).astype(np.int64), PHASES_PER_CYCLE * n)
    phase, i = tick // n, tick % n
    u = u_table[i][..., None, None]  # (..., 1, 1)
    s = along_table[i][..., None, None]
    shift_s = 2.0 * period_s
    zero = np.zeros_like(command[..., 0])
    trans = (np.stack([command[..., 0], command[..., 1], zero], -1) * shift_s)[..., None, :]  # (..., 1, 3)
    theta = command[..., 2] * shift_s
    p = nominal_feet(geo)
    land = _rot_z_apply(theta, np.broadcast_to(p, theta.shape + (4, 3))) + trans
    lift = _rot_z_apply(-theta, p - trans)
    k = 2.0 * np.pi * u
    up = np.array([0.0, 0.0, 1.0])
    swinging = (
        lift
        + (land - lift) * ((k - np.sin(k)) / (2.0 * np.pi))
        + g.step_height_m * 0.5 * (1.0 - np.cos(k)) * up
    )
    ang = -s[..., 0, 0] * theta
    after_landing = _rot_z_apply(ang, land - s * trans)
    before_lift = _rot_z_apply(ang, p - s * trans)
    after_landing[..., 2] = p[:, 2]
    before_lift[..., 2] = p[:, 2]
    local = np.where(geo.pair_b, (phase[..., None] + 2) % PHASES_PER_CYCLE, phase[..., None])[..., None]
    rest = np.broadcast_to(p, land.shape)
    return np.where(
        local == 0, swinging, np.where(local == 1, after_landing, np.where(local == 2, rest, before_lift))
    )


def serial_ik(target, geo: Geometry, side) -> tuple[np.ndarray, np.ndarray]:
    """serial.serial_ik with Caramel's limits in float64: target (..., 3) in the hip frame [m],
    side (...) -> (angles (..., 3) [rad], valid (...) bool)."""
    target = np.asarray(target, np.float64)
    x, y, z = target[..., 0], target[..., 1], target[..., 2]
    l1, l2, l3 = geo.leg
    s = np.asarray(side, np.float64)
    eps = np.finfo(np.float64).eps
    tol = 64 * eps
    depth_sq = y * y + z * z - l1 * l1
    floor = (eps * (l2 + l3)) ** 2
    depth = np.sqrt(np.where(depth_sq > floor, depth_sq, floor))
    a, b = depth * y + s * l1 * z, s * l1 * y - depth * z
    bad = (a == 0) & (b == 0)
    q1 = np.arctan2(np.where(bad, 0.0, a), np.where(bad, 1.0, b))
    cos_knee = (x * x + depth * depth - l2 * l2 - l3 * l3) / (2 * l2 * l3)
    c3 = np.minimum(np.maximum(cos_knee, -1 + eps), 1 - eps)
    s3 = np.sqrt((1 - c3) * (1 + c3))
    q3 = -np.arctan2(s3, c3)
    kc, ks = l2 + l3 * c3, l3 * s3
    q2 = np.arctan2(depth * ks - x * kc, depth * kc + x * ks)
    angles = np.stack([q1, q2, q3], axis=-1)
    lim = geo.joint_limits
    valid = (
        (depth_sq >= -tol * (y * y + z * z))
        & (cos_knee <= 1 + tol)
        & (cos_knee >= -1 - tol)
        & np.all((angles >= lim[:, 0]) & (angles <= lim[:, 1]), axis=-1)
    )
    return angles, valid


def motor_targets(feet, geo: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """gait.joint_targets: feet (..., 4, 3) body frame [m] -> (angles clipped into the joint limits
    (..., 4, 3) [rad], valid (..., 4) bool)."""
    q, valid = serial_ik(np.asarray(feet, np.float64) - geo.hip_pos, geo, geo.side)
    lim = geo.joint_limits
    return np.minimum(np.maximum(np.nan_to_num(q), lim[:, 0]), lim[:, 1]), valid
