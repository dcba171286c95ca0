"""Gait generators (quadson_mjx.gait, quadson_mjx.swing) against hand arithmetic, the seeds'
published numbers and finite differences, run as production runs them: jit(vmap(...)).

Published numbers are copied here with their source (the tests never read ../shared):
  * robots.md gait table (cm, s), pace corrected to same-side legs (FL+RL, FR+RR).
  * robots.md stance: base_y -20 cm, start x -4 cm front / +13 cm rear, direction +1 / -1.
  * robots.md: "trot apex about 2.9 cm of 5" for Algorithm 6's control points.
  * robots.md inverse vectors: (-4, -20) cm -> (t1, t5) = (2.8406, 1.7611) rad.
  * seed 003: cycloid eq. 1-4; T 0.5 s, P_T 0.66, P_N 0.33 -> 8 of 25 points in the first
    0.33 s, then 0.34 ... 0.50 s in 0.01 s steps.
  * seed 000 link lengths: L1 8 cm, L2 + L3 18 cm (the p1-p2-foot chain reaches 26 cm).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from quadson_mjx import swing as S
from quadson_mjx.robots.quadson import body, fivebar
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import gait as G

CM = 0.01
# robots.md gait table: offsets FL/FR/RL/RR, cycle [s], duty, step height [cm], step length [cm]
SEED_TABLE = {
    "walk": ((0.0, 0.5, 0.25, 0.75), 1.2, 0.75, 3.0, 8.0),
    "trot": ((0.0, 0.5, 0.5, 0.0), 0.8, 0.5, 5.0, 12.0),
    "pace": ((0.0, 0.5, 0.0, 0.5), 0.7, 0.5, 5.0, 12.0),  # corrected: same-side pairs
    "bound": ((0.0, 0.0, 0.5, 0.5), 0.6, 0.4, 8.0, 16.0),
    "gallop": ((0.1, 0.25, 0.6, 0.75), 0.5, 0.35, 7.0, 21.0),
}
SEED_START_X_CM = np.array([-4.0, -4.0, 13.0, 13.0])
SEED_DIRECTION = np.array([1.0, 1.0, -1.0, -1.0])
SEED_BASE_Y_CM = -20.0
FIVE = tuple(SEED_TABLE)
FRONT = np.array([True, True, False, False])


# --- compiled once per module ------------------------------------------------------------------


@pytest.fixture(scope="module")
def feet_fn():
    """jit(vmap) over a batch of (time, command); params traced, so one compile serves every gait."""
    return jax.jit(jax.vmap(G.foot_targets, in_axes=(0, 0, None)))


@pytest.fixture(scope="module")
def feet_offset_fn():
    return jax.jit(jax.vmap(G.foot_targets, in_axes=(0, 0, None, 0)))


@pytest.fixture(scope="module")
def phases_fn():
    return jax.jit(jax.vmap(G.leg_phases, in_axes=(0, None)))


@pytest.fixture(scope="module")
def motor_fn():
    return jax.jit(jax.vmap(G.motor_targets))


def _feet(feet_fn, t, command, params):
    t = np.asarray(t, np.float32)
    cmd = np.broadcast_to(np.asarray(command, np.float32), (t.size, 3))
    return np.asarray(feet_fn(jnp.asarray(t), jnp.asarray(cmd), params), np.float64)


def _to_body(feet_shoulder):
    """(..., 4, 3) shoulder-frame vectors -> body frame (rotation only)."""
    return np.einsum("lij,...lj->...li", C.SHOULDER_ROT, feet_shoulder)


def _event_time(phase, params, leg):
    """First time > one cycle at which `leg` has `phase`."""
    return ((phase - params.phase_offset[leg]) % 1.0 + 1.0) * params.cycle_s


# --- 1. parameters and phases (Algorithm 5) -----------------------------------------------------


@pytest.mark.parametrize("name", FIVE)
def test_gait_params_match_published_table(name):
    p = G.gait_params(name)
    offsets, cycle, duty, height_cm, length_cm = SEED_TABLE[name]
    np.testing.assert_allclose(p.phase_offset, offsets, atol=1e-7)
    assert (p.cycle_s, p.duty) == pytest.approx((cycle, duty))
    assert p.step_height_m == pytest.approx(height_cm * CM)
    assert p.step_length_m == pytest.approx(length_cm * CM)
    assert p.swing == 0 and not p.discontinuous  # the seed's Bezier by default


def test_gait_params_overrides_and_errors():
    p = G.gait_params("trot", swing="bezier_apex", step_height_m=0.03)
    assert p.swing == S.SWING_SHAPES.index("bezier_apex") and p.step_height_m == 0.03
    for bad in (
        lambda: G.gait_params("canter"),
        lambda: G.gait_params("trot", step_hieght_m=0.03),
        lambda: G.gait_params("trot", swing="spline"),
        lambda: G.gait_params("trot", duty=1.0),
        lambda: G.gait_params("trot", p_t=0.5, p_n=1.0),
        lambda: G.gait_params("walk", discontinuous=True),  # four different offsets: no pairs
        lambda: G.gait_params("trot", discontinuous=True),  # duty 0.5 leaves no time to shift
    ):
        with pytest.raises(ValueError):
            bad()


@pytest.mark.parametrize("name", FIVE)
def test_leg_phases_algorithm5_and_duty(name, phases_fn):
    p = G.gait_params(name)
    offsets, cycle, duty, _, _ = SEED_TABLE[name]
    n = 4000
    t = (np.arange(n) + 0.5) / n * cycle + 3 * cycle  # one cycle, three cycles in
    ph = np.asarray(phases_fn(jnp.asarray(t, jnp.float32), p))
    assert ph.shape == (n, 4) and ph.dtype == np.float32
    # Algorithm 5 by hand, as the robot's code: ((t % T) / T + offset) % 1
    ref = ((t % cycle) / cycle)[:, None] + np.array(offsets)
    np.testing.assert_allclose(ph, ref % 1.0, atol=2e-5)
    # every leg spends `duty` of the cycle in stance
    np.testing.assert_allclose(np.mean(ph < duty, axis=0), duty, atol=1.0 / n)
    same = {"trot": [(0, 3), (1, 2)], "pace": [(0, 2), (1, 3)], "bound": [(0, 1), (2, 3)]}
    for a, b in same.get(name, []):  # pace same side, bound front/rear, trot diagonal
        np.testing.assert_allclose(ph[:, a], ph[:, b], atol=1e-6)
    if name in same:  # and the two pairs half a cycle apart
        a, b = same[name][0][0], same[name][1][0]
        np.testing.assert_allclose((ph[:, a] - ph[:, b]) % 1.0, 0.5, atol=1e-5)


def test_leg_phases_stay_below_one():
    p = G.gait_params("trot")
    # x - floor(x) for x = -1e-9 is 1.0 in float32: the phase must wrap to 0 instead
    ph = np.asarray(G.leg_phases(jnp.asarray([-1e-9, -1e-30, 0.0, 0.8, 1e4], jnp.float32), p))
    assert np.all((ph >= 0.0) & (ph < 1.0))


_phases_jit = jax.jit(G.leg_phases)
_warp_jit = jax.jit(S.warp)


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e4, 1e4, width=32), st.sampled_from(FIVE))
def test_leg_phases_in_unit_interval_for_any_time(t, name):
    ph = np.asarray(_phases_jit(jnp.float32(t), G.gait_params(name)))
    assert np.all((ph >= 0.0) & (ph < 1.0))


@settings(max_examples=200, deadline=None)
@given(st.floats(0.05, 0.95), st.floats(0.05, 0.95), st.floats(0.0, 1.0))
def test_warp_is_monotone_and_keeps_ends(p_t, p_n, u):
    u2 = min(u + 1e-3, 1.0)
    s = np.asarray(_warp_jit(jnp.array([0.0, u, u2, 1.0], jnp.float32), p_t, p_n))
    np.testing.assert_allclose(s[[0, 3]], [0.0, 1.0], atol=1e-6)
    assert 0.0 <= s[1] <= s[2] <= 1.0 + 1e-6


# --- 2. the seed's paths (Algorithms 6-7) --------------------------------------------------------


def _seed_algorithm6(t, name):
    """Seed 000 Algorithm 6 transcribed in numpy, in cm, with robots.md's numbers -> (n, 4, 3) m."""
    offsets, cycle, duty, h, length = SEED_TABLE[name]
    out = np.zeros((len(t), 4, 3))
    for i, ti in enumerate(t):
        for leg in range(4):
            phase = ((ti % cycle) / cycle + offsets[leg]) % 1.0
            sx, d, y0 = SEED_START_X_CM[leg], SEED_DIRECTION[leg], SEED_BASE_Y_CM
            if phase < duty:
                x, y = sx + d * length * phase / duty, y0
            else:
                u = (phase - duty) / (1 - duty)
                pts = np.array(
                    [(sx + d * length, y0), (sx + d * length / 2, y0 + h), (sx, y0 + h / 2), (sx, y0)]
                )
                x, y = np.array([(1 - u) ** 3, 3 * (1 - u) ** 2 * u, 3 * (1 - u) * u**2, u**3]) @ pts
            out[i, leg] = (x * CM, y * CM, 0.0)
    return out


