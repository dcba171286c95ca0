"""Caramel in the shared environment: its JAX trot against seed 003's planner, the config a robot
brings, and the environment's motor targets against the serial-leg forward kinematics."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import gait, serial
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import check_env_config, env_config
from quadson_mjx.robots import ROBOT_NAMES, get_robot
from quadson_mjx.robots.caramel import constants as C
from quadson_mjx.robots.caramel import gait as G

COMMANDS = [(0.05, 0.0, 0.0), (0.0, 0.0, 0.25), (0.03, -0.02, 0.2), (-0.02, 0.03, -0.3), (0.0, 0.0, 0.0)]


@pytest.mark.parametrize("command", COMMANDS)
def test_jax_trot_equals_the_planner_after_the_first_phase(command):
    """G.foot_targets (stateless, steady state) against G.trot_feet (seed 003's planner, stateful,
    numpy) tick for tick over three cycles; jitted and batched over time as the env's vmap runs it.
    The first phase differs only where trot_feet lifts pair A from the standing pose (a half step)."""
    p = G.gait_params()
    n = 300
    ref = G.trot_feet(n, command)  # float64
    f = jax.jit(lambda t, c: G.foot_targets(t, c, p))
    out = np.asarray(f(jnp.arange(n, dtype=jnp.float32) * C.TICK_S, jnp.asarray(command, jnp.float32)))
    assert out.shape == (n, 4, 3) and out.dtype == np.float32 and np.all(np.isfinite(out))
    tol = 1e-6  # [m] float32 rounding of 0.2 m-scale positions (measured error in float64: 3e-17)
    np.testing.assert_allclose(out[25:], ref[25:], atol=tol)
    pair_b = np.array([leg in C.TROT_PAIRS[1] for leg in C.LEGS])
    np.testing.assert_allclose(out[:25, pair_b], ref[:25, pair_b], atol=tol)


def test_jax_trot_float32_matches_and_batches_over_commands():
    p = G.gait_params()
    t = jnp.array([0.6, 1.3, 4.02], jnp.float32)
    cmds = jnp.asarray(COMMANDS[:3], jnp.float32)
    out = np.asarray(jax.jit(lambda t, c: G.foot_targets(t, c, p))(t, cmds))
    assert out.shape == (3, 4, 3) and out.dtype == np.float32
    for i, tick in enumerate((30, 65, 201)):
        np.testing.assert_allclose(out[i], G.trot_feet(tick + 1, COMMANDS[i])[tick], atol=2e-6)


def test_phase_table_is_the_planner_swing_schedule():
    """A foot is lifted (above the stance plane) only where the GaitParams phase table says swing."""
    p = G.gait_params()
    t = np.arange(200) * C.TICK_S
    stance = np.asarray(gait.leg_phases(t, p)) < p.duty
    lifted = G.trot_feet(200, (0.05, 0.0, 0.0))[..., 2] > -C.STANCE_HEIGHT + 1e-9
    assert not np.any(lifted & stance)
    assert np.mean(~stance) == pytest.approx(0.25)  # each leg swings one phase of four
    assert float(gait.seed_speed(p)) == pytest.approx(0.05)  # seed 003's forward command


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"swing": "bezier_seed"}, "cycloid"),
        ({"cycle_s": 2.1}, "multiple"),  # T = 0.525 s is not a whole number of 20 ms ticks
        ({"duty": 0.6}, "fixes"),
    ],
)
def test_caramel_gait_params_refuse_what_the_planner_cannot_run(overrides, match):
    with pytest.raises(ValueError, match=match):
        G.gait_params("trot_discontinuous", **overrides)
    with pytest.raises(ValueError, match="unknown gait 'trot'"):
        G.gait_params("trot")


def test_env_config_takes_the_robot_defaults():
    cfg = env_config(robot="caramel", command_tracking=True)
    robot = get_robot("caramel")
    assert cfg.robot == "caramel" and cfg.gait == "trot_discontinuous" and cfg.swing == "cycloid"
    assert cfg.action_scale_m == 0.03 and cfg.reward.height_target == pytest.approx(0.18)
    assert tuple(cfg.command_range.yaw_rate) == (-0.3, 0.3)
    for dotted, value in robot.env_defaults.items():  # every default lands where it says
        node = cfg
        for part in dotted.split("."):
            node = node[part]
        assert (node.to_dict() if hasattr(node, "to_dict") else node) == value
    check_env_config(cfg)
    q = env_config()  # Quadson's are unchanged
    assert q.robot == "quadson" and q.gait == "trot" and q.action_scale_m == 0.05


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"robot": "spot"}, "unknown robot 'spot'"),
        ({"robot": "caramel", "gait": "walk"}, "unknown gait 'walk' for caramel"),
        ({"robot": "caramel", "gait_recipe": True, "gait": "trot_discontinuous"}, "no gait recipe"),
    ],
)
def test_env_config_names_a_bad_robot_or_gait(kwargs, match):
    with pytest.raises(ValueError, match=match):
        env_config(**kwargs)


@pytest.mark.parametrize(
    "override, match",
    [
        ("gait_action=True", "env.gait_action"),
        ("swing=bezier_seed", "env.gait, env.swing, env.gait_scale"),
        ("gait_scale.cycle_s=1.05", "env.gait, env.swing, env.gait_scale"),
        ("robot=spot", "env.robot"),
        ("gait=trot", "env.gait is 'trot'"),
    ],
)
def test_check_env_config_names_the_key(override, match):
    cfg = apply_overrides(env_config(robot="caramel"), [override])
    with pytest.raises(ValueError, match=match):
        check_env_config(cfg)
    with pytest.raises(ValueError, match=match):
        LocomotionEnv(cfg)


@pytest.fixture(scope="module")
def caramel_env():
    env = LocomotionEnv(env_config(robot="caramel", command_tracking=True))
    return env, jax.jit(env.reset), jax.jit(env.step)


def _command_state(env, reset, command):
    state = reset(jax.random.PRNGKey(3))
    info = dict(state.info, command=jnp.asarray(command, jnp.float32))
    return state.replace(info=info)


def test_motor_targets_reach_the_gait_targets_plus_offsets(caramel_env):
    """The ctrl a step sends, through serial_fk in each hip frame (independent of the IK), lands on
    the gait's targets plus action_scale x action (within the model's reach)."""
    env, reset, step = caramel_env
    state = _command_state(env, reset, (0.05, 0.0, 0.1))
    for _ in range(40):  # past the start ramp, into the walk
        state = step(state, jnp.zeros(12))
    action = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, 12), jnp.float32)
    expected = np.asarray(env.gait_targets(state.info)) + 0.03 * np.asarray(action).reshape(4, 3)
    nxt = step(state, action)
    ctrl = np.asarray(nxt.info["last_ctrl"])[np.asarray(env.motor_actuators)].reshape(4, 3)
    feet = np.asarray(serial.serial_fk(jnp.asarray(ctrl), C.LEG, jnp.asarray(C.SIDE, jnp.float32)))
    np.testing.assert_allclose(feet + C.HIP_POS, expected, atol=2e-5)  # float32 IK
    assert float(nxt.metrics["ik_invalid_legs"]) == 0.0
    np.testing.assert_allclose(np.asarray(nxt.info["foot_targets"]), expected, atol=1e-6)


def test_model_ids_and_observation_against_mujoco(caramel_env):
    """Motor positions of the observation are the named joints' qpos (looked up here with MuJoCo C);
    env.observation of a state equals the observation the step returned."""
    env, reset, step = caramel_env
    state = _command_state(env, reset, (0.05, 0.0, 0.0))
    for _ in range(5):
        state = step(state, jnp.full(12, 0.3))
    m = env.mj_model
    qadr = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in C.JOINT_NAMES]
    data = state.pipeline_state
    obs = np.asarray(state.obs)
    assert obs.shape == (32,) and env.observation_size == 32 and env.action_size == 12
    np.testing.assert_allclose(obs[9:21], np.asarray(data.qpos)[qadr], atol=0)
    np.testing.assert_allclose(np.asarray(env.observation(data.qpos, data.qvel, state.info)), obs, atol=1e-6)
    acts = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in C.ACTUATORS]
    assert np.asarray(env.motor_actuators).tolist() == acts


def test_open_loop_trot_walks_forward_without_falling(caramel_env):
    """Zero action: seed 003's trot in MJX walks forward at about what CPU MuJoCo measured for
    Table II (3.3 cm/s flat; models/caramel/README.md), with the base near its 0.18 m home height."""
    env, reset, step = caramel_env
    state = _command_state(env, reset, (0.05, 0.0, 0.0))
    x0 = None
    for i in range(400):  # 8 s = 4 cycles
        state = step(state, jnp.zeros(12))
        assert float(state.done) == 0.0
        if i == 99:
            x0 = float(state.pipeline_state.qpos[0])
    speed = (float(state.pipeline_state.qpos[0]) - x0) / (300 * env.ctrl_dt)
    assert 0.02 < speed < 0.05
    assert abs(float(state.metrics["base_height"]) - 0.18) < 0.02
    assert float(state.metrics["contact_match"]) >= 0.75


def test_registry_names_every_robot_folder():
    for name in ROBOT_NAMES:
        robot = get_robot(name)
        assert robot.name == name and len(robot.motor_joints) == 12 == len(robot.actuators)
        assert robot.default_gait in robot.gait_names
        assert np.asarray(robot.home_feet).shape == (4, 3)


def test_pid_controller_tilts_caramel_feet_with_its_body_kinematics(caramel_env):
    """The rollout's PID controller maps a roll/pitch command through the robot's tilt_feet: for
    Caramel (z-up body frame) a positive pitch of 0.1 rad moves front feet down and rear feet up by
    about hip_x sin(0.1), as G.tilt_feet does (by hand: R^T f)."""
    from quadson_mjx.rollout import pid_action

    env, _, _ = caramel_env
    feet = jnp.asarray(G.nominal_feet(), jnp.float32)
    a = np.asarray(pid_action(feet, jnp.array([0.0, 0.1]), 0.03, env.robot.tilt_feet)).reshape(4, 3)
    dz = a[:, 2] * 0.03
    hx = C.HIP_POS[:, 0]
    expected = np.sin(0.1) * hx + (math.cos(0.1) - 1.0) * -C.STANCE_HEIGHT  # (R^T f)_z - f_z
    np.testing.assert_allclose(dz, np.clip(expected, -0.03, 0.03), atol=1e-6)


@pytest.fixture(scope="module")
def caramel_run(tmp_path_factory):
    """`python train/ppo_mjx.py --robot caramel` with the test preset, through the script's main."""
    from quadson_mjx.cli import train as script

    run_dir = tmp_path_factory.mktemp("caramel") / "run"
    argv = ["--robot", "caramel", "--env-preset", "command", "--preset", "test", "--no-compile-cache"]
    assert script.main([*argv, "--run-dir", str(run_dir)]) == 0
    return script, run_dir


