"""Gait machinery: leg phases, stance and swing foot paths from a velocity command, pure JAX, SI,
batched. No robot inside: a robot's gait table, its neutral feet and its leg frames come as
arguments (Quadson: quadson_mjx.robots.quadson.gait; Caramel: quadson_mjx.robots.caramel.gait).

Seed 000 Algorithms 5-7 (phases, linear stance, Bezier swing), generalised from a fixed step to a
body velocity command (vx, vy, yaw_rate), plus seed 003's cycloid swing with its P_T/P_N timing and
its discontinuous trot. Feet are (..., 4, 3) in the robot's leg ("gait") frames, whose "up" axis is
the swing curves' +y (swing.py).

A gait is a `GaitParams` pytree; every field may be a traced array (the swing shape and the
discontinuous flag are selected with `where`), so a policy may scale step length or cycle time
per environment.

Per leg: phase = (t / cycle_s + phase_offset) mod 1 (Algorithm 5, as the robot's code). Stance
while phase < duty: the foot moves on a straight line at ground height from p_start to p_end =
p_start + step, at constant velocity step / (duty cycle_s). Swing otherwise: from p_end back to
p_start over (1 - duty) cycle_s, on the curve of `swing` (see swing.py for shapes, apexes and
lift-off/touchdown velocities). Positions are continuous at lift-off, touchdown and phase
wrap-around; velocities are not: the stance foot moves at step / (duty T) while the cycloid starts
and ends at rest and the Bezier starts with d/du = 1.5 (p_start - p_end) + 3 h up (all shapes: see
swing.py). A command that changes mid-step moves the foot with it.

Step from a command: a stance foot moves relative to the body by -(v + w x r) * stance_time, with
r the foot's body-frame position at mid-stance (the "neutral" point) and stance_time =
duty * cycle_s; it is expressed in each leg frame with the frame's rotation (Quadson: body lateral
motion lands on the shoulder-frame z, which the leg reaches through motor 0).

Discontinuous trot (seed 003): the body moves only while all four feet are down. With two leg
pairs half a cycle apart and duty > 1/2 the cycle reads: body shift, FR+RL swing, body shift,
FL+RR swing (each shift (duty - 1/2) cycle_s, each swing (1 - duty) cycle_s). A stance foot then
moves only while the other pair is down too; the command is the mean body velocity, so the step
is -(v + w x r) * cycle_s and the body moves at 1 / (2 duty - 1) times the command while it moves.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import swing as S


class GaitParams(NamedTuple):
    """A gait as a pytree. Leaves are scalars except phase_offset (4,), LEGS order."""

    phase_offset: jax.Array  # (4,) fraction of a cycle added to each leg's phase
    cycle_s: float  # s, one gait cycle
    duty: float  # fraction of the cycle in stance
    step_height_m: float  # commanded swing height above the stance line [m]
    step_length_m: float  # seed step length [m]: sets the neutral point and seed_speed
    swing: int = 0  # index into swing.SWING_SHAPES
    p_t: float = 1.0  # seed 003 warp: fraction of the swing trajectory ...
    p_n: float = 1.0  # ... covered in this fraction of the swing time (1, 1: no warp)
    discontinuous: bool = False  # seed 003's discontinuous gait (body moves with all feet down)


def params_from(base: dict, **overrides) -> GaitParams:
    """A GaitParams from a gait table entry `base` (GaitParams fields; swing may be a name) with
    field overrides. Raises ValueError on an unknown field or inconsistent values."""
    base = dict(base)
    unknown = set(overrides) - set(GaitParams._fields)
    if unknown:
        raise ValueError(f"unknown gait field(s) {sorted(unknown)}; fields are {GaitParams._fields}")
    base.update(overrides)
    base["swing"] = S.swing_shape_index(base.get("swing", 0))
    offsets = np.asarray(base["phase_offset"], dtype=np.float32)
    base["phase_offset"] = offsets
    base = {k: v if k in ("phase_offset", "swing", "discontinuous") else float(v) for k, v in base.items()}
    base["discontinuous"] = bool(base.get("discontinuous", False))
    p = GaitParams(**base)
    _check(p)
    return p


def _check(p: GaitParams) -> None:
    if p.phase_offset.shape != (4,) or np.any((p.phase_offset < 0) | (p.phase_offset >= 1)):
        raise ValueError(f"phase_offset must be 4 values in [0, 1), got {p.phase_offset}")
    if not p.cycle_s > 0 or not 0 < p.duty < 1:
        raise ValueError(f"need cycle_s > 0 and 0 < duty < 1, got {p.cycle_s}, {p.duty}")
    if p.step_height_m < 0 or p.step_length_m < 0:
        raise ValueError("step height and length must be >= 0")
    if not (0 < p.p_t <= 1 and 0 < p.p_n <= 1) or ((p.p_t == 1 or p.p_n == 1) and p.p_t != p.p_n):
        raise ValueError(f"warp needs 0 < p_t, p_n < 1, or p_t == p_n; got {p.p_t}, {p.p_n}")
    if p.discontinuous:
        d = np.mod(p.phase_offset - p.phase_offset[0], 1.0)
        pairs = np.all(np.isclose(d, 0.0) | np.isclose(d, 0.5)) and np.sum(np.isclose(d, 0.5)) == 2
        if not pairs or p.duty <= 0.5:
            raise ValueError("the discontinuous gait needs two leg pairs half a cycle apart and duty > 0.5")


def seed_speed(params: GaitParams):
    """Forward speed [m/s] at which the command path reproduces the seed's fixed step:
    step_length / (duty cycle_s), or step_length / cycle_s for the discontinuous gait."""
    return params.step_length_m / _stance_time(params)


def _stance_time(params: GaitParams):
    """Time [s] over which a stance foot's step relates to the mean body velocity."""
    return jnp.where(params.discontinuous, 1.0, params.duty) * params.cycle_s