@pytest.mark.parametrize("name", FIVE)
def test_seed_speed_command_reproduces_algorithm6(name, feet_fn):
    p = G.gait_params(name)
    _, cycle, duty, _, length_cm = SEED_TABLE[name]
    v0 = length_cm * CM / (duty * cycle)
    assert float(G.seed_speed(p)) == pytest.approx(v0, rel=1e-6)
    t = np.linspace(0.0, 2 * cycle, 203)[1:-1]
    # stay off exact phase boundaries, where float rounding may pick either side
    ph = ((t % cycle) / cycle)[:, None] + np.array(SEED_TABLE[name][0])
    t = t[np.all(np.abs(((ph % 1.0) - duty + 0.5) % 1.0 - 0.5) > 1e-4, axis=1)]
    got = _feet(feet_fn, t, (v0, 0.0, 0.0), p)
    np.testing.assert_allclose(got, _seed_algorithm6(t, name), atol=2e-6)


def test_seed_bezier_trot_apex_is_2p9_cm():
    # y(u) - y0 = h (3u(1-u)^2 + 1.5u^2(1-u)) = h u(1-u)(3 - 1.5u); dy/du = h(3 - 9u + 4.5u^2) = 0
    # at u* = 1 - 1/sqrt(3) = 0.42265, where u(1-u)(3 - 1.5u) = 0.42265 * 0.57735 * 2.36603
    # = 0.57735 = 1/sqrt(3): apex 5 cm * 0.57735 = 2.8868 cm (robots.md: "about 2.9 cm of 5").
    u = jnp.linspace(0.0, 1.0, 200001)
    lift, land = jnp.array([0.08, -0.2, 0.0]), jnp.array([-0.04, -0.2, 0.0])
    path = np.asarray(S.bezier_swing(u, lift, land, 0.05))
    apex = path[:, 1].max() + 0.2
    assert apex == pytest.approx(0.028868, abs=2e-6)
    assert apex == pytest.approx(2.9 * CM, abs=0.05 * CM)
    # the maximum sits at u* (float32 cannot resolve the flat top to better than ~1e-3 in u)
    at_star = np.asarray(S.bezier_swing(jnp.float32(1 - 1 / math.sqrt(3)), lift, land, 0.05))
    assert at_star[1] + 0.2 == pytest.approx(apex, abs=1e-7)


