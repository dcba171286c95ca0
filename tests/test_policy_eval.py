"""policy_eval: the velocity a true_state policy is fed, and the command's bad inputs."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx import tasks
from quadson_mjx.cli import policy_eval as cli
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.policy_eval import SETTLE_S, fed_velocity, tracking_sums


@pytest.fixture(scope="module")
def true_state_env():
    return LocomotionEnv(tasks.make_task_config("QuadsonJoystickTrueStateFlat"))


def test_fed_velocity_replaces_only_the_velocity_entry(true_state_env):
    env = true_state_env
    spec = env.obs_spec
    obs = jnp.arange(spec.size, dtype=jnp.float32) + 1.0
    echo = lambda o, key: (o, {})  # noqa: E731
    vel, cmd = spec.slices()["base_lin_vel"], spec.slices()["command"]
    assert fed_velocity(echo, env, "true") is echo
    zero = np.asarray(fed_velocity(echo, env, "zero")(obs, None)[0])
    assert not np.any(zero[vel]) and np.array_equal(
        np.delete(zero, np.r_[vel]), np.delete(np.asarray(obs), np.r_[vel])
    )
    from_cmd = np.asarray(fed_velocity(echo, env, "command")(obs, None)[0])
    np.testing.assert_array_equal(from_cmd[vel], [obs[cmd][0], obs[cmd][1], 0.0])  # commanded vx, vy; vz 0
    with pytest.raises(ValueError, match="velocity source"):
        fed_velocity(echo, env, "estimator")


def test_fed_velocity_refuses_a_sensor_policy():
    env = LocomotionEnv(tasks.make_task_config("QuadsonJoystickFlat"))
    with pytest.raises(ValueError, match="observes no base velocity"):
        fed_velocity(lambda o, k: (o, {}), env, "zero")


@pytest.mark.parametrize(
    "argv",
    [
        ["--policy", "results/policy_h100_joystick:estimate"],
        ["--policy", "no/such/run"],
        ["--policy", "results/policy_h100_joystick/config.json"],  # neither a run nor a checkpoint
        ["--policy", "results/policy_h100_joystick", "--seconds", "nan"],
        ["--policy", "results/policy_h100_joystick", "--replicas", "0"],
        ["--policy", "results/policy_h100_joystick", "--out", "/proc/version/x.json"],
        # --env: the evaluation's conditions only (cli.conditions), checked by the env config
        ["--policy", "results/policy_h100_sensors", "--env.obs_history=1"],
        ["--policy", "results/policy_h100_sensors", "--env.reward.weights.termination=-5"],
        ["--policy", "results/policy_h100_sensors", "--env.sensor.imu_tilt=0.01"],
        ["--policy", "results/policy_h100_sensors", "--env.sensor.imu_tilt_rad=nan"],
        ["--policy", "results/policy_h100_sensors", "--imu_tilt_rad=0.01"],
        ["--policy", "results/policy_h100_sensors", "--env.sim_dt=0.003"],  # ctrl_dt 0.02 not a multiple
        ["--policy", "results/policy_h100_sensors", "--env.hfield_foot_contacts=2"],  # 4 or 1
        ["--policy", "results/policy_h100_sensors", "--env.hfield_foot_contacts=1", "--env.impl=warp"],
        ["--policy", "results/policy_h100_sensors", "--env.fivebar_model=heavy"],  # full or light
    ],
)
def test_cli_bad_inputs_one_line_exit_2(argv, capsys, monkeypatch):
    from pathlib import Path

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1, err


def test_cli_env_overrides_reach_every_evaluation(monkeypatch, tmp_path):
    """--env.sensor.imu_tilt_rad=0.01 goes to policy_eval.evaluate for all the policies, and
    evaluate_one's env config is the run's with the terrain and the override, nothing else."""
    import json
    from pathlib import Path

    from quadson_mjx import policy_eval
    from quadson_mjx.training import load_run_config

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    seen = {}

    def fake(runs, commands, terrains, seconds, replicas, seed, overrides):
        seen.update(runs=runs, overrides=overrides)
        return []

    monkeypatch.setattr(policy_eval, "evaluate", fake)
    argv = ["--policy", "results/policy_h100_sensors", "--policy", "results/policy_h100_joystick:zero"]
    argv += ["--env.sensor.imu_tilt_rad=0.01", "--env.sim_dt=0.002", "--out", str(tmp_path / "e.json")]
    assert cli.main(argv) == 0
    assert seen["overrides"] == ["sensor.imu_tilt_rad=0.01", "sim_dt=0.002"] and len(seen["runs"]) == 2
    assert json.loads((tmp_path / "e.json").read_text())["argv"] == argv
    # the config evaluate_one builds from them: only the sensor model differs (the run trained on
    # the stones, the terrain evaluated here)
    run_cfg, _ = load_run_config(Path("results/policy_h100_sensors"))
    cfg = policy_eval.eval_config(run_cfg, "rough", seen["overrides"])
    assert cfg.sensor.imu_tilt_rad == 0.01 and run_cfg.sensor.imu_tilt_rad == pytest.approx(0.035)
    assert cfg.sim_dt == 0.002 and run_cfg.sim_dt == 0.0  # the physics step; the policy's ctrl_dt stays
    assert cfg.ctrl_dt == run_cfg.ctrl_dt
    assert run_cfg.terrain == "rough" and {k for k in cfg.to_dict() if cfg[k] != run_cfg[k]} == {
        "sensor",
        "sim_dt",
    }


def test_a_checkpoint_file_is_evaluated_as_that_checkpoint(monkeypatch, tmp_path, capsys):
    """--policy RUN/checkpoints/step_N.msgpack[:source]: the CLI hands the file on, and
    evaluate_one loads that checkpoint of that run (not the run's newest); a checkpoint whose bytes
    no longer match its checksum is one line and exit 2."""
    import shutil
    from pathlib import Path

    from quadson_mjx import policy_eval

    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    ckpt = next(Path("results/policy_h200_sensors_e16u10_dt2_lr3/checkpoints").glob("step_*.msgpack"))
    seen = {}
    monkeypatch.setattr(policy_eval, "evaluate", lambda runs, *a: seen.update(runs=runs) or [])
    assert cli.main(["--policy", f"{ckpt}:true"]) == 0
    assert seen["runs"] == [(str(ckpt), "true")]

    class Loaded(Exception):
        pass

    def fake_load(run_dir, checkpoint=None, deterministic=True):
        seen.update(run_dir=Path(run_dir), checkpoint=checkpoint)
        raise Loaded

    monkeypatch.setattr(policy_eval, "load_policy", fake_load)
    with pytest.raises(Loaded):
        policy_eval.evaluate_one(str(ckpt), np.zeros((1, 3)), "flat", 2.0)
    assert (
        seen["run_dir"] == Path("results/policy_h200_sensors_e16u10_dt2_lr3") and seen["checkpoint"] == ckpt
    )
    with pytest.raises(Loaded):
        policy_eval.evaluate_one("results/policy_h200_sensors_e16u10_dt2_lr3", np.zeros((1, 3)), "flat", 2.0)
    assert seen["checkpoint"] is None  # a run directory: load_policy takes its newest

    run = tmp_path / "run"
    shutil.copytree(
        "results/policy_h200_sensors_e16u10_dt2_lr3", run, ignore=shutil.ignore_patterns("comparison")
    )
    damaged = run / ckpt.relative_to("results/policy_h200_sensors_e16u10_dt2_lr3")
    data = bytearray(damaged.read_bytes())
    data[100] ^= 0xFF
    damaged.write_bytes(bytes(data))
    capsys.readouterr()
    assert cli.main(["--policy", str(damaged)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1 and "--policy" in err, err


def test_the_five_bar_model_is_an_evaluation_condition(monkeypatch):
    """--env.fivebar_model=light|full evaluates a policy on the other five-bar model (a policy
    trained on the light model, on the robot's full one): the plant changes (link 4 and its hinge
    gone), what the actor and the critic observe and what the policy commands do not, entry by
    entry, and the encoders read the same home stance on both."""
    from pathlib import Path

    from quadson_mjx.cli.conditions import condition_overrides, conditions_config
    from quadson_mjx.training import load_run_config

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    run_cfg, _ = load_run_config(Path("results/policy_h100_sensors"))
    assert run_cfg.fivebar_model == "full" and run_cfg.observation == "sensors"
    cfg = conditions_config(run_cfg, condition_overrides(["--env.fivebar_model=light"]))
    assert {k for k in cfg.to_dict() if cfg[k] != run_cfg[k]} == {"fivebar_model"}
    full, light = LocomotionEnv(run_cfg), LocomotionEnv(cfg)
    assert (full.mj_model.nv, light.mj_model.nv) == (26, 22)
    assert light.obs_spec.names == full.obs_spec.names
    assert light.critic_spec.names == full.critic_spec.names
    assert light.action_spec.names == full.action_spec.names
    # what the encoders read at the home keyframe: the same motor angles on both models
    joints = [n.split(".", 1)[1] for n in full.obs_spec.names if n.startswith("motor_pos.")]
    assert len(joints) == 12

    def home(m):
        return np.asarray([m.key("home").qpos[m.jnt_qposadr[m.joint(j).id]] for j in joints])

    np.testing.assert_allclose(home(light.mj_model), home(full.mj_model), atol=1e-9)


def test_tracking_sums_leave_out_the_first_second_and_the_ending_step():
    """Two environments, 4 control steps of 0.5 s (hand arithmetic): only steps past SETTLE_S (1 s) of
    their episode count, and a step that ends an episode does not."""
    from types import SimpleNamespace

    assert SETTLE_S == 1.0
    episode_step = np.array([[1, 1], [2, 2], [3, 3], [4, 1]])  # env 1 restarted at the last step
    done = np.array([[0, 0], [0, 0], [0, 1], [0, 0]], bool)
    lin_vel = np.zeros((4, 2, 3))
    lin_vel[..., 0] = [[9.0, 9.0], [9.0, 9.0], [0.5, 0.7], [0.1, 9.0]]  # vx
    lin_vel[..., 1] = 0.2  # vy
    ang_vel = np.zeros((4, 2, 3))
    ang_vel[..., 2] = -0.3  # yaw rate
    command = np.broadcast_to(np.array([0.3, 0.0, 0.0]), (4, 2, 3))
    traj = SimpleNamespace(
        episode_step=episode_step, done=done, lin_vel=lin_vel, ang_vel=ang_vel, command=command
    )
    sq, kept = tracking_sums(traj, ctrl_dt=0.5)
    # env 0 keeps steps 3 and 4 (1.5 s, 2 s): vx errors 0.2 and -0.2; env 1 keeps none (its step 3 ends it)
    np.testing.assert_array_equal(kept, [2, 0])
    np.testing.assert_allclose(sq, [[0.08, 0.08, 0.18], [0.0, 0.0, 0.0]], atol=1e-12)
