"""The observation and action specification (quadson_mjx.obs_spec): defined once, and the environment,
the deploy loop and the exported file agree on it.

References: the observation table published with the ONNX export (docs/deploy.md: indices 0-2 rpy,
3-5 base linear velocity, 6-8 gyro, 9-20 motors, 21-24 sin, 25-28 cos of the phases, 29-31
command), and the environment's own observation of a physics state, which the deploy loop must
rebuild from the sensor readings of that state.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx import deploy, obs_spec
from quadson_mjx.config import to_json
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.quat import quat_rotate_inverse

LEGS = ("FL", "FR", "RL", "RR")
MOTORS = tuple(f"{leg}_{m}_joint" for leg in LEGS for m in ("motor0", "motor1", "motor5"))


def test_locomotion_observation_is_the_published_table():
    spec = obs_spec.locomotion_observation(LEGS, MOTORS, command_tracking=True)
    assert spec.size == 32
    s = spec.slices()
    assert (s["base_rpy"], s["base_lin_vel"], s["base_ang_vel"]) == (slice(0, 3), slice(3, 6), slice(6, 9))
    assert (s["motor_pos"], s["phase_sin"], s["phase_cos"]) == (slice(9, 21), slice(21, 25), slice(25, 29))
    assert s["command"] == slice(29, 32)
    assert spec.names[9] == "motor_pos.FL_motor0_joint" and spec.names[20] == "motor_pos.RR_motor5_joint"
    assert spec.names[29:] == ("command.vx", "command.vy", "command.yaw_rate")
    assert obs_spec.locomotion_observation(LEGS, MOTORS, command_tracking=False).size == 29
    # only the base velocity comes from no sensor of the robot (an estimator)
    assert {e.name for e in spec.entries if e.sensor == "estimator"} == {"base_lin_vel"}


def test_action_spec_sizes():
    assert obs_spec.locomotion_action(LEGS, False, 0.05).size == 12
    act = obs_spec.locomotion_action(LEGS, True, 0.05)
    assert act.size == 14 and act.names[:3] == ("foot_offset.FL.x", "foot_offset.FL.y", "foot_offset.FL.z")


def test_assemble_split_and_json_round_trip():
    spec = obs_spec.locomotion_observation(LEGS, MOTORS, command_tracking=True)
    vec = np.arange(32.0)
    parts = spec.split(vec)
    np.testing.assert_array_equal(spec.assemble(parts), vec)
    assert obs_spec.Spec.from_json(spec.to_json()) == spec
    # batched and jitted, as the environment runs it
    batch = jnp.arange(64.0).reshape(2, 32)
    out = jax.jit(lambda b: spec.assemble(spec.split(b)))(batch)
    assert out.shape == (2, 32) and out.dtype == jnp.float32
    np.testing.assert_array_equal(out, batch)


def test_array_namespace_of_numpy_jax_and_tracers():
    from quadson_mjx.arrays import namespace

    assert namespace(np.zeros(2)).__name__ == "array_api_compat.numpy"
    assert namespace([1.0, 2.0]).__name__ == namespace().__name__ == "array_api_compat.numpy"
    assert namespace(jnp.zeros(2), 3.0) is jnp
    seen = []
    jax.jit(jax.vmap(lambda x: seen.append(namespace(x)) or x))(jnp.zeros((2, 3)))
    assert seen == [jnp]  # a batched tracer under jit: taken from the tracer itself
    with pytest.raises(TypeError, match="Multiple namespaces"):
        namespace(np.zeros(2), jnp.zeros(2))


def test_assemble_refuses_a_wrong_or_missing_part():
    spec = obs_spec.locomotion_observation(LEGS, MOTORS, command_tracking=False)
    parts = spec.split(np.zeros(29))
    with pytest.raises(ValueError, match=r"motor_pos has shape \(11,\)"):
        spec.assemble({**parts, "motor_pos": np.zeros(11)})
    with pytest.raises(ValueError, match=r"missing \['phase_cos'\]"):
        spec.assemble({k: v for k, v in parts.items() if k != "phase_cos"})
    with pytest.raises(ValueError, match=r"unknown \['command'\]"):
        spec.assemble({**parts, "command": np.zeros(3)})


class _Policy:
    def __init__(self, env):
        self.meta = {
            "env_config": json.loads(to_json(env.config)),
            "obs_spec": env.obs_spec.to_json(),
            "action_spec": env.action_spec.to_json(),
            "trained_sensor_model": {  # as export_meta records it
                "actuation_latency_s": list(env.config.randomization.latency_s),
                "sensor": {"servo_latency_error_s": env.config.sensor.servo_latency_error_s},
            },
        }
        self.obs_size, self.action_size = env.observation_size, env.action_size

    def __call__(self, obs):
        return np.zeros(self.action_size, np.float32)


@pytest.fixture(scope="module")
def command_env():
    return LocomotionEnv(env_config(command_tracking=True))


def test_env_and_deploy_loop_build_the_same_observation_from_the_same_sensors(command_env):
    env = command_env
    loop = deploy.DeployLoop(_Policy(env))
    assert loop.config.obs_spec == env.obs_spec and loop.config.action_spec == env.action_spec
    observe = jax.jit(env.observation)
    rng = np.random.default_rng(3)
    motor_q = np.asarray(env._motor_qpos)
    for _ in range(5):
        qpos = np.asarray(env._home_qpos, np.float64).copy()
        quat = rng.normal(size=4)
        qpos[3:7] = quat / np.linalg.norm(quat)
        qpos[motor_q] += rng.uniform(-0.2, 0.2, 12)
        qvel = rng.uniform(-1.0, 1.0, env.sys.nv)
        progress = float(rng.uniform(0, 1))
        command = rng.uniform(-0.3, 0.3, 3)
        info = {
            "gait_progress": jnp.float32(progress),
            "command": jnp.asarray(command, jnp.float32),
            "rng": jax.random.PRNGKey(0),
        }
        want = np.asarray(observe(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32), info))
        loop.progress = progress
        got = loop.observation(
            imu_quat_wxyz=qpos[3:7],
            gyro=qvel[3:6],  # the free joint's angular velocity is in the body frame
            motor_pos=qpos[motor_q],
            base_lin_vel=quat_rotate_inverse(qpos[3:7], qvel[0:3]),
            command=command,
        )
        assert got.shape == want.shape == (env.obs_spec.size,) and got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-5)  # float32 env, float64 loop


def test_deploy_loop_refuses_a_file_with_another_spec(command_env):
    policy = _Policy(command_env)
    entries = list(obs_spec.Spec.from_json(policy.meta["obs_spec"]).entries)
    entries[0], entries[1] = entries[1], entries[0]  # same sizes, another order
    policy.meta["obs_spec"] = obs_spec.Spec(tuple(entries)).to_json()
    with pytest.raises(ValueError, match="obs_spec differs"):
        deploy.DeployLoop(policy)


# --- the sensor-only observation: env and deploy loop from the same sensor stream -----------------


@pytest.fixture(scope="module")
def sensor_env():
    cfg = env_config(command_tracking=True)
    cfg.unlock()
    cfg.observation = "sensors"
    cfg.obs_history = 3
    cfg.yaw_error_tau_s = 0.5
    cfg.observe_servo_latency = True
    cfg.lock()
    return LocomotionEnv(cfg)


def test_env_and_deploy_loop_build_the_same_sensor_observation_from_the_same_stream(sensor_env):
    """The jitted env steps with random actions; the loop is fed what the env's sensors read at each
    tick (IMU quaternion and gyro, the encoders quantised as the env quantises them) and returns the
    same actions: its observation (gravity, gyro, encoders, their velocity, last action, two ticks of
    history, phases, command, the yaw error, the servos' measured latency) equals the env's to
    float32 precision, from the first tick on. The yaw error also equals its recurrence worked by
    hand from the env's gyro entries."""
    env = sensor_env
    loop = deploy.DeployLoop(_Policy(env))
    assert loop.config.obs_spec == env.obs_spec and not loop.needs_lin_vel
    assert loop.needs_servo_latency and loop.servo_latency_range == pytest.approx((0.0, 0.022))
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    state = reset(jax.random.PRNGKey(4))
    with pytest.raises(ValueError, match="set loop.servo_latency_s"):
        loop.step(np.array([1.0, 0, 0, 0]), np.zeros(3), loop.config.robot.home_motor, command=np.zeros(3))
    # an episode whose servos were measured at 13 ms (the env config is not randomized: 0 otherwise)
    latency = env.obs_spec.slices()["servo_latency"]
    assert float(state.obs[latency][0]) == 0.0
    state = state.replace(
        info={**state.info, "servo_latency_reading": jnp.float32(0.013)},
        obs=state.obs.at[latency].set(0.013),
    )
    loop.servo_latency_s = 0.013
    actions = np.asarray(
        jax.random.uniform(jax.random.PRNGKey(5), (20, env.action_size), minval=-0.4, maxval=0.4)
    )
    motor_q = np.asarray(env._motor_qpos)
    res = np.float32(env.config.sensor.encoder_resolution_rad)
    command = np.asarray(state.info["command"], np.float64)
    worst = 0.0
    where = env.obs_spec.slices()
    decay, dt, by_hand = np.exp(-env.ctrl_dt / 0.5), env.ctrl_dt, 0.0
    for k in range(20):
        qpos, qvel = np.asarray(state.pipeline_state.qpos), np.asarray(state.pipeline_state.qvel)
        encoders = np.round(qpos[motor_q] / res) * res  # float32, as sensors.quantize
        policy_action = actions[k].astype(np.float32)
        loop.policy = lambda obs, a=policy_action: a
        out = loop.step(qpos[3:7], qvel[3:6], encoders, command=command)
        assert out.fault == "ok"
        want = np.asarray(state.obs)
        worst = max(worst, float(np.max(np.abs(out.obs - want))))
        # measured 6.2e-6: float32 env (phases, quaternion rotation, velocity quotient), float64 loop
        np.testing.assert_allclose(out.obs, want, rtol=0, atol=2e-5, err_msg=f"tick {k}")
        if k:  # 0 at the first tick, then e <- e exp(-dt / tau) + dt (gyro z - commanded yaw rate)
            by_hand = decay * by_hand + dt * (float(want[where["gyro"]][2]) - command[2])
        assert float(want[where["yaw_error"]][0]) == pytest.approx(by_hand, abs=1e-6)
        assert float(want[latency][0]) == pytest.approx(0.013, abs=1e-9)  # the env's, every tick
        state = step(state, jnp.asarray(actions[k]))
        assert not bool(state.done)
    print(f"sensor observation, env vs loop over 20 ticks: max abs difference {worst:.2e}")
    assert abs(by_hand) > 1e-3  # the random actions turned the body: the entry was exercised


def test_the_measured_servo_latency_is_checked_against_the_trained_range(sensor_env, command_env):
    """The loop refuses a servo latency outside the trained 0-20 ms widened by the calibration's
    2 ms, a non-finite one, and one for a policy that does not observe it; the entry comes last,
    from the robot's calibration, so the actor stays robot-measurable."""
    loop = deploy.DeployLoop(_Policy(sensor_env))
    for bad in (-0.001, 0.0221, 0.06, float("nan")):
        with pytest.raises(ValueError, match=r"trained for a measured latency in \[0, 0.022\] s"):
            loop.servo_latency_s = bad
    loop.servo_latency_s = 0.022
    assert loop.servo_latency_s == 0.022
    assert "servo_latency_s" in deploy.describe(loop)
    spec = sensor_env.obs_spec
    assert spec.entries[-1] == obs_spec.SERVO_LATENCY and spec.entries[-1].sensor == "calibration"
    assert spec.robot_measurable()
    plain = deploy.DeployLoop(_Policy(command_env))
    with pytest.raises(ValueError, match="does not observe the servos' latency"):
        plain.servo_latency_s = 0.01


def test_yaw_error_step_by_hand_and_its_bias_level():
    """tau 1 s, ctrl_dt 0.02 s: 0.1 rad, gyro 0.5, command 0.2 rad/s -> 0.1 exp(-0.02) + 0.02 x 0.3
    = 0.104019867 rad; a constant 0.03 rad/s bias settles at 0.03 x 0.02 / (1 - exp(-0.02)) =
    0.0303 rad (about bias x tau)."""
    assert obs_spec.yaw_error_step(0.1, 0.5, 0.2, 0.02, 1.0) == pytest.approx(0.104019867, abs=1e-9)
    e = np.zeros(1)
    for _ in range(2000):
        e = obs_spec.yaw_error_step(e, np.array([0.33]), np.array([0.3]), 0.02, 1.0)
    assert float(e[0]) == pytest.approx(0.0303, abs=1e-4)
    spec = obs_spec.sensor_observation(LEGS, MOTORS, 12, 1, True, True)
    assert spec.names[-1] == "yaw_error.z" and spec.entries[-1].sensor == "imu" and spec.robot_measurable()
    with pytest.raises(ValueError, match="needs the command"):
        obs_spec.sensor_observation(LEGS, MOTORS, 12, 1, False, True)
