"""Seed 003 PID stabilizer against hand-computed outputs."""

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx.stabilizer import PidGains, limit, pid_init, pid_step

step = jax.jit(pid_step)


def test_limiter_published_case():
    # robots.md: (0.4, -0.2) sums to 0.6 > 0.45, so both scale by 0.45 / 0.6 = 0.75 -> (0.3, -0.15).
    np.testing.assert_allclose(limit(jnp.array([0.4, -0.2])), [0.3, -0.15], atol=1e-7)
    np.testing.assert_allclose(
        limit(jnp.array([0.2, -0.1])), [0.2, -0.1], atol=1e-7
    )  # 0.3 <= 0.45: untouched


def test_first_step_by_hand():
    # roll 0.1, pitch -0.05; e = (-0.1, 0.05); sum = e; I term = 7.5 * e * 0.02 = 0.15 e;
    # D term = 0.006 * e / 0.02 = 0.3 e; P term = 0.3 e. u = 0.75 e = (-0.075, 0.0375); |u| sum 0.1125 < 0.45.
    state, u = step(pid_init(), jnp.array([0.1, -0.05]))
    np.testing.assert_allclose(u, [-0.075, 0.0375], rtol=1e-6)
    np.testing.assert_allclose(state.error_sum, [-0.1, 0.05], rtol=1e-6)


def test_anti_windup_freezes_the_integral():
    # A constant roll of 0.45 rad, error -0.45: the I term is 7.5 * 0.02 * |sum| = 0.15 |sum|. Sums -0.45,
    # -0.9, -1.35, -1.8 give 0.0675, 0.135, 0.2025, 0.27 < 0.30 and are taken; -2.25 would give 0.3375, so
    # the sum stays at -1.8 however long the error lasts.
    state = pid_init()
    for _ in range(10):
        state, _ = step(state, jnp.array([0.45, 0.0]))
    np.testing.assert_allclose(state.error_sum, [-1.8, 0.0], rtol=1e-6)


def test_limiter_active_in_the_loop_and_batched():
    gains = PidGains()
    rp = jnp.array([[0.6, -0.3], [0.01, 0.0]])
    state, u = jax.jit(jax.vmap(pid_step, in_axes=(0, 0, None)))(pid_init((2,)), rp, gains)
    assert u.shape == (2, 2)
    np.testing.assert_allclose(jnp.sum(jnp.abs(u[0])), 0.45, rtol=1e-6)
    assert jnp.sign(u[0, 0]) == -1 and jnp.sign(u[0, 1]) == 1  # corrects against the tilt
    np.testing.assert_allclose(u[1], [-0.0075, 0.0], atol=1e-7)