def leg_phases(t: jax.Array, params: GaitParams) -> jax.Array:
    """Seed 000 Algorithm 5. t: (...) time [s] -> (..., 4) phase of each leg in [0, 1)."""
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    x = t[..., None] / params.cycle_s + jnp.asarray(params.phase_offset, t.dtype)
    phase = x - jnp.floor(x)
    return jnp.where(phase >= 1.0, 0.0, phase)  # x - floor(x) rounds up to 1 for tiny negative x


def step_vectors(command: jax.Array, params: GaitParams, neutral, frame_pos, frame_rot) -> jax.Array:
    """Stance displacement of each foot relative to the body over one stance.

    command: (..., 3) body velocity (vx [m/s], vy [m/s], yaw_rate [rad/s]), body frame; neutral (4, 3)
    mid-stance feet in the leg frames [m]; frame_pos (4, 3), frame_rot (4, 3, 3) the leg frames in the
    body (quadson_mjx.pose) -> (..., 4, 3) p_end - p_start in each leg frame [m]:
    -(v + w x r_neutral) * stance_time.
    """
    command = jnp.asarray(command, dtype=jnp.result_type(float))
    rot = jnp.asarray(frame_rot, command.dtype)  # (4, 3, 3) leg frame -> body
    r = jnp.asarray(frame_pos, command.dtype) + jnp.einsum(
        "lij,lj->li", rot, jnp.asarray(neutral, command.dtype)
    )
    vx, vy, wz = command[..., 0:1], command[..., 1:2], command[..., 2:3]  # (..., 1)
    v_foot = jnp.stack([-(vx - wz * r[:, 1]), -(vy + wz * r[:, 0]), jnp.zeros_like(vx * r[:, 0])], -1)
    step_body = v_foot * _stance_time(params)  # (..., 4, 3) body frame
    return jnp.einsum("lji,...lj->...li", rot, step_body)


def stance_progress(phase: jax.Array, params: GaitParams) -> jax.Array:
    """Fraction of the step done at `phase` (...) in stance -> (...) in [0, 1].

    Continuous gaits: phase / duty. Discontinuous: the foot moves only while the other pair is
    down, i.e. outside local phases [duty - 1/2, 1/2) where the other pair swings.
    """
    d = params.duty
    cont = phase / d
    shift = d - 0.5
    moved = jnp.minimum(phase, shift) + jnp.maximum(phase - 0.5, 0.0)
    disc = moved / jnp.where(params.discontinuous, 2.0 * shift, 1.0)
    return jnp.clip(jnp.where(params.discontinuous, disc, cont), 0.0, 1.0)


def feet_on_path(t: jax.Array, params: GaitParams, neutral, step) -> jax.Array:
    """Foot targets of the gait (seed 000 Algorithm 6, generalised to a velocity command).

    t: (...) time [s]; neutral: (4, 3) mid-stance feet in the leg frames [m]; step: (..., 4, 3) the
    stance displacement (`step_vectors`) -> (..., 4, 3) feet in the leg frames [m].
    """
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    phase = leg_phases(t, params)  # (..., 4)
    neutral = jnp.asarray(neutral).astype(t.dtype)
    p_start = neutral - 0.5 * step
    p_end = neutral + 0.5 * step
    stance = p_start + stance_progress(phase, params)[..., None] * step
    u = jnp.clip((phase - params.duty) / (1.0 - params.duty), 0.0, 1.0)
    u = S.warp(u, params.p_t, params.p_n)
    swing = S.swing_point(u, p_end, p_start, params.step_height_m, params.swing)
    return jnp.where((phase < params.duty)[..., None], stance, swing)