@pytest.mark.parametrize("name", (*FIVE, "trot_discontinuous"))
@pytest.mark.parametrize("shape", ("bezier_seed", "bezier_apex", "cycloid"))
def test_swing_apex_and_ground_height(name, shape, feet_fn):
    p = G.gait_params(name, swing=shape)
    h = p.step_height_m
    t = np.linspace(0.0, p.cycle_s, 20001)
    feet = _feet(feet_fn, t, (float(G.seed_speed(p)), 0.0, 0.0), p)
    lift = feet[..., 1] + C.STANCE_HEIGHT  # height above the stance line, (n, 4)
    assert np.all(lift >= -1e-6)
    expected = h / math.sqrt(3.0) if shape == "bezier_seed" else h  # seed's apex is h / sqrt 3
    np.testing.assert_allclose(lift.max(axis=0), expected, atol=1e-5)


@pytest.mark.parametrize("name", (*FIVE, "trot_discontinuous"))
@pytest.mark.parametrize("shape", ("bezier_seed", "bezier_apex", "cycloid"))
@pytest.mark.parametrize("command", [(1.0, 0.0, 0.0), (-0.1, 0.08, 0.4)])
def test_positions_continuous_at_liftoff_touchdown_and_wrap(name, shape, command, feet_fn):
    p = G.gait_params(name, swing=shape)
    cmd = np.array(command) * (float(G.seed_speed(p)) if command[0] == 1.0 else 1.0)
    eps = 1e-5  # s; at the fastest foot (~3 m/s) two samples 2 eps apart differ by < 6e-5 m
    for leg in range(4):
        # lift-off (phase = duty) and touchdown, which is also the wrap of the phase (1 -> 0)
        for phase in (p.duty, 0.0):
            te = _event_time(phase, p, leg)
            pts = _feet(feet_fn, [te - eps, te + eps], cmd, p)[:, leg]
            assert np.linalg.norm(pts[1] - pts[0]) < 1e-4, (name, shape, leg, phase, pts)


