"""The gait recipes (env_config(gait=G, gait_recipe=True)), the contact-pattern reward and the gait
evaluation (quadson_mjx.gait_eval, eval/gaits.py, train/ppo_mjx.py --gait).

References: hand arithmetic on the gait table (constants.GAITS) and on small hand-made arrays,
MuJoCo C on the same model and state for the feet's ground contact, the numpy deployment gait.
One bound-recipe env with one jitted reset and step is shared by the env tests (module fixtures).
"""

import math
import signal
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import deploy, gait_eval, rewards
from quadson_mjx import rollout as R
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import (
    check_env_config,
    env_config,
    env_gait,
    with_added_keys,
)
from quadson_mjx.env_recipes import GAIT_RECIPES
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import gait, gait_np

ROOT = Path(__file__).resolve().parents[1]
GAIT_FIELDS = ("cycle_s", "duty", "step_height_m", "step_length_m", "swing", "p_t", "p_n", "discontinuous")


def _assert_same_gait(a, b):
    for f in GAIT_FIELDS:
        assert float(getattr(a, f)) == pytest.approx(float(getattr(b, f)), rel=1e-12), f
    # the JAX gait holds its phase offsets in float32 (0.1 is 0.1 + 1.5e-9), the numpy one in float64
    np.testing.assert_allclose(
        np.asarray(a.phase_offset, float), np.asarray(b.phase_offset, float), atol=1e-7
    )


# --- gait_eval on hand-made arrays --------------------------------------------------------------------


def test_tolerant_agreement_lets_a_transition_be_one_step_late():
    stance = np.array([0, 0, 1, 1, 1, 0, 0, 0], bool)
    late1 = np.roll(stance, 1)  # touchdown and lift-off one step late
    late2 = np.roll(stance, 2)
    assert gait_eval.tolerant_agreement(late1, stance, 1).all()
    assert gait_eval.tolerant_agreement(np.roll(stance, -1), stance, 1).all()  # one step early
    ok2 = gait_eval.tolerant_agreement(late2, stance, 1)
    # two late: t=3 (contact up, stance down at 2, 3, 4) and t=6 (contact down, stance up at 5, 6, 7)
    np.testing.assert_array_equal(np.flatnonzero(~ok2), [3, 6])
    assert gait_eval.tolerant_agreement(late2, stance, 2).all()
    # tolerance 0 is the strict comparison, also with trailing (B, 4) axes
    rng = np.random.default_rng(0)
    c, s = rng.random((2, 9, 3, 4)) < 0.5
    np.testing.assert_array_equal(gait_eval.tolerant_agreement(c, s, 0), c == s)
    assert gait_eval.tolerant_agreement(c, s, 1).shape == (9, 3, 4)


def test_first_episode_mask_ends_at_the_first_done():
    done = np.array([[0, 0], [1, 0], [0, 0], [1, 0], [0, 1]], bool)  # (T=5, B=2)
    expect = np.array([[1, 1], [1, 1], [0, 1], [0, 1], [0, 1]], bool)
    np.testing.assert_array_equal(gait_eval.first_episode_mask(done), expect)


def _synthetic_traj():
    """T = 8 steps of 0.1 s, B = 2 envs; settle 0.2 s -> steps 0, 1 are not measured.

    Table: feet 0, 1 in stance at t = 0..3, feet 2, 3 at t = 4..7.
    env 0 walks all 8 steps: foot 0 lifts and foot 2 touches down one step late (t = 4);
        garbage contact (all up) at t = 0, before the settle time. Measured t = 2..7 (6 steps).
    env 1 falls at t = 6 (done, fall) and restarts; its second episode falls again at t = 7 (not
        counted). Foot 3 touches down two steps late (up at t = 4, 5). Measured t = 2..5 (4 steps).
    Garbage values (9 m/s, 90 deg) where nothing is measured.
    """
    T, B = 8, 2
    stance = np.zeros((T, B, 4), bool)
    stance[:4, :, :2] = True
    stance[4:, :, 2:] = True
    contact = stance.copy()
    contact[0, 0] = False
    contact[4, 0, 0] = True
    contact[4, 0, 2] = False
    contact[4:6, 1, 3] = False
    done = np.zeros((T, B), bool)
    done[6, 1] = done[7, 1] = True
    fall = done.copy()
    lin_vel = np.full((T, B, 3), 9.0)
    lin_vel[2:8, 0, 0] = [0.4, 0.6, 0.4, 0.6, 0.5, 0.5]  # mean 0.5
    lin_vel[2:6, 1, 0] = [0.2, 0.4, 0.2, 0.4]  # mean 0.3
    rpy = np.full((T, B, 3), np.radians(90.0))
    rpy[2:8, 0, 0] = np.radians([1, -1, 1, -1, 1, -1])  # std 1 deg
    rpy[2:8, 0, 1] = np.radians(2.0)  # std 0
    rpy[2:6, 1, 0] = np.radians([3, -3, 3, -3])  # std 3 deg
    rpy[2:6, 1, 1] = np.radians([0, 4, 0, 4])  # std 2 deg
    foot_force = np.where(contact, 5.0, 0.5)  # 0.5 N is below the 1 N threshold: "up"
    fields = dict(
        lin_vel=lin_vel, rpy=rpy, foot_force=foot_force, scheduled_stance=stance, done=done, fall=fall
    )
    return R.Trajectory(**{f: fields.get(f) for f in R.Trajectory._fields})


