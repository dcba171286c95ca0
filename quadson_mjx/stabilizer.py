"""Roll/pitch PID stabilizer of seed 003 (Caramel), as a pure JAX function.

Two identical PID loops hold body roll and pitch at zero; their outputs are body roll/pitch commands
[rad] that the gait applies through body kinematics. Numbers from the robot's code (robots.md):
kp 0.3, ki 7.5, kd 0.006 at 50 Hz; anti-windup: the integral grows only while
|ki (sum + e) dt| < 0.30 rad; limiter: when |u_roll| + |u_pitch| > 0.45 rad, both outputs are
scaled down by the same factor so that the sum is 0.45 (it keeps the body inside the joints' reach).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class PidGains(NamedTuple):
    kp: float = 0.3
    ki: float = 7.5
    kd: float = 0.006
    dt: float = 0.02  # s, 50 Hz
    integral_limit: float = 0.30  # rad, bound on the integral term's output
    output_limit: float = 0.45  # rad, bound on |u_roll| + |u_pitch|


class PidState(NamedTuple):
    error_sum: jnp.ndarray  # (..., 2) running sum of roll, pitch errors [rad] (times dt in the I term)
    prev_error: jnp.ndarray  # (..., 2) last errors [rad]


SEED_003_GAINS = PidGains()


def pid_init(batch_shape=()) -> PidState:
    z = jnp.zeros((*batch_shape, 2))
    return PidState(z, z)


def limit(u, output_limit=0.45):
    """u (..., 2) roll, pitch commands -> scaled so that |u_roll| + |u_pitch| <= output_limit."""
    total = jnp.sum(jnp.abs(u), axis=-1, keepdims=True)
    scale = jnp.where(total > output_limit, output_limit / jnp.maximum(total, 1e-12), 1.0)
    return u * scale


def pid_step(state: PidState, roll_pitch, gains: PidGains = SEED_003_GAINS):
    """roll_pitch (..., 2) measured body roll, pitch [rad] -> (new state, (..., 2) command [rad])."""
    error = -roll_pitch  # setpoint 0
    candidate = state.error_sum + error
    grow = jnp.abs(gains.ki * candidate * gains.dt) < gains.integral_limit
    error_sum = jnp.where(grow, candidate, state.error_sum)
    derivative = (error - state.prev_error) / gains.dt
    u = gains.kp * error + gains.ki * error_sum * gains.dt + gains.kd * derivative
    return PidState(error_sum, error), limit(u, gains.output_limit)