def _one_sided_velocity(feet_fn, t0, direction, cmd, p, h=1e-4):
    """Second-order one-sided difference of the feet (4, 3) at t0 (just inside the swing)."""
    t = t0 + direction * np.array([0.0, h, 2 * h])
    x = _feet(feet_fn, t, cmd, p)
    return direction * (-3 * x[0] + 4 * x[1] - x[2]) / (2 * h)


@pytest.mark.parametrize(
    "shape, liftoff, touchdown",
    [
        # trot, FL: lift (8, -20) cm -> land (-4, -20) cm over 0.4 s, h = 5 cm.
        # seed Bezier: d/du = 3 (p1 - p0) = (1.5 * -0.12, 3 * 0.05) = (-0.18, 0.15) -> / 0.4 s;
        # at touchdown 3 (p3 - p2) = (0, -0.075) -> / 0.4 s.
        ("bezier_seed", (-0.45, 0.375), (0.0, -0.1875)),
        # apex variant: vertical control offsets times sqrt(3)
        ("bezier_apex", (-0.45, 0.375 * math.sqrt(3)), (0.0, -0.1875 * math.sqrt(3))),
        # cycloid: dx/dK = (xf - x0)(1 - cos K)/(2 pi), dz/dK = H sin K / 2: both 0 at K = 0, 2 pi
        ("cycloid", (0.0, 0.0), (0.0, 0.0)),
    ],
)
def test_swing_velocities_at_liftoff_and_touchdown(shape, liftoff, touchdown, feet_fn):
    p = G.gait_params("trot", swing=shape)
    cmd = (float(G.seed_speed(p)), 0.0, 0.0)
    t_lift = _event_time(p.duty, p, 0) + 1e-6
    t_land = _event_time(0.0, p, 0) - 1e-6
    v_lift = _one_sided_velocity(feet_fn, t_lift, +1, cmd, p)[0]
    v_land = _one_sided_velocity(feet_fn, t_land, -1, cmd, p)[0]
    np.testing.assert_allclose(v_lift[:2], liftoff, atol=5e-3)
    np.testing.assert_allclose(v_land[:2], touchdown, atol=5e-3)
    # the stance before lift-off moves at +0.12 m / 0.4 s = 0.3 m/s in FL's x: a velocity jump
    v_stance = _one_sided_velocity(feet_fn, t_lift - 2e-6, -1, cmd, p)[0]
    np.testing.assert_allclose(v_stance, (0.3, 0.0, 0.0), atol=5e-3)


# --- cycloid and warp (seed 003) ---------------------------------------------------------------


def test_cycloid_at_hand_computed_points():
    # seed 003 Test 1: (x, y) = (5, 3) cm, H = 5 cm; horizontal here is the shoulder x and z.
    lift, land, H = jnp.zeros(3), jnp.array([0.05, 0.0, 0.03]), 0.05
    u = jnp.array([0.0, 0.25, 0.5, 0.75, 1.0])
    got = np.asarray(S.cycloid_swing(u, lift, land, H))
    # K = 2 pi u: (K - sin K)/(2 pi) = 0, (pi/2 - 1)/(2 pi) = 0.0908451, 1/2,
    # (3 pi/2 + 1)/(2 pi) = 0.9091549, 1; (1 - cos K)/2 = 0, 1/2, 1, 1/2, 0
    along = np.array([0.0, 0.0908451, 0.5, 0.9091549, 1.0])
    bump = np.array([0.0, 0.5, 1.0, 0.5, 0.0])
    want = np.stack([0.05 * along, H * bump, 0.03 * along], axis=-1)
    np.testing.assert_allclose(got, want, atol=1e-7)