def test_gait_stats_on_a_hand_made_trajectory():
    s = gait_eval.gait_stats(_synthetic_traj(), ctrl_dt=0.1, command_vx=0.5, duty=0.5, settle_s=0.2)
    assert s["episodes"] == 2 and s["falls"] == 1  # env 1's second fall is not its first episode
    assert s["steps_measured"] == 6 + 4  # env 1's fall step itself is not measured
    assert s["command_vx"] == 0.5 and s["duty_table"] == 0.5
    assert s["speed_mean"] == pytest.approx(0.4)  # (0.5 + 0.3) / 2
    assert s["speed_std"] == pytest.approx(0.1)  # std of (0.5, 0.3)
    assert s["speed_ratio"] == pytest.approx(0.8)  # 0.4 / 0.5
    assert s["roll_std_deg"] == pytest.approx(2.0)  # mean of 1 and 3 deg
    assert s["pitch_std_deg"] == pytest.approx(1.0)  # mean of 0 and 2 deg
    # all four feet agree at 5 of env 0's 6 steps (not t = 4) and 2 of env 1's 4 (not t = 4, 5)
    assert s["pattern_match"] == pytest.approx(7 / 10)
    # +-1 step: env 0's t = 4 passes, env 1's t = 4 passes (stance at t = 3 was up), t = 5 does not
    assert s["pattern_match_1step"] == pytest.approx(9 / 10)
    # 40 (step, foot) pairs, 4 disagree: env 0 t = 4 feet 0, 2; env 1 t = 4, 5 foot 3
    assert s["foot_agreement"] == pytest.approx(36 / 40)
    # feet down over the 10 measured steps: foot 0: 3 + 2, foot 1: 2 + 2, foot 2: 3 + 2, foot 3: 4 + 0
    np.testing.assert_allclose(s["duty_measured"], [0.5, 0.4, 0.5, 0.4])


def test_gait_stats_force_threshold_decides_contact():
    # with a threshold above 5 N no foot is ever down: agreement only where the table says swing
    s = gait_eval.gait_stats(_synthetic_traj(), 0.1, 0.5, 0.5, settle_s=0.2, force_threshold_n=10.0)
    np.testing.assert_allclose(s["duty_measured"], [0, 0, 0, 0])
    assert s["pattern_match"] == 0.0 and s["foot_agreement"] == pytest.approx(0.5)


# --- config: the scaled gait, the recipes, older configs -------------------------------------------------


def test_env_gait_is_the_table_gait_with_scaled_values():
    cfg = apply_overrides(
        env_config(), ["gait_scale.cycle_s=1.5", "gait_scale.step_length_m=0.5", "gait_scale.step_height_m=2"]
    )
    check_env_config(cfg)
    # trot: cycle 0.8 s, step 12 cm, height 5 cm (constants.GAITS)
    expect = gait.gait_params("trot", swing=cfg.swing, cycle_s=1.2, step_length_m=0.06, step_height_m=0.10)
    _assert_same_gait(env_gait(cfg), expect)
    # speed = length / (duty cycle): 0.06 / (0.5 * 1.2) = 0.1 m/s (unscaled: 0.12 / 0.4 = 0.3)
    assert float(gait.seed_speed(env_gait(cfg))) == pytest.approx(0.1)
    assert float(gait.seed_speed(env_gait(env_config()))) == pytest.approx(0.3)