def test_train_script_runs_caramel_and_stores_its_robot(caramel_run):
    import json

    from quadson_mjx import mcap_check

    script, run_dir = caramel_run
    cfg = json.loads((run_dir / "config.json").read_text())
    assert cfg["env"]["robot"] == "caramel" and cfg["env"]["gait"] == "trot_discontinuous"
    report = mcap_check.check(run_dir / "train.mcap")
    assert report.complete and "caramel.xml" in report.attachments
    assert script.main(["--robot", "caramel", "--gait", "walk", "--preset", "test"]) == 2  # Quadson's recipe
    assert script.main(["--resume", str(run_dir), "--robot", "caramel"]) == 2  # the saved config rules


def test_caramel_policy_exports_with_its_motors_and_runs_in_the_deploy_loop(caramel_run, tmp_path):
    from quadson_mjx import deploy, export

    _, run_dir = caramel_run
    out = export.export_run(run_dir, tmp_path / "caramel.npz")
    policy = deploy.load_policy(out)
    assert policy.meta["env_config"]["robot"] == "caramel" and policy.obs_size == 32
    assert policy.meta["motors"][:3] == ["FL_hip_roll_joint", "FL_hip_pitch_joint", "FL_knee_joint"]
    loop = deploy.DeployLoop(policy)  # Caramel's own loop: serial IK, its trot
    assert loop.config.robot.name == "caramel"


