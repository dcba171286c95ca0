"""The IMU calibration of the deploy loop (quadson_mjx.deploy_imu) against the simulator's sensor
model: readings made by quadson_mjx.sensors (JAX: its tilt quaternion and its gyro, mounted and
biased as the env draws them) must give back the mounting and the bias, and a calibrated loop fed
them must observe what an uncalibrated loop fed the body's true orientation and rate observes."""

import functools
import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx import deploy, sensors
from quadson_mjx.config import apply_overrides, to_json
from quadson_mjx.deploy_imu import MOUNT_TOLERANCE_RAD, calibrate_imu, needs_calibration
from quadson_mjx.env_recipes import SENSOR_MODEL
from quadson_mjx.quat import axis_quat, quat_mul
from quadson_mjx.tasks import make_task_config

TILT = np.array([0.03, -0.025])  # roll, pitch [rad]: within the trained 0.035
BIAS = np.array([0.02, -0.015, 0.028])  # [rad/s]: within the trained 0.03


@functools.cache
def _cfg(task="QuadsonJoystickRough"):
    # a joystick task (default: the sensor-only one); no random noise, so the sensor model's
    # readings are exact
    return apply_overrides(make_task_config(task), ["randomize=false"])


def _imu(body_quat, body_rate):
    """What the env's sensor model reads for a body orientation (4,) and angular velocity (3,),
    body frame: the IMU's orientation (body * tilt, sensors.tilt_quat) and its gyro
    (sensors.read_sensors)."""
    tilt = sensors.tilt_quat(jnp.asarray(TILT))
    qpos = jnp.concatenate([jnp.zeros(3), jnp.asarray(body_quat), jnp.zeros(12)])
    qvel = jnp.concatenate([jnp.zeros(3), jnp.asarray(body_rate), jnp.zeros(12)])
    errors = {"imu_tilt": jnp.asarray(TILT), "gyro_bias": jnp.asarray(BIAS)}
    read = sensors.read_sensors(_cfg(), qpos, qvel, jnp.zeros(12), errors, None)
    imu_quat = np.asarray(sensors.quat_mul(jnp.asarray(body_quat), tilt), np.float64)
    # the reading's gravity is the IMU quaternion's (the loop computes it from the quaternion)
    np.testing.assert_allclose(
        np.asarray(read["gravity"]), np.asarray(sensors.gravity_direction(jnp.asarray(imu_quat))), atol=1e-6
    )
    return imu_quat, np.asarray(read["gyro"], np.float64)


class _Still:
    """Stands in for an exported joystick policy (sensor-only, or true_state: base velocity and
    yaw observed): its config, a zero action."""

    def __init__(self, task="QuadsonJoystickRough"):
        self.meta = {"env_config": json.loads(to_json(_cfg(task)))}
        self.obs_size = deploy.LoopConfig.from_env_config(self.meta["env_config"]).obs_size
        self.action_size = 12

    def __call__(self, obs):
        return np.zeros(12, np.float32)


def _standing(n=50, quat_noise=0.0, gyro_noise=0.0, seed=0):
    """n ticks of a robot standing level at a yaw of 1.2 rad: IMU quaternions and gyros, with noise
    added to each quaternion component and each gyro axis."""
    rng = np.random.default_rng(seed)
    q, g = _imu(axis_quat(2, 1.2), np.zeros(3))
    quats = np.tile(q, (n, 1)) + quat_noise * rng.normal(size=(n, 4))
    return quats, np.tile(g, (n, 1)) + gyro_noise * rng.normal(size=(n, 3))


def test_calibration_recovers_the_sensor_models_mounting_and_bias():
    cal = calibrate_imu(*_standing())
    np.testing.assert_allclose(cal.roll_pitch, TILT, atol=1e-6)
    np.testing.assert_allclose(cal.gyro_bias, BIAS, atol=1e-6)
    np.testing.assert_allclose(cal.mount_quat, np.asarray(sensors.tilt_quat(jnp.asarray(TILT))), atol=1e-6)
    assert cal.samples == 50 and cal.spread_rad < 1e-6
    # the training's sensor noise (a reading's gravity ~0.02 off per component, the gyro's 0.05
    # rad/s), 100 ticks: accepted (not "moved"), within 5 mrad and 15 mrad/s
    cal = calibrate_imu(*_standing(n=100, quat_noise=0.01, gyro_noise=0.05))
    np.testing.assert_allclose(cal.roll_pitch, TILT, atol=5e-3)
    np.testing.assert_allclose(cal.gyro_bias, BIAS, atol=1.5e-2)


def test_a_calibrated_loop_observes_the_body_as_an_uncalibrated_one_fed_the_truth():
    calibrated, truth = deploy.DeployLoop(_Still()), deploy.DeployLoop(_Still())
    assert {"gravity", "gyro"} <= {e.name for e in calibrated.config.obs_spec.entries}
    calibrated.imu_calibration = calibrate_imu(*_standing())
    rng = np.random.default_rng(1)
    home = calibrated.config.robot.home_motor
    for _ in range(5):  # a tilted, turning body: its true orientation and rate, and the IMU's reading
        rpy = rng.uniform([-0.3, -0.3, -math.pi], [0.3, 0.3, math.pi])
        body = quat_mul(axis_quat(2, rpy[2]), quat_mul(axis_quat(1, rpy[1]), axis_quat(0, rpy[0])))
        rate = rng.uniform(-2.0, 2.0, 3)
        imu_quat, gyro = _imu(body, rate)
        command = rng.uniform(-0.2, 0.2, 3)
        want = truth.step(body, rate, home, command=command).obs
        got = calibrated.step(imu_quat, gyro, home, command=command).obs
        np.testing.assert_allclose(got, want, atol=2e-6)
        # the same reading, not calibrated, observes the mounting and the bias
        plain = deploy.DeployLoop(_Still()).observation(imu_quat, gyro, home, command=command)
        assert np.max(np.abs(plain - want)) > 0.01