@pytest.mark.parametrize(
    "name, recipe, speed",
    [
        ("bound", False, 0.16 / (0.4 * 0.6)),  # 0.667 m/s: the seed's bound
        ("bound", True, 0.75 * 0.16 / (0.4 * 0.6)),  # 0.5 m/s
        ("gallop", False, 0.21 / (0.35 * 0.5)),  # 1.2 m/s
        ("gallop", True, 0.5 * 0.21 / (0.35 * 0.5)),  # 0.6 m/s
    ],
)
def test_seed_speed_scales_as_length_over_cycle(name, recipe, speed):
    assert float(gait.seed_speed(env_gait(env_config(gait=name, gait_recipe=recipe)))) == pytest.approx(speed)


def test_doubling_the_cycle_halves_the_speed():
    cfg = apply_overrides(env_config(gait="bound"), ["gait_scale.cycle_s=2.0"])
    assert float(gait.seed_speed(env_gait(cfg))) == pytest.approx(0.16 / (0.4 * 1.2))


@pytest.mark.parametrize("name", sorted(GAIT_RECIPES))
def test_every_recipe_builds_and_passes_the_checks(name):
    cfg = env_config(gait=name, gait_recipe=True)
    check_env_config(cfg)
    assert cfg.gait == name and cfg.randomize is True
    assert cfg.reward.target_gait_speed is True
    assert cfg.reward.weights.contact_phase == GAIT_RECIPES[name]["contact_phase"] > 0
    assert cfg.gait_scale.step_length_m == GAIT_RECIPES[name]["step_length_m"]
    assert cfg.reward.forward_sigma == GAIT_RECIPES[name]["forward_sigma"]
    assert cfg.gait_scale.cycle_s == cfg.gait_scale.step_height_m == 1.0


@pytest.mark.parametrize(
    "key, value",
    [("cycle_s", 0.0), ("step_length_m", -0.5), ("step_height_m", math.nan), ("cycle_s", math.inf)],
)
def test_gait_scale_out_of_range_names_the_key(key, value):
    cfg = env_config(gait="bound", gait_recipe=True)
    cfg.gait_scale[key] = (
        value  # as a hand-edited config.json would have it (NaN does not parse as an override)
    )
    with pytest.raises(ValueError, match=rf"env\.gait_scale\.{key}"):
        check_env_config(cfg)


def test_recipe_of_a_gait_without_one_names_the_recipes():
    with pytest.raises(ValueError, match="trot_discontinuous") as e:
        env_config(gait="trot_discontinuous", gait_recipe=True)
    assert all(name in str(e.value) for name in GAIT_RECIPES)


def test_older_config_gets_the_new_keys_with_the_old_behaviour():
    old = env_config().to_dict()
    del old["gait_scale"]
    del old["reward"]["target_gait_speed"]
    del old["reward"]["weights"]["contact_phase"]
    cfg = with_added_keys(old)
    assert dict(cfg.gait_scale) == {"cycle_s": 1.0, "step_length_m": 1.0, "step_height_m": 1.0}
    assert cfg.reward.target_gait_speed is False
    assert cfg.reward.weights.contact_phase == 0.0
    assert cfg.to_dict() == env_config().to_dict()
    check_env_config(cfg)
    _assert_same_gait(env_gait(cfg), gait.gait_params("trot", swing=cfg.swing))


def test_default_config_is_unchanged_by_the_recipes():
    cfg = env_config()
    assert dict(cfg.gait_scale) == {"cycle_s": 1.0, "step_length_m": 1.0, "step_height_m": 1.0}
    assert cfg.reward.weights.contact_phase == 0.0 and cfg.reward.target_gait_speed is False
    assert cfg.randomize is False and cfg.gait == "trot"
    _assert_same_gait(env_gait(cfg), gait.gait_params("trot", swing=cfg.swing))


# --- the env: contact from MJX against MuJoCo C, the phase table, the rewards -------------------------

BOUND_SPEED = 0.5  # 0.75 * 16 cm / (0.4 * 0.6 s)
BOUND_SIGMA = 0.25