def test_warp_hand_values():
    u = jnp.array([0.0, 0.165, 0.33, 0.5, 1.0])
    got = np.asarray(S.warp(u, 0.66, 0.33))
    # slope 0.66/0.33 = 2 up to u = 0.33; then 0.66 + (u - 0.33) * 0.34/0.67: u = 0.5 -> 0.746269
    np.testing.assert_allclose(got, [0.0, 0.33, 0.66, 0.7462687, 1.0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(S.warp(u, 1.0, 1.0)), np.asarray(u))  # "off"
    np.testing.assert_allclose(np.asarray(S.warp(u, 0.4, 0.4)), np.asarray(u), atol=1e-7)
    assert np.all(np.diff(np.asarray(S.warp(jnp.linspace(0, 1, 1001), 0.66, 0.33))) > 0)


def test_seed003_tick_times_example():
    ticks = S.cycloid_tick_times(0.5, 0.66, 0.33)
    assert ticks.shape == (25,)  # N = 0.5 s / 20 ms
    assert np.sum(ticks <= 0.33 + 1e-12) == 8  # int(25 * 0.33) = 8 points over [0, 0.33] s
    np.testing.assert_allclose(ticks[:8], np.linspace(0.0, 0.33, 8), atol=1e-12)
    np.testing.assert_allclose(ticks[8:], 0.34 + 0.01 * np.arange(17), atol=1e-12)
    # P_T = P_N = 1: 25 equally spaced points (seed 003's single-leg experiment)
    np.testing.assert_allclose(S.cycloid_tick_times(0.5, 1.0, 1.0), np.linspace(0, 0.5, 25), atol=1e-12)
    with pytest.raises(ValueError):
        S.cycloid_tick_times(0.51, 0.66, 0.33)


def test_warped_cycloid_in_foot_targets(feet_fn):
    p = G.gait_params("trot", swing="cycloid", p_t=0.66, p_n=0.33)
    cmd = (float(G.seed_speed(p)), 0.0, 0.0)
    t_lift = _event_time(p.duty, p, 0)  # FL lifts off at 0.4 s (+ one cycle), swing 0.4 s
    # a third of the swing time in, the trajectory is 0.66 through (K = 1.32 pi)
    foot = _feet(feet_fn, [t_lift + 0.33 * 0.4], cmd, p)[0, 0]
    k = 2 * np.pi * 0.66
    along, bump = (k - np.sin(k)) / (2 * np.pi), (1 - np.cos(k)) / 2
    want = (0.08 - 0.12 * along, -0.2 + 0.05 * bump, 0.0)  # from (8, -20) to (-4, -20) cm
    np.testing.assert_allclose(foot, want, atol=3e-5)


# --- 3. commands -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", (*FIVE, "trot_discontinuous"))
@pytest.mark.parametrize("command", [(0.2, 0.0, 0.0), (-0.1, 0.0, 0.0), (0.0, 0.1, 0.0), (0.05, -0.07, 0.0)])
def test_stance_on_ground_moving_at_command(name, command, feet_fn, phases_fn):
    p = G.gait_params(name)
    n, h = 400, 1e-4
    t = np.linspace(p.cycle_s, 2 * p.cycle_s, n)
    feet = _feet(feet_fn, np.concatenate([t - h, t + h]), command, p)
    vel = _to_body((feet[n:] - feet[:n]) / (2 * h))  # (n, 4, 3) foot velocity relative to the body
    ph = np.asarray(phases_fn(jnp.asarray(t, jnp.float32), p))
    margin = 2 * h / p.cycle_s + 1e-4
    stance = (ph > margin) & (ph < p.duty - margin)
    mid = _feet(feet_fn, t, command, p)
    assert np.all(np.abs(mid[..., 1][stance] + 0.2) < 1e-6)  # on the ground line, y = -20 cm
    v = -np.array([command[0], command[1], 0.0])
    if not p.discontinuous:
        np.testing.assert_allclose(vel[stance], np.broadcast_to(v, vel[stance].shape), atol=2e-3)
    else:
        # shift windows (global phase of FL in [0, .25) or [.5, .75)): body at v / (2 duty - 1)
        # = 2v; swing windows: every stance foot still
        g = ph[:, 0]
        shifting = ((g > 0.002) & (g < 0.248)) | ((g > 0.502) & (g < 0.748))
        swinging = ((g > 0.252) & (g < 0.498)) | ((g > 0.752) & (g < 0.998))
        s_shift, s_swing = stance & shifting[:, None], stance & swinging[:, None]
        np.testing.assert_allclose(vel[s_shift], np.broadcast_to(2 * v, vel[s_shift].shape), atol=2e-3)
        np.testing.assert_allclose(vel[s_swing], 0.0, atol=2e-3)
        # contact pattern of seed 003: shift (4 down), FR+RL swing, shift, FL+RR swing
        for window, swing_legs in (((0.26, 0.49), [1, 2]), ((0.76, 0.99), [0, 3])):
            sel = (g > window[0]) & (g < window[1])
            assert np.all(ph[sel][:, swing_legs] >= p.duty)
            assert np.all(ph[sel][:, [i for i in range(4) if i not in swing_legs]] < p.duty)
        assert np.all(ph[shifting] < p.duty)


@pytest.mark.parametrize("name", FIVE)
def test_yaw_command_moves_feet_around_the_body_centre(name, feet_fn):
    p = G.gait_params(name)
    w, h = 0.5, 1e-4
    for leg in range(4):
        t_mid = _event_time(0.5 * p.duty, p, leg)  # mid-stance
        f = _feet(feet_fn, [t_mid - h, t_mid, t_mid + h], (0.0, 0.0, w), p)[:, leg]
        r = C.SHOULDER_POS[leg] + C.SHOULDER_ROT[leg] @ f[1]  # foot in the body frame
        v = C.SHOULDER_ROT[leg] @ ((f[2] - f[0]) / (2 * h))
        # a foot fixed on the ground seen from a body turning at w: v = -w x r
        np.testing.assert_allclose(v, [w * r[1], -w * r[0], 0.0], atol=2e-3)


def test_sideways_and_turn_directions_by_hand():
    p = G.gait_params("trot")  # stance 0.4 s; mid-stance feet at x_leg = 2 cm front, 7 cm rear
    step = np.asarray(G.step_vectors(jnp.array([0.0, 0.1, 0.0]), p))
    # sideways left at 0.1 m/s: feet move 4 cm toward body -y; shoulder z is +y front, -y rear
    np.testing.assert_allclose(step, [[0, 0, -0.04], [0, 0, -0.04], [0, 0, 0.04], [0, 0, 0.04]], atol=1e-7)
    step = np.asarray(G.step_vectors(jnp.array([0.0, 0.0, 0.5]), p))
    # turning left at 0.5 rad/s: foot at body r moves by -w x r * 0.4 s = 0.2 (r_y, -r_x).
    # FL r = (0.153 - 0.02, 0.112): body (0.0224, -0.0266) -> shoulder (x = -X, z = +Y)
    # RL r = (-0.153 + 0.07, 0.112): body (0.0224, 0.0166) -> shoulder (x = +X, z = -Y)
    want = [[-0.0224, 0, -0.0266], [0.0224, 0, -0.0266], [0.0224, 0, -0.0166], [-0.0224, 0, -0.0166]]
    np.testing.assert_allclose(step, want, atol=1e-6)
    step = np.asarray(G.step_vectors(jnp.array([-0.3, 0.0, 0.0]), p))  # backward: seed step reversed
    np.testing.assert_allclose(step, [[-0.12, 0, 0], [-0.12, 0, 0], [0.12, 0, 0], [0.12, 0, 0]], atol=1e-6)


def test_discontinuous_trot_mean_speed(feet_fn):
    p = G.gait_params("trot_discontinuous")
    assert float(G.seed_speed(p)) == pytest.approx(0.05)  # seed 003's command: 10 cm per 2 s cycle
    # each foot's stance covers one full cycle's body travel: v T = 0.05 m/s * 2 s = 10 cm
    step = np.asarray(G.step_vectors(jnp.array([0.05, 0.0, 0.0]), p))
    np.testing.assert_allclose(step[:, 0], [0.1, 0.1, -0.1, -0.1], atol=1e-7)
    # seed 003's swing: a 0.5 s cycloid (1 - duty = 0.25 of 2 s)
    assert (1 - p.duty) * p.cycle_s == pytest.approx(0.5)


# --- production path, batching, gradients ----------------------------------------------------


def test_jit_vmap_batch_matches_single_calls(feet_fn):
    p = G.gait_params("walk", swing="cycloid")
    key = jax.random.PRNGKey(0)
    kt, kc = jax.random.split(key)
    t = jax.random.uniform(kt, (64,), maxval=10.0)
    cmd = jax.random.uniform(kc, (64, 3), minval=-0.3, maxval=0.3)
    batch = feet_fn(t, cmd, p)
    assert batch.shape == (64, 4, 3) and batch.dtype == jnp.float32
    assert bool(jnp.all(jnp.isfinite(batch)))
    one = jax.jit(G.foot_targets)  # unbatched: scalar time, (3,) command
    single = np.stack([np.asarray(one(t[i], cmd[i], p)) for i in (0, 17, 63)])
    np.testing.assert_allclose(np.asarray(batch)[[0, 17, 63]], single, atol=1e-5)
    # broadcasting without vmap: (64,) times, one command
    # (float32 times up to 10 s: eager and fused jit round the phase differently by ~1e-6 s)
    direct = one(t, cmd[0], p)
    np.testing.assert_allclose(
        np.asarray(direct), np.asarray(feet_fn(t, jnp.tile(cmd[0], (64, 1)), p)), atol=1e-5
    )


def test_vmap_over_gait_params_and_finite_gradients():
    # the env may scale step length and cycle time per environment: params as a batched pytree
    p = G.gait_params("trot", swing="bezier_apex")
    scale = jnp.array([0.5, 1.0, 1.5])
    batch = jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (3, *np.shape(x))), p)
    batch = batch._replace(step_length_m=p.step_length_m * scale, cycle_s=p.cycle_s / scale)
    fn = jax.jit(jax.vmap(G.foot_targets, in_axes=(None, None, 0)))
    out = fn(jnp.float32(0.1), jnp.array([0.2, 0.0, 0.0]), batch)
    assert out.shape == (3, 4, 3) and bool(jnp.all(jnp.isfinite(out)))
    ref_params = G.gait_params("trot", swing="bezier_apex", step_length_m=0.18, cycle_s=0.8 / 1.5)
    ref = G.foot_targets(0.1, jnp.array([0.2, 0.0, 0.0]), ref_params)
    np.testing.assert_allclose(np.asarray(out[2]), np.asarray(ref), atol=1e-6)

    def loss(cmd, t):
        angles, _ = G.motor_targets(G.foot_targets(t, cmd, p))
        return jnp.sum(angles**2)

    t = jnp.linspace(0.0, 0.8, 33)  # includes phase boundaries
    g = jax.jit(jax.vmap(jax.grad(loss), in_axes=(None, 0)))(jnp.array([0.2, 0.05, 0.3]), t)
    assert bool(jnp.all(jnp.isfinite(g)))


