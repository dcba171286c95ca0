"""Caramel's deploy loop (robots/caramel/gait_np.py, deploy_robots) against the code the simulator runs.

References: Caramel's JAX trot (robots/caramel/gait.py) and serial IK with its clip (serial.py,
gait.joint_targets) in float64, so any difference is a port error; the environment's own motor-target
computation in float32 (start ramp included); the models' `home` keyframes (MJCF) for the home stance.
"""

import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from loop_vs_env import assert_loop_targets_match_env

from quadson_mjx import deploy
from quadson_mjx.config import to_json
from quadson_mjx.deploy_robots import robot_kinematics
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config, env_gait
from quadson_mjx.robots import get_robot
from quadson_mjx.robots.caramel import gait as cgait
from quadson_mjx.robots.caramel import gait_np

GEO = gait_np.geometry()


@pytest.fixture
def float64_traces():
    """Clears JAX's caches before a jax.enable_x64 block (see tests/test_deploy.py's fixture)."""
    jax.clear_caches()


def test_geometry_survives_the_metadata_round_trip():
    d = json.loads(json.dumps(GEO.to_dict()))
    back = gait_np.Geometry.from_dict(d)
    for a, b in zip(back, GEO, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_numpy_trot_equals_the_jax_trot(float64_traces):
    rng = np.random.default_rng(0)
    t = np.round(rng.uniform(-1.0, 9.0, 512) / 0.02) * 0.02  # ticks over several 2 s cycles
    cmd = rng.uniform([-0.02, -0.03, -0.3], [0.08, 0.03, 0.3], (512, 3))
    params = cgait.gait_params()
    with jax.enable_x64(True):
        want = np.asarray(cgait.foot_targets(jnp.asarray(t), jnp.asarray(cmd), params))
    g = gait_np.gait_params({k: np.asarray(v) for k, v in params._asdict().items()})
    got = gait_np.foot_targets(t, cmd, g, GEO)
    assert got.shape == (512, 4, 3) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    one = gait_np.foot_targets(t[5], cmd[5], g, GEO)  # unbatched, as the loop calls it
    np.testing.assert_allclose(one, want[5], rtol=0, atol=1e-12)


def test_numpy_serial_ik_equals_the_jax_ik_with_its_clip(float64_traces):
    rng = np.random.default_rng(1)
    nominal = gait_np.nominal_feet(GEO)
    feet = nominal + rng.uniform(-0.12, 0.12, (4096, 4, 3))  # reachable and unreachable targets
    with jax.enable_x64(True):
        want_q, want_v = (np.asarray(x) for x in cgait.joint_targets(jnp.asarray(feet)))
    got_q, got_v = gait_np.motor_targets(feet, GEO)
    assert 0.2 < got_v.mean() < 0.9  # a real mix of valid and invalid targets
    np.testing.assert_array_equal(got_v, want_v)
    np.testing.assert_allclose(got_q, want_q, rtol=0, atol=1e-12)


@pytest.mark.parametrize("robot", ["quadson", "caramel"])
def test_home_stance_is_the_models_home_keyframe(robot):
    r = robot_kinematics(json.loads(to_json(env_config(robot=robot))))
    spec = get_robot(robot)
    m = spec.load_model("flat")
    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, spec.home_keyframe)
    act = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in r.actuator_names]
    assert r.motor_names == spec.motor_joints and r.actuator_names == spec.actuators
    np.testing.assert_allclose(r.home_motor, m.key_ctrl[key][act], atol=1e-6)
    joints = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in r.motor_names]
    np.testing.assert_allclose(r.motor_limits, m.jnt_range[joints], atol=1e-9)


class _FixedPolicy:
    def __init__(self, cfg, obs_size, action_size):
        self.meta = {"env_config": json.loads(to_json(cfg))}
        self.obs_size, self.action_size = obs_size, action_size

    def __call__(self, obs):
        return np.zeros(self.action_size, np.float32)


def test_caramel_loop_motor_targets_equal_the_env_step_start_ramp_included():
    cfg = env_config(robot="caramel", command_tracking=True)
    env = LocomotionEnv(cfg)
    loop = deploy.DeployLoop(_FixedPolicy(cfg, env.observation_size, env.action_size))
    want = env_gait(cfg)
    for name, value in loop.config.gait._asdict().items():
        np.testing.assert_allclose(value, np.asarray(getattr(want, name)), rtol=1e-7, err_msg=name)
    assert_loop_targets_match_env(env, loop, np.array([0.05, -0.01, 0.2]))