@pytest.fixture(scope="module")
def env():
    """The bound recipe with the training physics; reward.forward_target moved off the bound's 0.5
    m/s so that the forward reward tells the gait's speed from forward_target."""
    cfg = env_config(gait="bound", gait_recipe=True, base_terrain_contact=False, joint_limits=False)
    return LocomotionEnv(apply_overrides(cfg, ["reward.forward_target=0.3"]))


@pytest.fixture(scope="module")
def fns(env):
    return jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def states(env, fns):
    """The states after 1..40 zero-action steps of the bound recipe (0.8 s: ramp, then the gait)."""
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    out = []
    for _ in range(40):
        s = step(s, jnp.zeros(env.action_size))
        out.append(s)
    return out


KNIFE_EDGE_M = 1e-6  # MJX float32 and MuJoCo C float64 distances differ by < 1e-7 m (measured 8e-8)


def _contact_c(env, state):
    """MuJoCo C's contacts for the stepped MJX state -> (4,) bool (LEGS order: the foot collision
    geom touches with dist < 0), (4,) dist [m] (+inf: no contact within the zero margin).

    mjx.step, like mj_step, computes contacts before it integrates: the contacts in the stepped data
    belong to the start of the env step's last physics substep. With the Euler integrator qpos_end =
    qpos_start (+) qvel_end dt exactly, so integrating back by one timestep gives that state."""
    m = env.mj_model
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    d = mujoco.MjData(m)
    qpos = np.asarray(state.pipeline_state.qpos, np.float64).copy()
    mujoco.mj_integratePos(m, qpos, np.asarray(state.pipeline_state.qvel, np.float64), -m.opt.timestep)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    feet = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{leg}_foot_collision") for leg in C.LEGS]
    dist = np.full(4, np.inf)
    for c in d.contact[: d.ncon]:
        for i, g in enumerate(feet):
            if g in (c.geom1, c.geom2):
                dist[i] = min(dist[i], c.dist)
    return dist < 0, dist


def _stance_by_hand(progress) -> np.ndarray:
    """Bound: FL, FR at phase offset 0, RL, RR at 0.5; stance while phase < duty 0.4."""
    phase = np.mod(float(progress) + np.array([0.0, 0.0, 0.5, 0.5]), 1.0)
    return phase < 0.4


def test_env_runs_the_scaled_gait(env):
    _assert_same_gait(env.gait_params, env_gait(env.config))
    assert float(env.gait_params.step_length_m) == pytest.approx(0.75 * 0.16)


def test_foot_contact_equals_mujoco_c(env, states):
    foot_contact = jax.jit(env.foot_contact)
    lifted = False
    for t, s in enumerate(states):
        got = np.asarray(foot_contact(s.pipeline_state))
        assert got.shape == (4,) and got.dtype == bool
        down, dist = _contact_c(env, s)
        sure = np.abs(dist) > KNIFE_EDGE_M
        np.testing.assert_array_equal(got[sure], down[sure], err_msg=f"step {t + 1}")
        if t < 8:  # start ramp: all four feet on the ground (the rear feet lift from step 9 on)
            assert got.all() and sure.all()
        lifted |= not got.all()
    assert lifted  # the bound lifts feet within 0.8 s: the comparison saw both outcomes


def test_scheduled_stance_is_the_bound_phase_table(env):
    got = jax.jit(env.scheduled_stance)(jnp.array([0.1, 0.6, 0.35, 0.45]))
    assert got.shape == (4, 4) and got.dtype == jnp.bool_
    np.testing.assert_array_equal(got[0], [True, True, False, False])  # fronts stance, rears swing
    np.testing.assert_array_equal(got[1], [False, False, True, True])  # the reverse
    np.testing.assert_array_equal(got[2], [True, True, False, False])  # 0.35 < 0.4
    np.testing.assert_array_equal(got[3], [False, False, False, False])  # 0.45, 0.95: all in swing
    for p in np.linspace(0.0, 0.99, 23):
        np.testing.assert_array_equal(env.scheduled_stance(jnp.asarray(p)), _stance_by_hand(p))