# --- 4. body pose offsets ----------------------------------------------------------------------


def test_body_offset_keeps_world_feet(feet_fn, feet_offset_fn):
    p = G.gait_params("trot")
    t = np.linspace(0.0, 0.8, 9).astype(np.float32)
    cmd = np.tile(np.float32([0.3, 0.0, 0.0]), (9, 1))
    plain = np.asarray(feet_fn(t, cmd, p))
    # raise the body 2 cm: in every shoulder frame the feet are 2 cm lower (y - 0.02)
    up = np.tile(np.float32([0, 0, 0.02, 0, 0, 0]), (9, 1))
    np.testing.assert_allclose(np.asarray(feet_offset_fn(t, cmd, p, up)), plain - [0, 0.02, 0], atol=1e-6)
    # roll and pitch: the world feet stay where the level body put them
    tilt = np.tile(np.float32([0.0, 0.0, 0.01, 0.1, -0.08, 0.0]), (9, 1))
    moved = feet_offset_fn(t, cmd, p, tilt)
    world_tilted = np.asarray(body.shoulder_to_world(jnp.asarray(tilt), moved))
    world_level = np.asarray(body.shoulder_to_world(jnp.zeros((9, 6)), jnp.asarray(plain)))
    np.testing.assert_allclose(world_tilted, world_level, atol=1e-6)
    # pitch by +0.08 rad (R = Ry(pitch)): a world point (X, Z) seen from the body has body
    # z = sin(pitch) X + cos(pitch) Z, and shoulder y is body z: the foot's y changes by
    # sin X + (cos - 1) Z with (X, Z) its body x and z on the level body.
    nose = np.tile(np.float32([0, 0, 0, 0, 0.08, 0]), (9, 1))
    dy = np.asarray(feet_offset_fn(t, cmd, p, nose))[..., 1] - plain[..., 1]
    level_body = _to_body(plain) + C.SHOULDER_POS
    want = math.sin(0.08) * level_body[..., 0] + (math.cos(0.08) - 1) * level_body[..., 2]
    np.testing.assert_allclose(dy, want, atol=1e-6)
    assert np.all(dy[:, FRONT] > 0) and np.all(dy[:, ~FRONT] < 0)  # nose down: front feet rise