def test_caramel_rollout_mcap_of_the_trained_policy(caramel_run, tmp_path):
    """The run's policy (training.load_policy, as eval/rollout.py --run loads it) in a rollout MCAP:
    complete, Caramel's MJCF attached, no closed chain (closure residual 0), and the policy driver of
    the seed 003 experiments gives the step's own motor targets for the same state."""
    from quadson_mjx import mcap_check, training
    from quadson_mjx import rollout as R
    from quadson_mjx import seed003 as E
    from quadson_mjx.recording import record

    _, run_dir = caramel_run
    policy, env_cfg, _, _ = training.load_policy(run_dir)
    env = LocomotionEnv(env_cfg)
    path = tmp_path / "caramel.mcap"
    summary = record(
        path, env, R.policy_controller(policy), jax.random.PRNGKey(0), 2, 4, command=(0.05, 0, 0)
    )
    assert summary["steps"] == 4 and summary["nan_resets"] == 0
    report = mcap_check.check(path)
    assert report.complete and report.attachments == ["caramel.xml"]
    steps = [m for top, _, m in mcap_check.read_messages(path) if top == "/rollout/step"]
    assert all(max(abs(v) for v in m["closure_residual_m"].values()) == 0.0 for m in steps)

    drive = E.policy_driver(run_dir)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    command = np.array([0.05, 0.0, 0.1], np.float32)
    state = state.replace(info=dict(state.info, command=jnp.asarray(command)))
    state = state.replace(
        obs=env.observation(state.pipeline_state.qpos, state.pipeline_state.qvel, state.info)
    )
    action = policy(state.obs, jax.random.PRNGKey(0))[0]
    nxt = jax.jit(env.step)(state, action)
    data = state.pipeline_state
    ctrl, n_invalid = drive(np.asarray(data.qpos), np.asarray(data.qvel), 0, command)
    np.testing.assert_allclose(ctrl, np.asarray(nxt.info["last_ctrl"]), atol=1e-6)
    assert n_invalid == int(nxt.metrics["ik_invalid_legs"])