def test_contact_reward_and_metric_by_hand(env, states):
    checked = 0
    for s in states[6:40:3]:
        contact, dist = _contact_c(env, s)
        if np.any(np.abs(dist) < KNIFE_EDGE_M):
            continue
        stance = _stance_by_hand(s.info["gait_progress"])
        match = np.mean(contact == stance)
        assert float(s.metrics["reward/contact_phase"]) == pytest.approx(
            GAIT_RECIPES["bound"]["contact_phase"] * match
        )
        assert float(s.metrics["contact_match"]) == pytest.approx(match)
        checked += 1
    assert checked >= 10


def test_forward_reward_targets_the_gait_speed(env, states):
    assert env.config.reward.forward_sigma == BOUND_SIGMA
    for s in states[5:40:7]:
        qpos = np.asarray(s.pipeline_state.qpos, np.float64)
        qvel = np.asarray(s.pipeline_state.qvel, np.float64)
        conj = np.zeros(4)
        mujoco.mju_negQuat(conj, qpos[3:7])
        v_body = np.zeros(3)
        mujoco.mju_rotVecQuat(v_body, qvel[0:3], conj)  # free joint: world-frame linear velocity
        expect = math.exp(-((v_body[0] - BOUND_SPEED) ** 2) / (2 * BOUND_SIGMA**2))  # weight 1
        assert float(s.metrics["reward/forward_velocity_exp"]) == pytest.approx(expect, rel=1e-4, abs=1e-6)


def test_footfall_lines_by_hand():
    # 2 steps, FL down in both, FR lifts at the second step; the table: FL stance, FR swing then stance
    contact = np.array([[1, 1, 0, 0], [1, 0, 0, 1]], bool)
    stance = np.array([[1, 0, 0, 0], [1, 1, 0, 1]], bool)
    lines = gait_eval.footfall_lines(contact, stance, ("FL", "FR", "RL", "RR"))
    assert lines == [
        "FL table ##",
        "FL feet  ##",
        "FR table .#",
        "FR feet  #.",
        "RL table ..",
        "RL feet  ..",
        "RR table .#",
        "RR feet  .#",
    ]


def test_evaluate_one_tiny_case(env):
    s = gait_eval.evaluate(
        env,
        R.gait_only(env),
        jax.random.PRNGKey(1),
        n_envs=2,
        seconds=1.2,
        settle_s=0.6,
        footfall_s=(0.6, 1.0),
    )
    # 0.4 s of 20 ms steps: 20 characters after the 9-character label, 8 lines; none if env 0 fell
    assert s["footfalls"] == [] or (
        len(s["footfalls"]) == 8 and all(len(x) == 9 + 20 for x in s["footfalls"])
    )
    assert s["episodes"] == 2 and 0 <= s["falls"] <= 2
    assert s["command_vx"] == pytest.approx(BOUND_SPEED) and s["duty_table"] == pytest.approx(0.4)
    assert 0.0 <= s["pattern_match"] <= s["pattern_match_1step"] <= 1.0
    assert s["pattern_match"] <= s["foot_agreement"] <= 1.0
    assert math.isfinite(s["speed_mean"]) and math.isfinite(s["speed_std"])
    assert len(s["duty_measured"]) == 4 and all(0.0 <= d <= 1.0 for d in s["duty_measured"])
    assert s["steps_measured"] <= 2 * 30  # at most 0.6 s of 20 ms steps per env


# --- deploy: the numpy gait with the scale ---------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(GAIT_RECIPES))
def test_numpy_gait_scale_equals_env_gait(name):
    cfg = apply_overrides(env_config(gait=name, gait_recipe=True), ["gait_scale.cycle_s=1.25"])
    _assert_same_gait(gait_np.gait_params(name, swing=cfg.swing, scale=cfg.gait_scale), env_gait(cfg))
    loop = deploy.LoopConfig.from_env_config(cfg.to_dict())
    _assert_same_gait(loop.gait, env_gait(cfg))


def test_numpy_gait_rejects_an_unknown_scale_key():
    with pytest.raises(ValueError, match="duty"):
        gait_np.gait_params("bound", scale={"duty": 0.5})


# --- command lines ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gaits_cli():
    from quadson_mjx.cli import gaits

    return gaits