# --- 5. motor targets --------------------------------------------------------------------------


def test_motor_targets_published_vector_and_clamping(motor_fn):
    feet = jnp.array(
        [
            [[-0.04, -0.2, 0.0], [0.13, -0.2, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]],
            [[0.3, -0.3, 0.0], [0.0, -0.01, 0.0], [-0.04, -0.2, 0.0], [0.0, -0.2, 0.5]],
        ]
    )
    angles, valid = motor_fn(feet)
    assert angles.shape == (2, 4, 3) and valid.shape == (2, 4)
    # robots.md inverse vectors: (-4, -20) -> (2.8406, 1.7611); (13, -20) -> (1.6217, 0.5686)
    np.testing.assert_allclose(np.asarray(angles[0, 0]), [0.0, 2.8406, 1.7611], atol=1e-4)
    np.testing.assert_allclose(np.asarray(angles[0, 1]), [0.0, 1.6217, 0.5686], atol=1e-4)
    np.testing.assert_array_equal(
        np.asarray(valid), [[True, True, False, False], [False, False, True, False]]
    )
    a = np.asarray(angles)
    assert np.all(np.isfinite(a))
    assert np.all((a >= C.MOTOR_RANGES[:, 0] - 1e-6) & (a <= C.MOTOR_RANGES[:, 1] + 1e-6))
    assert np.all(a[..., 2] - a[..., 1] <= C.TOE_IN_MAX + 1e-6)
    assert int(jnp.sum(~valid)) == 5


