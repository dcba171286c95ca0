"""The sensor model of the "sensors" observation against hand-computed values, and the environment's
sensor-only actor and privileged critic as brax PPO trains them (jitted env, network input sizes)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import pytest

from quadson_mjx import obs_spec, sensors, tasks
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.training import ppo_config
from quadson_mjx.training.networks import params_template

STEP = 2 * math.pi / 4096  # a 12-bit encoder's resolution [rad]


def _cfg(**changes):
    d = env_config(command_tracking=True).to_dict()
    d.update(changes)
    return ml_collections.ConfigDict(d)


@pytest.mark.parametrize("angle", [0.0, 0.3, -0.7])
def test_gravity_direction_of_a_tilt_by_hand(angle):
    # R = Rx(roll): gravity in the body frame is R^T (0, 0, -1) = (0, -sin r, -cos r);
    # R = Ry(pitch): (sin p, 0, -cos p)
    quats = sensors.tilt_quat(jnp.asarray([[angle, 0.0], [0.0, angle]]))
    got = np.asarray(jax.jit(jax.vmap(sensors.gravity_direction))(quats))
    s, c = math.sin(angle), math.cos(angle)
    np.testing.assert_allclose(got, [[0, -s, -c], [s, 0, -c]], atol=1e-6)
    assert got.dtype == np.float32


def test_quantize_by_hand():
    x = jnp.asarray([0.1, -0.1, 0.0, 3 * STEP + 0.4 * STEP])
    # 0.1 / STEP = 65.19 -> 65 steps; 3.4 steps -> 3
    np.testing.assert_allclose(
        np.asarray(sensors.quantize(x, STEP)), [65 * STEP, -65 * STEP, 0, 3 * STEP], atol=1e-7
    )
    assert sensors.quantize(x, 0.0) is x


def test_read_sensors_tilt_and_bias_by_hand():
    # an IMU mounted with roll r, a base at rest and level turning at 1 rad/s about z, a gyro bias b:
    # gyro = Rx(r)^T (0, 0, 1) + b = (0, sin r, cos r) + b; gravity = (0, -sin r, -cos r)
    cfg = _cfg()
    r, bias = 0.035, jnp.asarray([0.01, -0.02, 0.03])
    qpos = jnp.zeros(7).at[3].set(1.0).at[2].set(0.2)
    qvel = jnp.zeros(6).at[5].set(1.0)
    errors = {"imu_tilt": jnp.asarray([r, 0.0]), "gyro_bias": bias}
    motors = jnp.asarray([0.1] * 12)
    out = jax.jit(lambda q, v, m: sensors.read_sensors(cfg, q, v, m, errors, jax.random.PRNGKey(0)))(
        qpos, qvel, motors
    )
    np.testing.assert_allclose(
        out["gyro"], np.array([0, math.sin(r), math.cos(r)]) + np.asarray(bias), atol=1e-6
    )
    np.testing.assert_allclose(out["gravity"], [0, -math.sin(r), -math.cos(r)], atol=1e-6)
    np.testing.assert_allclose(out["motor_pos"], [65 * STEP] * 12, atol=1e-7)


def test_episode_sensor_errors_within_their_ranges():
    cfg = _cfg(randomize=True)
    draw = jax.jit(jax.vmap(lambda k: sensors.episode_sensor_errors(cfg, 0.004, k)))
    e = draw(jax.random.split(jax.random.PRNGKey(3), 512))
    assert np.all(np.abs(e["gyro_bias"]) <= cfg.sensor.gyro_bias_rps)
    assert np.all(np.abs(e["imu_tilt"]) <= cfg.sensor.imu_tilt_rad)
    # latency U(0, 20 ms) in 4 ms physics steps: 0..5, every value drawn
    assert set(np.unique(e["sensor_latency_steps"]).tolist()) == {0, 1, 2, 3, 4, 5}
    still = sensors.episode_sensor_errors(_cfg(randomize=False), 0.004, jax.random.PRNGKey(0))
    assert not np.any(still["gyro_bias"]) and int(still["sensor_latency_steps"]) == 0


def test_servo_latency_reading_by_hand_and_per_episode():
    """The calibration's reading: the latency itself without randomization; with it, the latency
    + an error uniform in +-2 ms, never below 0. Per episode in the env: the episode's actuation
    latency (in 2 ms physics steps) within 2 ms, every one of its 11 values drawn."""
    cfg = _cfg(randomize=True)
    assert float(sensors.servo_latency_reading(_cfg(randomize=False), 0.008, None)) == pytest.approx(0.008)
    draw = jax.jit(jax.vmap(lambda lat, k: sensors.servo_latency_reading(cfg, lat, k)))
    lat = jnp.repeat(jnp.asarray([0.0, 0.01]), 2048)
    r = np.asarray(draw(lat, jax.random.split(jax.random.PRNGKey(0), 4096)))
    assert r.dtype == np.float32 and r.min() == 0.0
    err = r[2048:] - 0.01
    assert np.all(np.abs(err) <= 0.002 + 1e-7) and err.min() < -0.0019 and err.max() > 0.0019
    assert np.mean(r[:2048] == 0.0) == pytest.approx(0.5, abs=0.05)  # half the draws clipped at 0
    d = tasks.make_task_config("QuadsonJoystickRough").to_dict()
    d.update(observe_servo_latency=True, sim_dt=0.002)
    env = LocomotionEnv(ml_collections.ConfigDict(d))
    info = jax.jit(jax.vmap(env.episode_info))(jax.random.split(jax.random.PRNGKey(1), 1024))
    true_s = np.asarray(info["latency_steps"]) * 0.002
    assert set(np.unique(np.asarray(info["latency_steps"])).tolist()) == set(range(11))
    assert np.all(np.abs(np.asarray(info["servo_latency_reading"]) - true_s) <= 0.002 + 1e-7)


def test_sensor_parts_velocity_and_history_by_hand():
    # three ticks of history, newest first: after the call the newest row is this tick's block
    a = 12
    block = 3 + 3 + 12 + 12 + a
    history = jnp.stack([jnp.full(block, 1.0), jnp.full(block, 2.0)])  # (H - 1 = 2, block)
    readings = {
        "gravity": jnp.asarray([0.0, 0.0, -1.0]),
        "gyro": jnp.zeros(3),
        "motor_pos": jnp.full(12, 0.5),
    }
    parts, new = sensors.sensor_observation_parts(
        readings,
        jnp.full(12, 0.48),
        0.02,
        jnp.full(a, 0.25),
        history,
        jnp.zeros(4),
        jnp.asarray([0.3, 0.0, 0.1]),
    )
    np.testing.assert_allclose(parts["motor_vel"], np.full(12, (0.5 - 0.48) / 0.02), rtol=1e-5)
    np.testing.assert_allclose(parts["gyro@-1"], [1.0] * 3)
    np.testing.assert_allclose(parts["last_action@-2"], [2.0] * a)
    assert new.shape == (2, block)
    np.testing.assert_allclose(new[1], history[0])  # the old newest moved one back, the oldest dropped
    np.testing.assert_allclose(new[0][:3], [0, 0, -1])
    spec = obs_spec.sensor_observation(("FL", "FR", "RL", "RR"), [f"m{i}" for i in range(12)], a, history=3)
    assert spec.assemble(parts).shape == (spec.size,)


@pytest.fixture(scope="session")
def sensor_env():
    """The robust recipe's env with its sensor errors fixed (no noise, readings one tick old, a known
    tilt and bias) and 2 ticks of history, jitted reset and step."""
    d = tasks.make_task_config("QuadsonJoystickFlat").to_dict()
    d.update(obs_history=2, pushes=False)
    d["sensor"].update(
        gravity_noise=0.0, gyro_noise_rps=0.0, encoder_noise_rad=0.0, gyro_bias_rps=0.0, imu_tilt_rad=0.0,
        latency_s=(0.02, 0.02),
    )  # fmt: skip
    env = LocomotionEnv(ml_collections.ConfigDict(d))
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_actor_excludes_and_critic_includes_the_privileged_state(sensor_env):
    env, _, _ = sensor_env
    assert env.obs_spec.robot_measurable() and not env.critic_spec.robot_measurable()
    sim = [e.name for e in env.critic_spec.entries if e.sensor == "simulator"]
    assert {"true_lin_vel", "base_height", "foot_contact", "physics", "ground_under_feet"} <= set(sim)
    assert not ({"true_lin_vel", "base_lin_vel", "base_rpy"} & {e.name for e in env.obs_spec.entries})
    # brax's networks: the policy's first layer takes the actor's entries, the value's the critic's
    _, policy, value = params_template(env.observation_size, env.action_size, ppo_config("test"))
    first = lambda p: next(iter(p["params"].values()))["kernel"].shape[0]  # noqa: E731
    assert first(policy) == env.obs_spec.size == 3 + 3 + 12 + 12 + 12 + 42 + 4 + 4 + 3
    assert first(value) == env.critic_spec.size == env.obs_spec.size + 3 + 3 + 1 + 4 + 4 + 4 + 4 + 6


def test_env_sensor_observation_reads_the_previous_tick(sensor_env):
    env, reset, step = sensor_env
    s0 = reset(jax.random.PRNGKey(0))
    a0 = env.obs_spec.split(s0.obs["state"])
    assert not np.any(a0["motor_vel"]) and not np.any(a0["last_action"])
    np.testing.assert_allclose(a0["gravity@-1"], a0["gravity"])  # history starts as the first reading
    s1 = step(s0, jnp.full(12, 0.2))
    s2 = step(s1, jnp.full(12, -0.2))
    a2 = env.obs_spec.split(s2.obs["state"])
    # readings 20 ms old: tick 2 reads the state at tick 1's end (no noise, no tilt or bias here)
    q1 = s1.pipeline_state.qpos
    np.testing.assert_allclose(a2["gravity"], sensors.gravity_direction(q1[3:7]), atol=1e-6)
    np.testing.assert_allclose(a2["gyro"], s1.pipeline_state.qvel[3:6], atol=1e-5)
    enc1 = sensors.quantize(q1[env._motor_qpos], STEP)
    np.testing.assert_allclose(a2["motor_pos"], enc1, atol=1e-6)
    # tick 1 read the state at reset (its last_encoders); the velocity is their difference / 20 ms
    np.testing.assert_allclose(a2["motor_vel"], (enc1 - s1.info["last_encoders"]) / 0.02, atol=1e-3)
    np.testing.assert_allclose(a2["last_action"], np.full(12, -0.2))
    np.testing.assert_allclose(a2["last_action@-1"], np.full(12, 0.2))
    c2 = env.critic_spec.split(s2.obs["privileged_state"])
    # the critic sees the present: the true velocity of the state after tick 2
    from quadson_mjx.sensors import base_state

    _, lin_vel, _ = base_state(s2.pipeline_state.qpos, s2.pipeline_state.qvel)
    np.testing.assert_allclose(c2["true_lin_vel"], lin_vel, atol=1e-6)
    np.testing.assert_allclose(c2["base_height"], s2.pipeline_state.qpos[2:3], atol=1e-6)  # flat ground
    np.testing.assert_allclose(c2["sensor_model"][-1], 0.02, atol=1e-6)
    for x in jax.tree.leaves(s2.obs):
        assert x.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(x)))


def test_env_sensor_observation_reads_mid_step(sensor_env):
    """Readings 2 physics steps old: the observation after a control step reads the state of its
    third physics step of five, checked against three mjx.step calls from the step's start."""
    from mujoco import mjx

    env, reset, step = sensor_env
    s1 = step(reset(jax.random.PRNGKey(1)), jnp.full(12, 0.3))
    info = dict(
        s1.info, sensor_latency_steps=jnp.asarray(2, jnp.int32), latency_steps=jnp.asarray(0, jnp.int32)
    )
    s2 = step(s1.replace(info=info), jnp.full(12, -0.3))
    physics = jax.jit(lambda d, c: mjx.step(env.sys, d.replace(ctrl=c)))
    data, gravity = s1.pipeline_state, []
    for _ in range(env._n_substeps):
        data = physics(data, s2.info["last_ctrl"])
        gravity.append(np.asarray(sensors.gravity_direction(data.qpos[3:7])))
    np.testing.assert_allclose(gravity[-1], sensors.gravity_direction(s2.pipeline_state.qpos[3:7]), atol=1e-6)
    got = env.obs_spec.split(s2.obs["state"])["gravity"]
    np.testing.assert_allclose(got, gravity[2], atol=1e-6)  # physics step 3 of 5
    assert min(np.abs(got - gravity[i]).max() for i in (1, 3)) > 1e-5  # its neighbours differ