@pytest.mark.parametrize(
    "args, words",
    [
        (["--gaits", "bound,hop"], ["hop"]),
        (["--gaits", "trot_discontinuous"], ["trot_discontinuous"]),
        (["--gaits", ","], ["--gaits"]),
        (["--envs", "0"], ["--envs"]),
        (["--seconds", "1", "--settle-s", "1"], ["--seconds > --settle-s"]),
        (["--settle-s", "-1"], ["--settle-s", ">= 0"]),
        (["--seconds", "nan"], ["--seconds nan", "finite"]),  # regression: nan / inf episodes
        (["--seconds", "inf"], ["--seconds inf", "finite"]),
        (["--seconds", "1e12"], ["--seconds", "<= 3600"]),
        (["--settle-s", "nan"], ["--settle-s nan", "finite"]),
        (["--envs", "x"], ["--envs", "invalid int"]),
        (["--json", "{tmp}/no/such/folder/g.json"], ["--json", "does not exist"]),
        (["--json", "{tmp}/old.json/g.json"], ["--json", "not a folder"]),
        (["--runs", "{tmp}/missing"], ["missing", "not a directory"]),
        (["--json", "{tmp}/old.json"], ["old.json", "exists"]),
        (["--controllers", "gait,mpc"], ["--controllers"]),
        (["--footfalls", "2", "1"], ["--footfalls"]),
        (["--seconds", "3", "--footfalls", "1", "4"], ["--footfalls"]),
        (["--randomization", "mass=1,1"], ["--randomization", "env.randomization.mass", "mass_scale"]),
        (["--randomization", "mass_scale=1.2"], ["--randomization", "takes 2 values"]),
        (["--randomization", "friction=1.2,0.5"], ["--randomization", "env.randomization.friction"]),
        (["--randomization", "mass_scale"], ["--randomization"]),
        (["--run", "hop={tmp}"], ["--run hop=", "GAIT=DIR"]),
        (["--run", "bound"], ["--run bound", "GAIT=DIR"]),
        (["--run", "bound={tmp}/missing"], ["--run bound=", "missing is not a directory"]),
        (["--run", "bound={tmp}", "--run", "bound={tmp}"], ["--run", "once per gait"]),
        (["--physics", "timestep=0.002"], ["--physics timestep=0.002", "sim_dt, solver_iterations"]),
        (["--physics", "sim_dt=0.003"], ["--physics", "whole multiple", "0.003 s (env.sim_dt)"]),
        (["--physics", "solver_iterations=0"], ["--physics", "env.solver_iterations"]),
    ],
)
def test_gaits_cli_usage_errors_exit_2(gaits_cli, capsys, tmp_path, args, words):
    # One line on stderr and exit status 2, before any episode runs; nothing written.
    (tmp_path / "old.json").write_text("{}")
    argv = [a.format(tmp=tmp_path) for a in args]
    assert gaits_cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err
    assert all(w in err for w in words), err
    assert (tmp_path / "old.json").read_text() == "{}"
    assert [p.name for p in tmp_path.iterdir()] == ["old.json"]


