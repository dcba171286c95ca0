"""Swing-foot curves: the seed's cubic Bezier, a variant that reaches its step height, the cycloid.

Every curve runs over normalised swing progress u in [0, 1] from the lift-off point (stance end)
to the touchdown point (stance start), in the shoulder frame of constants.py: y is up, x and z are
the horizontal components. Points are (..., 3) [m]; u is (...); height [m] broadcasts with u.
Velocities below are d/du; divide by the swing duration (1 - duty) * cycle_s [s] for m/s (and
multiply by the warp's slope when the P_T/P_N warp is on).

Shapes, selected by an integer so that a gait can be a traced pytree (all shapes are evaluated and
one is selected; each costs a handful of flops):
  0 "bezier_seed": seed 000 Algorithm 6/7. Control points p0 = lift, p1 = (lift + land)/2 + h up,
    p2 = land + h/2 up, p3 = land. Its apex is h / sqrt(3) (trot: 2.887 cm of 5), see
    `BEZIER_SEED_APEX_RATIO`. d/du at lift-off: 1.5 (land - lift) + 3 h up (moving toward the
    touchdown point and up); at touchdown: -1.5 h up (straight down, no horizontal velocity).
  1 "bezier_apex": the same curve with both vertical control offsets scaled by sqrt(3), so the
    apex is exactly h: the vertical part is h sqrt(3) f(u) with f(u) = 3u(1-u)^2 + 1.5u^2(1-u) =
    u(1-u)(3 - 1.5u), whose maximum f(1 - 1/sqrt(3)) = 1/sqrt(3). d/du at lift-off:
    1.5 (land - lift) + 3 sqrt(3) h up; at touchdown: -1.5 sqrt(3) h up.
  2 "cycloid": seed 003 eq. 1-4 with K = 2 pi u: horizontal lift + (land - lift)(K - sin K)/(2 pi),
    vertical + H (1 - cos K)/2. Apex H at u = 1/2; zero velocity (all components) at both ends.

`warp` is the continuous form of seed 003's P_T/P_N point spacing; `cycloid_tick_times` the
discrete one.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

SWING_SHAPES: tuple[str, ...] = ("bezier_seed", "bezier_apex", "cycloid")
BEZIER_SEED_APEX_RATIO = 1.0 / math.sqrt(3.0)  # apex / step height of Algorithm 6's control points
APEX_SCALE = math.sqrt(3.0)  # vertical control-point scale that makes the seed curve reach h
SEED_003_TICK_S = 0.02  # seed 003: trajectory points replayed one per 20 ms tick (50 Hz)

_UP = np.array([0.0, 1.0, 0.0])  # shoulder-frame up (y)


def swing_shape_index(shape: str | int) -> int:
    """Name or index of a swing shape -> its index in SWING_SHAPES; ValueError if unknown."""
    if isinstance(shape, str):
        if shape not in SWING_SHAPES:
            raise ValueError(f"unknown swing shape {shape!r}; choose from {SWING_SHAPES}")
        return SWING_SHAPES.index(shape)
    if int(shape) != shape or not 0 <= int(shape) < len(SWING_SHAPES):
        raise ValueError(f"swing shape index {shape!r} out of range 0..{len(SWING_SHAPES) - 1}")
    return int(shape)


def cubic_bezier(u: jax.Array, p0, p1, p2, p3) -> jax.Array:
    """Seed 000 Algorithm 7. u: (...) in [0, 1]; p0..p3: (..., D) -> (..., D)."""
    u = jnp.asarray(u)[..., None]
    v = 1.0 - u
    return v**3 * p0 + 3.0 * v**2 * u * p1 + 3.0 * v * u**2 * p2 + u**3 * p3


def bezier_swing(u: jax.Array, lift: jax.Array, land: jax.Array, height, vertical_scale=1.0) -> jax.Array:
    """Algorithm 6's swing curve from lift (stance end) to land (stance start).

    u: (...); lift, land: (..., 3) shoulder frame [m]; height (...) [m] -> (..., 3) [m].
    vertical_scale 1 is the seed (apex h/sqrt 3); APEX_SCALE reaches h.
    """
    up = jnp.asarray(height * vertical_scale)[..., None] * _UP
    p1 = 0.5 * (lift + land) + up
    p2 = land + 0.5 * up
    return cubic_bezier(u, lift, p1, p2, land)


def cycloid_swing(u: jax.Array, lift: jax.Array, land: jax.Array, height) -> jax.Array:
    """Seed 003 eq. 1-4 with K = 2 pi u (u = t / T).

    u: (...); lift, land: (..., 3) [m]; height H (...) [m] -> (..., 3) [m]. All three components
    follow (K - sin K)/(2 pi) from lift to land (eq. 1-2; the seed's z0 = zf makes eq. 3's vertical
    interpolation vanish) and the vertical one adds H (1 - cos K)/2.
    """
    k = 2.0 * jnp.pi * jnp.asarray(u)
    along = ((k - jnp.sin(k)) / (2.0 * jnp.pi))[..., None]
    bump = (jnp.asarray(height) * 0.5 * (1.0 - jnp.cos(k)))[..., None] * _UP
    return lift + (land - lift) * along + bump


def swing_point(u: jax.Array, lift: jax.Array, land: jax.Array, height, shape) -> jax.Array:
    """Swing curve `shape` (index into SWING_SHAPES, may be traced) at progress u (...) -> (..., 3)."""
    shape = jnp.asarray(shape)[..., None]
    seed = bezier_swing(u, lift, land, height)
    apex = bezier_swing(u, lift, land, height, APEX_SCALE)
    cyc = cycloid_swing(u, lift, land, height)
    return jnp.where(shape == 0, seed, jnp.where(shape == 1, apex, cyc))


def warp(u: jax.Array, p_t, p_n) -> jax.Array:
    """Seed 003's P_T/P_N point spacing as a continuous, piecewise-linear time warp.

    u: (...) normalised real time since lift-off in [0, 1] -> (...) normalised trajectory time in
    [0, 1]. The first fraction P_N of real time covers the first fraction P_T of the trajectory,
    the rest the rest: s(u) = u P_T/P_N for u <= P_N, else P_T + (u - P_N)(1 - P_T)/(1 - P_N).
    Seed 003 (P_T 0.66, P_N 0.33) lifts off twice as fast as unwarped and lands at 0.51 times the
    speed. Continuous, monotone, s(0) = 0, s(1) = 1; a curve's zero end velocities stay zero.
    P_T = P_N gives the identity (use 1, 1 for "off").
    """
    u = jnp.asarray(u)
    p_t = jnp.asarray(p_t, dtype=u.dtype)
    p_n = jnp.asarray(p_n, dtype=u.dtype)
    first = u * p_t / jnp.where(p_n > 0, p_n, 1.0)
    rest_den = jnp.where(p_n < 1, 1.0 - p_n, 1.0)
    rest = p_t + (u - p_n) * (1.0 - p_t) / rest_den
    return jnp.where(u <= p_n, first, rest)


def cycloid_tick_times(period_s: float, p_t: float, p_n: float, tick_s: float = SEED_003_TICK_S):
    """Seed 003's discrete spacing: trajectory time [s] of each point, replayed one per tick.

    N = period_s / tick_s points; int(N P_N) of them spread evenly over [0, P_T T] (both ends
    included), the rest evenly over (P_T T, T]. Returns a numpy array (N,). Seed 003's example:
    T 0.5 s, P_T 0.66, P_N 0.33 -> 8 points over [0, 0.33] s, then 0.34 ... 0.50 s in 0.01 s steps.
    The continuous `warp` puts its break at u = P_N; this list reaches P_T T at point n1 - 1, i.e.
    at real time (n1 - 1) tick_s: the two agree as N grows.
    """
    n = round(period_s / tick_s)
    if n < 2 or abs(n * tick_s - period_s) > 1e-9:
        raise ValueError(f"period {period_s} s is not a multiple (>= 2) of the tick {tick_s} s")
    n1 = int(n * p_n + 1e-9)  # the seed's int(); the epsilon keeps 25 * 0.32 from becoming 7
    t_break = p_t * period_s
    first = np.linspace(0.0, t_break, n1) if n1 > 0 else np.zeros(0)
    n2 = n - n1
    rest = t_break + (period_s - t_break) * np.arange(1, n2 + 1) / max(n2, 1)
    return np.concatenate([first, rest])
