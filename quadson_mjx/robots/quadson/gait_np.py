"""Numpy versions of what the environment does between an action and the motor targets: the gait's
foot targets (gait.py, swing.py), the env's start ramp (env.LocomotionEnv.gait_targets) and the
five-bar IK with its clamp (fivebar.leg_ik, gait.motor_targets). For the robot's computer: numpy and
quadson_mjx.robots.quadson.constants only, no jax (tests/test_deploy.py checks them against the JAX code the
simulator runs).

Same frames, units and shapes as the JAX modules: feet (..., 4, 3) in the shoulder frames [m], LEGS
order; motor angles (..., 4, 3) (t0, t1, t5) [rad]. Computed in float64.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from quadson_mjx.robots.quadson import constants as C

SWING_SHAPES: tuple[str, ...] = ("bezier_seed", "bezier_apex", "cycloid")  # = swing.SWING_SHAPES
APEX_SCALE = math.sqrt(3.0)  # swing.APEX_SCALE
_UP = np.array([0.0, 1.0, 0.0])
_TINY = np.finfo(np.float64).tiny


def _clip(x, lo, hi):
    """np.clip without its overhead (several times slower on the robot's (4,)-sized arrays)."""
    return np.minimum(np.maximum(x, lo), hi)


class Gait(NamedTuple):
    """A gait, as gait.GaitParams, with numpy values."""

    phase_offset: np.ndarray  # (4,) fraction of a cycle, LEGS order
    cycle_s: float
    duty: float
    step_height_m: float
    step_length_m: float
    swing: int = 0  # index into SWING_SHAPES
    p_t: float = 1.0
    p_n: float = 1.0
    discontinuous: bool = False


def gait_params(name: str, swing: str | int | None = None, scale=None) -> Gait:
    """The gait `name` of constants.GAITS or "trot_discontinuous", optionally with another swing shape
    and the env config's gait_scale (a mapping of cycle_s, step_length_m, step_height_m factors)."""
    if name == "trot_discontinuous":
        base = dict(C.DISCONTINUOUS_TROT)
    elif name in C.GAITS:
        base = dict(C.GAITS[name])
    else:
        raise ValueError(f"unknown gait {name!r}; choose from {(*C.GAITS, 'trot_discontinuous')}")
    if swing is not None:
        base["swing"] = swing
    shape = base.get("swing", 0)
    if isinstance(shape, str):
        if shape not in SWING_SHAPES:
            raise ValueError(f"unknown swing shape {shape!r}; choose from {SWING_SHAPES}")
        shape = SWING_SHAPES.index(shape)
    base["swing"] = int(shape)
    base["phase_offset"] = np.asarray(base["phase_offset"], np.float64)
    for key, factor in (scale or {}).items():
        if key not in ("cycle_s", "step_length_m", "step_height_m"):
            raise ValueError(f"unknown gait_scale key {key!r}")
        base[key] = base[key] * float(factor)
    return Gait(**base)


def seed_speed(g: Gait) -> float:
    """gait.seed_speed: the forward command [m/s] that reproduces the seed's fixed step."""
    return g.step_length_m / _stance_time(g)


def _stance_time(g: Gait) -> float:
    return (1.0 if g.discontinuous else g.duty) * g.cycle_s


def leg_phases(t, g: Gait) -> np.ndarray:
    """Seed 000 Algorithm 5. t: (...) [s] -> (..., 4) phase of each leg in [0, 1)."""
    x = np.asarray(t, np.float64)[..., None] / g.cycle_s + g.phase_offset
    phase = x - np.floor(x)
    return np.where(phase >= 1.0, 0.0, phase)


def neutral_feet(g: Gait) -> np.ndarray:
    """(4, 3) mid-stance foot of each leg, shoulder frames [m]."""
    x = C.STANCE_START_X + C.STANCE_DIRECTION * (0.5 * g.step_length_m)
    return np.stack([x, np.full(4, -C.STANCE_HEIGHT), np.zeros(4)], axis=-1)


def step_vectors(command, g: Gait, neutral=None) -> np.ndarray:
    """command (..., 3) (vx, vy [m/s], yaw rate [rad/s]) -> (..., 4, 3) stance displacement [m].
    neutral: neutral_feet(g) if already computed."""
    command = np.asarray(command, np.float64)
    neutral = neutral_feet(g) if neutral is None else neutral
    r = C.SHOULDER_POS + (C.SHOULDER_ROT @ neutral[:, :, None])[:, :, 0]  # body frame
    vx, vy, wz = command[..., 0:1], command[..., 1:2], command[..., 2:3]
    v_foot = np.stack([-(vx - wz * r[:, 1]), -(vy + wz * r[:, 0]), np.zeros_like(vx * r[:, 0])], -1)
    step_body = v_foot * _stance_time(g)  # (..., 4, 3); to the shoulder frames: R_l^T s (row s R_l)
    return (step_body[..., None, :] @ C.SHOULDER_ROT)[..., 0, :]


def stance_progress(phase, g: Gait) -> np.ndarray:
    """gait.stance_progress: fraction of the step done at `phase` (...) in stance."""
    if not g.discontinuous:
        return _clip(phase / g.duty, 0.0, 1.0)
    shift = g.duty - 0.5
    moved = np.minimum(phase, shift) + np.maximum(phase - 0.5, 0.0)
    return _clip(moved / (2.0 * shift), 0.0, 1.0)


def warp(u, p_t: float, p_n: float) -> np.ndarray:
    """swing.warp: seed 003's P_T/P_N spacing as a piecewise-linear time warp of u in [0, 1]."""
    first = u * p_t / (p_n if p_n > 0 else 1.0)
    rest = p_t + (u - p_n) * (1.0 - p_t) / (1.0 - p_n if p_n < 1 else 1.0)
    return np.where(u <= p_n, first, rest)


def swing_point(u, lift, land, height: float, shape: int) -> np.ndarray:
    """swing.swing_point for one shape: u (...), lift/land (..., 3) [m] -> (..., 3) [m]."""
    u = np.asarray(u, np.float64)[..., None]
    if shape == 2:  # cycloid, seed 003 eq. 1-4
        k = 2.0 * np.pi * u
        return lift + (land - lift) * (k - np.sin(k)) / (2.0 * np.pi) + height * 0.5 * (1.0 - np.cos(k)) * _UP
    up = height * (APEX_SCALE if shape == 1 else 1.0) * _UP  # seed Bezier, Algorithms 6-7
    p1 = 0.5 * (lift + land) + up
    p2 = land + 0.5 * up
    v = 1.0 - u
    return v**3 * lift + 3.0 * v**2 * u * p1 + 3.0 * v * u**2 * p2 + u**3 * land


def foot_targets(t, command, g: Gait) -> np.ndarray:
    """gait.foot_targets without a body offset: t (...) [s], command (..., 3) -> (..., 4, 3) [m]."""
    phase = leg_phases(t, g)
    neutral = neutral_feet(g)
    step = step_vectors(command, g, neutral)
    p_start, p_end = neutral - 0.5 * step, neutral + 0.5 * step
    stance = p_start + stance_progress(phase, g)[..., None] * step
    u = warp(_clip((phase - g.duty) / (1.0 - g.duty), 0.0, 1.0), g.p_t, g.p_n)
    swing = swing_point(u, p_end, p_start, g.step_height_m, g.swing)
    return np.where((phase < g.duty)[..., None], stance, swing)


def home_feet() -> np.ndarray:
    """(4, 3) foot targets of the `home` keyframe (model.home_foot_targets with z = 0) [m]."""
    x = C.STANCE_START_X + C.STANCE_DIRECTION * (0.5 * C.GAITS["trot"]["step_length_m"])
    return np.stack([x, np.full(4, -C.STANCE_HEIGHT), np.zeros(4)], axis=-1)


def ramped_gait_targets(progress, episode_time_s, command, g: Gait, ctrl_dt: float, ramp_s: float):
    """env.LocomotionEnv.gait_targets: the gait at `progress` (fraction of a cycle), blended from the home
    stance by a smoothstep of (episode_time_s + ctrl_dt) / ramp_s. -> (..., 4, 3) [m]."""
    targets = foot_targets(np.asarray(progress) * g.cycle_s, command, g)
    s = _clip((np.asarray(episode_time_s) + ctrl_dt) / ramp_s, 0.0, 1.0)[..., None, None]
    home = home_feet()
    return home + (s * s * (3.0 - 2.0 * s)) * (targets - home)


# --- five-bar IK (seed 000 Algorithm 2; fivebar._ik_solve) ----------------------------------------


def _sin_acos(x):
    x = _clip(x, -1.0, 1.0)
    return np.sqrt(np.maximum(1.0 - x * x, 0.0))


def leg_ik(foot) -> tuple[np.ndarray, np.ndarray]:
    """fivebar.leg_ik: foot (..., 3) [m] -> (angles (..., 3) (t0, t1, t5) [rad], valid (...) bool)."""
    foot = np.asarray(foot, np.float64)
    x, y, z = foot[..., 0], foot[..., 1], foot[..., 2]
    on_axis = (y == 0) & (z == 0)
    t0 = np.where(on_axis, 0.0, -np.arctan2(z, np.where(on_axis, 1.0, -y)))
    r = np.sqrt(np.maximum(y * y + z * z, _TINY))
    l1e = np.sqrt(np.maximum(x * x + r * r, _TINY))
    l23 = C.L2 + C.L3
    c12 = (C.L1**2 + l1e**2 - l23**2) / (2.0 * C.L1 * l1e)
    ce, se = x / l1e, r / l1e
    cb, sb = _clip(c12, -1.0, 1.0), _sin_acos(c12)
    c1, s1 = ce * cb - se * sb, se * cb + ce * sb
    t1 = np.arctan2(s1, c1)
    t1 = np.where(t1 < 0.0, t1 + 2.0 * np.pi, t1)
    p2x, p2y = C.L1 * c1, -C.L1 * s1
    p3x, p3y = (x * C.L2 + p2x * C.L3) / l23, (-r * C.L2 + p2y * C.L3) / l23
    dx, dy = p3x - C.L0, p3y
    l35 = np.sqrt(np.maximum(dx * dx + dy * dy, _TINY))
    c354 = (l35**2 + C.L5**2 - C.L4**2) / (2.0 * l35 * C.L5)
    cd, sd = dx / l35, -dy / l35
    cb, sb = _clip(c354, -1.0, 1.0), _sin_acos(c354)
    c5, s5 = cd * cb + sd * sb, sd * cb - cd * sb
    t5 = np.arctan2(s5, c5)
    angles = np.stack([t0, t1, t5], axis=-1)
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    p4x, p4y = C.L0 + C.L5 * c5, -C.L5 * s5
    cross = (p4x - p2x) * (p3y - p2y) - (p4y - p2y) * (p3x - p2x)  # p3 clockwise of p2 -> p4
    tol = 64 * np.finfo(np.float64).eps * C.L2 * (C.L2 + C.L4)
    valid = (
        (np.abs(c12) <= 1.0)
        & (np.abs(c354) <= 1.0)
        & np.all((angles >= lo) & (angles <= hi), axis=-1)
        & (t5 - t1 <= C.TOE_IN_MAX)
        & (cross <= tol)
    )
    return angles, valid


def motor_targets(feet) -> tuple[np.ndarray, np.ndarray]:
    """gait.motor_targets: feet (..., 4, 3) [m] -> (angles clipped into the motor limits and the
    toe-in guard (..., 4, 3) [rad], valid (..., 4) bool)."""
    angles, valid = leg_ik(feet)
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    angles = _clip(np.nan_to_num(angles), lo, hi)
    angles[..., 2] = _clip(np.minimum(angles[..., 2], angles[..., 1] + C.TOE_IN_MAX), lo[2], hi[2])
    return angles, valid
