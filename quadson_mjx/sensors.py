"""What the environment's sensors read: the entries of the observation spec (quadson_mjx.obs_spec)
from a physics state, with the config's sensor noise when randomized.

Pure JAX, jitted and vmapped as part of the environment's step. The deploy loop builds the same
entries from the robot's own sensors (quadson_mjx.deploy).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from quadson_mjx.quat import quat_rotate_inverse, quat_to_rpy


def base_state(qpos, qvel):
    """The base as the IMU and a velocity estimator see it, from the free joint's qpos (nq,) and qvel
    (nv,): -> rpy (3,) [rad] (ZYX), body-frame linear velocity (3,) [m/s] (qvel[0:3] is world-frame),
    body-frame angular velocity (3,) [rad/s] (qvel[3:6] is already in the body frame)."""
    quat = qpos[3:7]
    return quat_to_rpy(quat), quat_rotate_inverse(quat, qvel[0:3]), qvel[3:6]


def observation_parts(cfg, rpy, lin_vel, ang_vel, motor_pos, phase, command, rng) -> dict:
    """cfg: the env config; rpy (3,) [rad], body-frame lin_vel (3,) [m/s] and ang_vel (3,) [rad/s],
    motor_pos (12,) [rad], phase (4,) [rad] (2 pi x each leg's gait phase), command (3,) (read only
    when the config tracks commands), rng: the step's noise key (read only when randomized) -> entry name -> value, the entries of obs_spec.locomotion_observation.
    Randomized configs add Gaussian noise of std cfg.noise.* to the IMU, velocity and encoders."""
    if cfg.randomize:
        k = jax.random.split(jax.random.fold_in(rng, 1), 4)
        n = cfg.noise
        rpy = rpy + n.rpy * jax.random.normal(k[0], (3,))
        lin_vel = lin_vel + n.lin_vel * jax.random.normal(k[1], (3,))
        ang_vel = ang_vel + n.ang_vel * jax.random.normal(k[2], (3,))
        motor_pos = motor_pos + n.motor_pos * jax.random.normal(k[3], motor_pos.shape)
    parts = {
        "base_rpy": rpy,
        "base_lin_vel": lin_vel,
        "base_ang_vel": ang_vel,
        "motor_pos": motor_pos,
        "phase_sin": jnp.sin(phase),
        "phase_cos": jnp.cos(phase),
    }
    if cfg.command_tracking:
        parts["command"] = command
    return parts
