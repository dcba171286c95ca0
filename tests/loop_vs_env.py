"""Shared by the deploy tests: the loop's motor targets against the jitted environment's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

# clock states in and after the 0.5 s start ramp
CLOCKS = [(0.0, 0.0), (0.1, 0.08), (0.35, 0.3), (0.62, 0.48), (0.9, 2.0), (0.99, 7.5)]


def assert_loop_targets_match_env(env, loop, command) -> None:
    """At each of CLOCKS (gait progress, episode time) and an action inside and beyond [-1, 1], the
    loop's foot targets, motor targets, IK validity and cycle time equal env._motor_targets'
    (float32 env, float64 loop: 2e-6 m, 2e-5 rad)."""
    actuator = np.asarray(env.motor_actuators)
    # after jitted float64 references, a float32 jit failed to lower on jax 0.10.2 (an f32 x f64
    # multiply: a cached float64 constant); it passes alone and with clean caches
    jax.clear_caches()
    motor_targets = jax.jit(env._motor_targets)
    rng = np.random.default_rng(2)
    for progress, t in CLOCKS:
        action = rng.uniform(-1.3, 1.3, env.action_size).astype(np.float32)
        info = {
            "gait_progress": jnp.float32(progress),
            "episode_time": jnp.float32(t),
            "command": jnp.asarray(command, jnp.float32),
        }
        ctrl, n_invalid, cycle_s, feet = motor_targets(info, jnp.clip(jnp.asarray(action), -1.0, 1.0))
        loop.progress, loop.time_s = progress, t
        motor, valid, got_feet, got_cycle = loop.targets(action, command)
        np.testing.assert_allclose(got_feet, feet, rtol=0, atol=2e-6)
        np.testing.assert_allclose(motor, np.asarray(ctrl)[actuator], rtol=0, atol=2e-5)
        assert int(np.sum(~valid)) == int(n_invalid)
        assert got_cycle == pytest.approx(float(cycle_s), rel=1e-6)
