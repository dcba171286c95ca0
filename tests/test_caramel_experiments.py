"""Caramel's trot planner and seed 003's experiments at a tiny size (one sample, a few seconds)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadson_mjx import seed003 as E
from quadson_mjx.robots.caramel import constants as C
from quadson_mjx.robots.caramel import gait as G

N = 25  # ticks per phase: T 0.5 s at 50 Hz


# --- planner (hand arithmetic) --------------------------------------------------------------------


def test_trot_phases_swing_pairs_and_shift():
    feet = G.trot_feet(4 * N, (0.05, 0.0, 0.0))
    z = feet[..., 2]
    lifted = z > -C.STANCE_HEIGHT + 1e-6
    # phase 0 swings FR + RL, phase 2 FL + RR, phases 1 and 3 keep all four feet down
    assert lifted[:N].any(axis=0).tolist() == [False, True, True, False]
    assert lifted[2 * N : 3 * N].any(axis=0).tolist() == [True, False, False, True]
    assert not lifted[N : 2 * N].any() and not lifted[3 * N :].any()
    assert z.max() == pytest.approx(-C.STANCE_HEIGHT + C.STEP_HEIGHT, abs=2e-3)  # apex near u = 1/2
    # one shift moves every stance foot back by v x 2T = 0.05 m (seed 003: 0.05 m/s)
    np.testing.assert_allclose(feet[2 * N - 1, :, 0] - feet[N - 1, :, 0], -0.05, atol=1e-6)
    # steady state: a swing lands 0.05 m ahead of the nominal foot and lifts 0.05 m behind it
    nominal = G.nominal_feet()
    land = G.trot_feet(8 * N, (0.05, 0.0, 0.0))[7 * N - 1]
    np.testing.assert_allclose(land[[0, 3], 0] - nominal[[0, 3], 0], 0.05, atol=1e-6)


def test_tilt_feet_by_hand():
    # a point h below the centre, body rolled by r: R^T (0, 0, -h) = (0, -h sin r, -h cos r)
    h, r = 0.17, 0.1
    out = np.asarray(G.tilt_feet(np.array([[0.0, 0.0, -h]] * 4), np.array([r, 0.0])))
    np.testing.assert_allclose(out[0], [0.0, -h * math.sin(r), -h * math.cos(r)], atol=1e-7)
    # pitch p: Ry(p)^T (0, 0, -h) = (h sin p, 0, -h cos p)
    out = np.asarray(G.tilt_feet(np.array([[0.0, 0.0, -h]] * 4), np.array([0.0, r])))
    np.testing.assert_allclose(out[0], [h * math.sin(r), 0.0, -h * math.cos(r)], atol=1e-7)


def test_trot_targets_within_reach_and_limits():
    for cmd in [(0.05, 0.0, 0.0), (0.0, 0.0, 0.25)]:
        _, valid = G.joint_targets(G.trot_feet(8 * N, cmd))
        assert np.asarray(valid).all(), cmd


# --- experiments, tiny ------------------------------------------------------------------------------


def test_table1_slow_cycloid_is_tracked():
    # T = 2 s (100 points): slow enough for the P servos; apex and end follow the commanded cycloid.
    r = E.leg_tracking_sample((0.05, 0.03), seed=0, period_s=2.0)
    # tolerance 3 mm on the apex: the leg's weight on a 6.4 N m / rad servo sags it by ~1-2 mm
    assert r["apex_m"] == pytest.approx(0.05, abs=3e-3)
    assert r["final_x_m"] == pytest.approx(0.05, abs=1e-3)
    assert r["final_y_m"] == pytest.approx(0.03, abs=1e-3)
    # last point commanded at 99 ticks = 1.98 s; the cycloid's flat end is within 2 mm a little earlier
    assert r["time_s"] == pytest.approx(1.98, abs=0.1)


def test_table1_fast_cycloid_lags_but_arrives():
    r = E.leg_tracking_sample((0.03, 0.05), seed=1)
    assert 0.48 < r["time_s"] < 1.0  # the 0.5 s cycloid's last point is commanded at 0.48 s
    assert 0.03 < r["apex_m"] < 0.05  # the servos cut the apex short (seed 003: 4.76 of 5 cm)


def test_trot_walks_forward():
    r = E.walk_sample("flat", (0.05, 0.0, 0.0), pid=False, seed=0, max_time_s=4.0)
    assert not r["fell"] and r["invalid_ticks"] == 0
    assert 0.01 < r["velocity_mps"] < 0.06


def test_turn_in_place_turns_the_commanded_way():
    # regression: the body shift once rotated the stance feet the wrong way and the robot turned clockwise
    r = E.walk_sample("flat", (0.0, 0.0, 0.25), pid=False, seed=0, max_time_s=4.0)
    assert r["yaw_rate_radps"] > 0.1


def test_pid_walk_on_rough_is_finite():
    r = E.walk_sample("rough", (0.05, 0.0, 0.0), pid=True, seed=0, max_time_s=3.0)
    assert not r["fell"]
    assert all(math.isfinite(r[k]) for k in ("velocity_mps", "roll_deg", "pitch_deg", "yaw_rate_radps"))


def test_perturbed_model_spreads_kp_only():
    from quadson_mjx.robots.caramel import model as M

    m = M.load_model("fixed")
    p = E.perturbed_model(m, np.random.default_rng(0))
    kp = p.actuator_gainprm[:, 0]
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], C.SERVO_KP, rtol=1e-8)  # original untouched
    np.testing.assert_array_equal(p.actuator_biasprm[:, 1], -kp)  # still a position servo
    assert 0.0 < np.std(kp / C.SERVO_KP) < 0.1 and np.all(np.abs(kp / C.SERVO_KP - 1) < 0.15)
    np.testing.assert_array_equal(p.actuator_forcerange, m.actuator_forcerange)


def test_regression_zero_samples_raise_instead_of_nan_tables():
    # Regression: --samples-1 0 wrote tables of NaN (the mean over no sample); the library raises,
    # the command line refuses it first (tests/test_entry_points.py).
    for table in (E.table_1, E.table_2, E.table_3):
        with pytest.raises(ValueError, match="at least one sample"):
            table(0)