def test_regression_gaits_cli_run_of_another_gait_is_refused_before_running(gaits_cli, capsys, tmp_path):
    # RUNS/<gait> that is not a run, is damaged or trained another gait: one line before any
    # episode (it used to fail with a traceback after the earlier gaits had run).
    import shutil

    run = tmp_path / "bound"
    run.mkdir()
    cases = [
        (None, "no config.json"),
        ("{not json", "not valid JSON"),
        (
            Path(__file__).parent / "data" / "legacy_run" / "config.json",
            "trained the gait 'trot', not 'bound'",
        ),
    ]
    for config, words in cases:
        if isinstance(config, str):
            (run / "config.json").write_text(config)
        elif config is not None:
            shutil.copy(config, run / "config.json")
        assert gaits_cli.main(["--gaits", "bound", "--runs", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and words in err, err
    # --run names the bound's run directly, in place of RUNS/bound (here the trot's config)
    other = tmp_path / "elsewhere"
    shutil.copytree(run, other)
    assert gaits_cli.main(["--gaits", "bound", "--runs", "results/gaits", "--run", f"bound={other}"]) == 2
    assert "--run: " in (err := capsys.readouterr().err) and "elsewhere trained the gait 'trot'" in err


@pytest.fixture(scope="module")
def ppo_cli():
    from quadson_mjx.cli import train

    return train


def test_ppo_unknown_gait_exits_2(ppo_cli, capsys):
    # One line on stderr and exit status 2 through main, before anything trains.
    assert ppo_cli.main(["--gait", "hop"]) == 2
    err = capsys.readouterr().err
    assert "--gait" in err and "hop" in err and len(err.strip().splitlines()) == 1, err


def test_ppo_gait_trains_the_recipe(ppo_cli, monkeypatch, tmp_path):
    seen = {}

    class Stop(Exception):
        pass

    def fake_train(env_cfg, ppo_cfg, run_dir, resume, init_from=None, stop=None, on_eval=None, record=None):
        seen.update(env_cfg=env_cfg, run_dir=run_dir, resume=resume, init_from=init_from)
        raise Stop

    monkeypatch.setattr(ppo_cli.training, "train", fake_train)
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(Stop):
            ppo_cli.main(["--gait", "bound", "--no-compile-cache", "--run-dir", str(tmp_path / "run")])
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    cfg = seen["env_cfg"]
    assert seen["init_from"] is None and seen["resume"] is False
    assert cfg.gait == "bound" and cfg.randomize is True
    assert cfg.gait_scale.step_length_m == GAIT_RECIPES["bound"]["step_length_m"]
    assert cfg.reward.target_gait_speed is True
    assert cfg.reward.weights.contact_phase == GAIT_RECIPES["bound"]["contact_phase"]
    assert cfg.base_terrain_contact is False and cfg.joint_limits is False  # the training physics
    assert float(gait.seed_speed(env_gait(cfg))) == pytest.approx(BOUND_SPEED)


@pytest.mark.parametrize(
    "extra, named",
    [
        (["--gait", "bound"], "--gait"),
        (["--terrain", "rough"], "--terrain"),
        (["--env-preset", "robust"], "--env-preset"),
        (["--gait-action"], "--gait-action"),
        (["--env.gait=pace"], "--env.gait=pace"),
    ],
)
def test_ppo_resume_refuses_config_options_regression(ppo_cli, monkeypatch, capsys, tmp_path, extra, named):
    # Regression: `--resume RUN --gait G` ignored --gait silently (the run's saved configs rule)
    def no_train(*args, **kwargs):
        raise AssertionError("nothing may train")

    monkeypatch.setattr(ppo_cli.training, "train", no_train)
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        rc = ppo_cli.main(["--resume", str(tmp_path / "run"), "--no-compile-cache", *extra])
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    err = capsys.readouterr().err
    assert rc == 2 and named in err and "--resume" in err


def test_contact_pattern_reward_is_the_evaluations_one_step_match():
    # the reward (JAX, per step, jitted over a batch) against the evaluation's numpy definition
    # (gait_eval.tolerant_agreement over a whole trajectory) on random footfalls and tables
    rng = np.random.default_rng(3)
    contact = rng.random((200, 4)) < 0.5
    stance = rng.random((200, 4)) < 0.5
    want = gait_eval.tolerant_agreement(contact, stance, 1).all(axis=-1)[1:-1]
    near = np.stack([stance[:-2], stance[1:-1], stance[2:]], axis=1)  # (198, 3, 4)
    got = jax.jit(jax.vmap(rewards.contact_pattern))(jnp.asarray(contact[1:-1]), jnp.asarray(near))
    assert got.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(got), want.astype(np.float32))
    assert 0 < want.sum() < want.size  # both outcomes occur
    # by hand: one foot down in swing with the table in swing all around -> 0
    lone = jnp.array([True, False, False, False])
    assert float(rewards.contact_pattern(lone, jnp.zeros((3, 4), bool))) == 0.0


def test_swing_touch_counts_the_feet_that_miss_the_pattern_by_touching():
    # the reward (jitted over a batch) against the evaluation's per-foot match: a foot on the ground
    # that misses the table within one step is a touch in swing; a lifted foot that misses is not
    rng = np.random.default_rng(4)
    contact = rng.random((300, 4)) < 0.5
    stance = rng.random((300, 4)) < 0.6
    agree = gait_eval.tolerant_agreement(contact, stance, 1)[1:-1]
    want = (contact[1:-1] & ~agree).sum(axis=-1).astype(np.float32)
    near = np.stack([stance[:-2], stance[1:-1], stance[2:]], axis=1)
    got = jax.jit(jax.vmap(rewards.swing_touch))(jnp.asarray(contact[1:-1]), jnp.asarray(near))
    np.testing.assert_array_equal(np.asarray(got), want)
    assert set(np.unique(want)) >= {0.0, 1.0, 2.0}  # none, one and two touches occur
    lifted_misses = (~contact[1:-1] & ~agree).sum()
    assert lifted_misses > 0  # a foot in the air during stance misses the pattern but costs nothing here
    # by hand: the table in swing all around, FL and RR down -> 2; FL's stance one step later -> 1
    feet = jnp.array([True, False, False, True])
    assert float(rewards.swing_touch(feet, jnp.zeros((3, 4), bool))) == 2.0
    assert float(rewards.swing_touch(feet, jnp.zeros((3, 4), bool).at[2, 0].set(True))) == 1.0


def test_stance_lift_counts_the_feet_that_miss_the_pattern_by_lifting():
    # the mirror of swing_touch against the evaluation's per-foot match: a lifted foot that misses
    # the table within one step is a lift in stance; together the two terms count every miss
    rng = np.random.default_rng(5)
    contact = rng.random((300, 4)) < 0.5
    stance = rng.random((300, 4)) < 0.6
    agree = gait_eval.tolerant_agreement(contact, stance, 1)[1:-1]
    want = (~contact[1:-1] & ~agree).sum(axis=-1).astype(np.float32)
    near = np.stack([stance[:-2], stance[1:-1], stance[2:]], axis=1)
    c, n = jnp.asarray(contact[1:-1]), jnp.asarray(near)
    got = jax.jit(jax.vmap(rewards.stance_lift))(c, n)
    np.testing.assert_array_equal(np.asarray(got), want)
    assert set(np.unique(want)) >= {0.0, 1.0, 2.0}
    both = np.asarray(got) + np.asarray(jax.vmap(rewards.swing_touch)(c, n))
    np.testing.assert_array_equal(both, (~agree).sum(axis=-1))
    # by hand: the table in stance all around, FL and RR up -> 2; FL's swing one step before -> 1
    feet = jnp.array([False, True, True, False])
    assert float(rewards.stance_lift(feet, jnp.ones((3, 4), bool))) == 2.0
    assert float(rewards.stance_lift(feet, jnp.ones((3, 4), bool).at[0, 0].set(False))) == 1.0


def _weighted_reward(cfg, rpy):
    """The weighted reward of one step (as env.step sums it) at base attitude rpy, the rest fixed."""
    terms = rewards.locomotion_terms(
        cfg.reward,
        0.3,
        lin_vel=jnp.array([0.25, 0.02, 0.01]),
        ang_vel=jnp.array([0.1, -0.2, 0.3]),
        rpy=jnp.asarray(rpy),
        height=0.2,
        action=jnp.zeros(12),
        last_action=jnp.zeros(12),
        actuator_force=jnp.ones(12),
        command=jnp.zeros(3),
        contact=jnp.array([True, False, False, True]),
        stance=jnp.array([True, False, False, True]),
        stance_near=jnp.tile(jnp.array([True, False, False, True]), (3, 1)),
        fallen=False,
    )
    return float(sum(cfg.reward.weights[k] * v for k, v in terms.items()))


@pytest.mark.parametrize("name", sorted(GAIT_RECIPES))
def test_recipe_reward_does_not_see_the_heading_its_actor_cannot(name):
    # the recipe's actor has the IMU (no magnetometer): a reward on absolute yaw is one it cannot
    # steer by (measured: the sensor-only trot policy's heading wandered and falls paid)
    cfg = env_config(gait=name, gait_recipe=True)
    assert cfg.observation == "sensors"
    r0 = _weighted_reward(cfg, [0.05, -0.03, 0.0])
    assert _weighted_reward(cfg, [0.05, -0.03, 1.5]) == pytest.approx(r0, abs=1e-6)
    # roll and pitch are still paid: 40 * 0.1^2 with weight -1
    assert _weighted_reward(cfg, [0.15, -0.03, 0.0]) == pytest.approx(r0 - 40 * (0.15**2 - 0.05**2), rel=1e-5)
    # the seed's true-state configuration pays yaw^2 (5 x 1.5^2 with weight -1): the test can tell
    seed = env_config(gait=name)
    assert _weighted_reward(seed, [0.05, -0.03, 1.5]) == pytest.approx(
        _weighted_reward(seed, [0.05, -0.03, 0.0]) - 5 * 1.5**2, rel=1e-5
    )
