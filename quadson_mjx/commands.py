"""What the environment draws during an episode: velocity commands and their resampling, pushes.

Pure functions of a config and a PRNG key, jitted and vmapped as part of the environment's step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# the joystick evaluations' command sweep (quadson-rollout's suite, quadson-policy-eval): 75 commands
SWEEP_GRID = {
    "vx": (-0.3, -0.1, 0.1, 0.3, 0.5),
    "vy": (-0.2, 0.0, 0.2),
    "yaw_rate": (-0.8, -0.4, 0.0, 0.4, 0.8),
}


def sample_command(cfg, seed_speed: float, rng):
    """-> (command (3,) vx [m/s], vy [m/s], yaw rate [rad/s], seconds until the next one).

    Uniform over cfg.command_range, zero with probability cfg.command_zero_prob; the timer is
    U(cfg.command_resample_s), or +inf when resampling is off ((0, 0)). Without command_tracking:
    the gait's seed-speed forward walk, never resampled."""
    if not cfg.command_tracking:
        return jnp.array([seed_speed, 0.0, 0.0]), jnp.array(jnp.inf)
    k_cmd, k_zero, k_timer = jax.random.split(rng, 3)
    r = cfg.command_range
    lo = jnp.array([r.vx[0], r.vy[0], r.yaw_rate[0]])
    hi = jnp.array([r.vx[1], r.vy[1], r.yaw_rate[1]])
    command = jax.random.uniform(k_cmd, (3,), minval=lo, maxval=hi)
    if cfg.command_zero_prob > 0:
        command = jnp.where(jax.random.bernoulli(k_zero, cfg.command_zero_prob), 0.0, command)
    lo_s, hi_s = cfg.command_resample_s
    if hi_s > 0:
        timer = jax.random.uniform(k_timer, (), minval=lo_s, maxval=hi_s)
    else:
        timer = jnp.array(jnp.inf)
    return command, timer


def resample(cfg, seed_speed: float, command, timer, rng):
    """A new command mid-episode when `timer` [s] (already counted down) has run out: -> (command,
    timer, next rng); the old ones where it has not."""
    rng, k_cmd = jax.random.split(rng)
    new_command, new_timer = sample_command(cfg, seed_speed, k_cmd)
    now = timer <= 0.0
    return jnp.where(now, new_command, command), jnp.where(now, new_timer, timer), rng


def push(push_cfg, timer, rng):
    """A horizontal velocity kick to the base when `timer` [s] (already counted down) has run out.

    push_cfg: the env config's `push` group (interval_s, speed_mps ranges) -> (next timer [s], kick
    (2,) world-frame vx, vy to add [m/s], zero when not due, next rng)."""
    rng, k_dir, k_speed, k_next = jax.random.split(rng, 4)
    push_now = timer <= 0.0
    angle = jax.random.uniform(k_dir, (), maxval=2 * jnp.pi)
    speed = jax.random.uniform(k_speed, (), minval=push_cfg.speed_mps[0], maxval=push_cfg.speed_mps[1])
    kick = jnp.where(push_now, speed, 0.0) * jnp.array([jnp.cos(angle), jnp.sin(angle)])
    next_timer = jax.random.uniform(k_next, (), minval=push_cfg.interval_s[0], maxval=push_cfg.interval_s[1])
    return jnp.where(push_now, next_timer, timer), kick, rng


def sweep_commands() -> np.ndarray:
    """(75, 3) the sweep's commands (vx, vy, yaw rate), vx slowest."""
    g = np.meshgrid(*SWEEP_GRID.values(), indexing="ij")
    return np.stack([a.ravel() for a in g], axis=-1)