@pytest.mark.parametrize(
    ("quats", "gyros", "match"),
    [
        (np.ones((5, 3)), np.zeros((5, 3)), r"\(N, 4\)"),
        (np.tile([1.0, 0, 0, 0], (5, 1)), np.zeros((4, 3)), r"\(5, 3\)"),
        (np.tile([np.nan, 0, 0, 0], (5, 1)), np.zeros((5, 3)), "not finite"),
        (np.tile([2.0, 0, 0, 0], (5, 1)), np.zeros((5, 3)), "norms"),
        # the robot rocked by 3 deg while it was read
        (np.array([[1.0, 0, 0, 0], axis_quat(0, 0.05)]), np.zeros((2, 3)), "moved"),
        (np.tile([1.0, 0, 0, 0], (2, 1)), np.array([[0.0, 0, 0], [0.0, 0, 0.5]]), "moved"),
        # on a 15 deg slope
        (np.tile(axis_quat(1, math.radians(15)), (3, 1)), np.zeros((3, 3)), "level ground"),
    ],
)
def test_calibration_refuses_bad_readings(quats, gyros, match):
    with pytest.raises(ValueError, match=match):
        calibrate_imu(quats, gyros)


def test_loop_refuses_a_calibration_of_another_type():
    loop = deploy.DeployLoop(_Still())
    with pytest.raises(ValueError, match="ImuCalibration"):
        loop.imu_calibration = (0.03, -0.025)
    loop.imu_calibration = None
    assert loop.imu_calibration is None


@pytest.mark.parametrize("explicit", [False, True])
def test_heading_reset_of_a_calibrated_loop_is_the_bodys_yaw(explicit):
    # a true_state policy observes roll, pitch and yaw (after the heading reset): with the calibration,
    # from the IMU's readings, the same as from the body's, whether the heading is reset from a given
    # reading or from the next step's
    calibrated = deploy.DeployLoop(_Still("QuadsonJoystickTrueStateRough"))
    truth = deploy.DeployLoop(_Still("QuadsonJoystickTrueStateRough"))
    assert "base_rpy" in {e.name for e in truth.config.obs_spec.entries}
    calibrated.imu_calibration = calibrate_imu(*_standing())
    home, lin_vel = truth.config.robot.home_motor, np.array([0.2, -0.05, 0.0])
    body = quat_mul(axis_quat(2, 2.0), quat_mul(axis_quat(1, 0.1), axis_quat(0, -0.05)))
    imu_quat, gyro = _imu(body, np.array([0.1, 0.2, 0.3]))
    calibrated.reset_heading(imu_quat if explicit else None)
    truth.reset_heading(body if explicit else None)
    for _ in range(3):
        want = truth.step(body, np.array([0.1, 0.2, 0.3]), home, base_lin_vel=lin_vel).obs
        got = calibrated.step(imu_quat, gyro, home, base_lin_vel=lin_vel).obs
        np.testing.assert_allclose(got, want, atol=2e-6)


class _Calibrated(_Still):
    """A sensor-only policy file trained with the mounting tilt of a calibrated robot: its metadata's
    trained_sensor_model as quadson_mjx.export_meta writes it."""

    def __init__(self, tilt=0.01, randomize=True, task="QuadsonJoystickRough"):
        super().__init__(task)
        cfg = apply_overrides(
            make_task_config(task), [f"sensor.imu_tilt_rad={tilt}", f"randomize={randomize}"]
        )
        self.meta["trained_sensor_model"] = {
            "observation": cfg.observation,
            "randomize": bool(cfg.randomize),
            "sensor": json.loads(to_json(cfg.sensor)),
        }


def test_a_policy_trained_for_a_calibrated_imu_does_not_walk_without_one():
    loop = deploy.DeployLoop(_Calibrated())
    assert loop.needs_imu_calibration and deploy.describe(loop).endswith(
        "; needs an IMU calibration (loop.imu_calibration)"
    )
    assert "needs base_lin_vel from an estimator" in deploy.describe(
        deploy.DeployLoop(_Still("QuadsonJoystickTrueStateRough"))
    )
    assert "needs" not in deploy.describe(deploy.DeployLoop(_Still()))
    q, g = _imu(np.array([1.0, 0, 0, 0]), np.zeros(3))
    home = loop.config.robot.home_motor
    with pytest.raises(ValueError, match=r"calibrated IMU \(mounting tilt within 0\.01 rad\).*calibrate_imu"):
        loop.step(q, g, home)
    loop.imu_calibration = calibrate_imu(*_standing())
    assert loop.step(q, g, home).fault == deploy.Fault.OK
    # the default range (an IMU mounted by hand, what the recipes train with), no randomization,
    # a true_state policy, a file from before the trained sensor model was recorded: none needed
    assert MOUNT_TOLERANCE_RAD == SENSOR_MODEL["imu_tilt_rad"]
    assert not needs_calibration(_Calibrated(tilt=MOUNT_TOLERANCE_RAD).meta)
    assert needs_calibration(_Calibrated(tilt=0.0).meta)
    assert not needs_calibration(_Calibrated(randomize=False).meta)
    assert not needs_calibration(_Calibrated(task="QuadsonJoystickTrueStateRough").meta)
    assert not needs_calibration(_Still().meta)
    assert not deploy.DeployLoop(_Still()).needs_imu_calibration