@pytest.mark.parametrize("name", (*FIVE, "trot_discontinuous"))
def test_ik_validity_along_default_gaits(name, feet_fn, motor_fn):
    """Every default gait at its seed speed, a full cycle, all legs, all swing shapes.

    Finding: the seed's gallop is NOT reachable at the end of the front legs' stance: the front
    foot reaches x = -4 + 21 = 17 cm at y = -20 cm, 26.25 cm from p1, beyond the p1-p2-foot
    chain's 8 + 18 = 26 cm. The front legs fail where x > sqrt(26^2 - 20^2) = 16.61 cm, i.e. the
    last 1.9 % of stance (phase 0.343 ... 0.35 of duty 0.35) and the first instants of swing.
    Every other gait (and every swing shape) is valid everywhere.
    """
    for shape in S.SWING_SHAPES:
        p = G.gait_params(name, swing=shape)
        t = np.linspace(0.0, p.cycle_s, 4001)
        feet = _feet(feet_fn, t, (float(G.seed_speed(p)), 0.0, 0.0), p)
        angles, valid = motor_fn(jnp.asarray(feet, jnp.float32))
        angles, valid = np.asarray(angles), np.asarray(valid)
        assert np.all(np.isfinite(angles))
        reach = np.linalg.norm(feet, axis=-1)  # z = 0 on these paths
        if name != "gallop":
            assert valid.all(), (name, shape, np.argwhere(~valid)[:5])
        else:
            assert np.any(~valid) and not np.any(~valid[:, ~FRONT]), shape
            assert np.all(reach[~valid] > 0.26 - 1e-6)  # only beyond 8 + 18 cm
            assert np.all(~valid[reach > 0.26 + 1e-6])
            assert np.all(feet[..., 0][~valid] > 0.1661 - 1e-4)
        # where valid, the angles put the foot on the target (FK of seed Algorithm 1)
        fk = np.asarray(fivebar.leg_fk(jnp.asarray(angles)))
        np.testing.assert_allclose(fk[valid], feet[valid], atol=2e-5)
