"""policy_eval: the velocity a true_state policy is fed, and the command's bad inputs."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx import tasks
from quadson_mjx.cli import policy_eval as cli
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.policy_eval import fed_velocity


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
        ["--policy", "results/policy_h100_joystick", "--seconds", "nan"],
        ["--policy", "results/policy_h100_joystick", "--replicas", "0"],
        ["--policy", "results/policy_h100_joystick", "--out", "/proc/version/x.json"],
    ],
)
def test_cli_bad_inputs_one_line_exit_2(argv, capsys, monkeypatch):
    from pathlib import Path

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1, err
