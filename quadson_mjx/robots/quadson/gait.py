"""Quadson's gaits: seed 000's gait table in the shoulder frames, and the five-bar motor targets.

The gaits of constants.GAITS and seed 003's discontinuous trot (constants.DISCONTINUOUS_TROT) on the
generic machinery of quadson_mjx.gait. Feet are in the shoulder (leg) frames of constants.py: x
along p1 -> p5, y up, z lateral; shapes (..., 4, 3) in LEGS order. The environment's entry points
are `foot_targets`, then `motor_targets`.

Stance runs at ground height (y = -STANCE_HEIGHT). The neutral point is the middle of the seed's
stance, (STANCE_START_X + STANCE_DIRECTION step_length_m / 2, -STANCE_HEIGHT, 0), so that the
command vx = seed_speed(params) = step_length_m / (duty cycle_s) reproduces Algorithm 6 (p_start =
STANCE_START_X) up to float rounding.

Reach (tests/test_gait.py): at their seed speeds walk, trot, pace, bound and trot_discontinuous are
inside the five-bar's workspace and limits along the whole cycle for every swing shape; the seed's
gallop is not: its front stance ends at x = 17 cm, y = -20 cm, 26.25 cm from p1, beyond the
p1-p2-foot chain's 26 cm (invalid for x > 16.61 cm, the last 1.9 % of the front legs' stance).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from quadson_mjx import gait as G
from quadson_mjx.gait import GaitParams, leg_phases, params_from, seed_speed  # noqa: F401 (Quadson's gait API)
from quadson_mjx.robots.quadson import body, fivebar
from quadson_mjx.robots.quadson import constants as C

# Seed 003's discontinuous trot: constants.DISCONTINUOUS_TROT (the numpy gait of deploy shares it).
SEED_003_P_T = C.SEED_003_P_T
SEED_003_P_N = C.SEED_003_P_N
DISCONTINUOUS_TROT = C.DISCONTINUOUS_TROT
GAIT_NAMES: tuple[str, ...] = (*C.GAITS, "trot_discontinuous")


def gait_params(name: str, **overrides) -> GaitParams:
    """The gait `name` (GAIT_NAMES) with field overrides; swing may be a name from SWING_SHAPES.

    Raises ValueError on an unknown gait, an unknown field or inconsistent values.
    """
    if name == "trot_discontinuous":
        base = dict(DISCONTINUOUS_TROT)
    elif name in C.GAITS:
        base = dict(C.GAITS[name])
    else:
        raise ValueError(f"unknown gait {name!r}; choose from {GAIT_NAMES}")
    return params_from(base, **overrides)


def neutral_feet(params: GaitParams) -> jax.Array:
    """Mid-stance foot of each leg: (4, 3) in the shoulder frames [m]."""
    x = jnp.asarray(C.STANCE_START_X) + jnp.asarray(C.STANCE_DIRECTION) * (0.5 * params.step_length_m)
    return jnp.stack([x, jnp.full_like(x, -C.STANCE_HEIGHT), jnp.zeros_like(x)], axis=-1)


def step_vectors(command: jax.Array, params: GaitParams) -> jax.Array:
    """Stance displacement of each foot relative to the body over one stance (gait.step_vectors).

    command: (..., 3) body velocity (vx [m/s], vy [m/s], yaw_rate [rad/s]), body frame ->
    (..., 4, 3) p_end - p_start in each shoulder frame [m]: -(v + w x r_neutral) * stance_time.
    """
    return G.step_vectors(command, params, neutral_feet(params), C.SHOULDER_POS, C.SHOULDER_ROT)


def foot_targets(t: jax.Array, command: jax.Array, params: GaitParams, body_offset=None) -> jax.Array:
    """Foot targets of the gait (seed 000 Algorithm 6, generalised to a velocity command).

    t: (...) time [s]; command: (..., 3) (vx, vy [m/s], yaw_rate [rad/s]) in the body frame, or
    (3,) for all; body_offset: None or (..., 6) body pose offset (x, y, z [m], roll, pitch, yaw
    [rad]) applied through body kinematics (quadson_mjx.robots.quadson.body), e.g. (0, 0, dz, roll, pitch, 0)
    raises and tilts the body over feet that stay put in the world.
    -> (..., 4, 3) feet in the shoulder frames [m], LEGS order.
    """
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    feet = G.feet_on_path(t, params, neutral_feet(params), step_vectors(command, params))
    if body_offset is not None:
        feet = apply_body_offset(feet, body_offset)
    return feet


def apply_body_offset(feet_shoulder: jax.Array, body_offset: jax.Array) -> jax.Array:
    """Feet (..., 4, 3) in the shoulder frames of the nominal body -> the same world points in the
    shoulder frames of a body displaced by body_offset (..., 6) (x, y, z, roll, pitch, yaw)."""
    feet_shoulder = jnp.asarray(feet_shoulder)
    nominal = jnp.zeros(feet_shoulder.shape[:-2] + (6,), feet_shoulder.dtype)
    world = body.shoulder_to_world(nominal, feet_shoulder)
    return body.world_to_shoulder(jnp.asarray(body_offset, feet_shoulder.dtype), world)


def motor_targets(foot_targets_shoulder: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Five-bar IK (seed 000 Algorithm 2) for all legs, clamped into the motor limits.

    foot_targets_shoulder: (..., 4, 3) [m] -> (angles (..., 4, 3) (t0, t1, t5) [rad], valid (..., 4)
    bool). Where a target is invalid (out of reach, beyond a limit, toe-in guard, other branch)
    the angles are clipped into constants.MOTOR_RANGES and t5 <= t1 + TOE_IN_MAX, never NaN;
    jnp.sum(~valid) counts them.
    """
    angles, valid = fivebar.leg_ik(foot_targets_shoulder)
    angles = jnp.nan_to_num(angles)
    lo = jnp.asarray(C.MOTOR_RANGES[:, 0], angles.dtype)
    hi = jnp.asarray(C.MOTOR_RANGES[:, 1], angles.dtype)
    angles = jnp.clip(angles, lo, hi)
    t5 = jnp.minimum(angles[..., 2], angles[..., 1] + C.TOE_IN_MAX)
    angles = angles.at[..., 2].set(jnp.clip(t5, lo[2], hi[2]))
    return angles, valid
