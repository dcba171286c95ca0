"""The IMU's calibration on the robot: its mounting tilt and its gyro bias, measured once while the
robot stands still on level ground, then taken out of every reading the deploy loop observes.

    cal = calibrate_imu(imu_quats_wxyz, gyros)   # (N, 4), (N, 3): a second or two standing still
    loop.imu_calibration = cal                   # quadson_mjx.deploy.DeployLoop

The simulator's sensor model (quadson_mjx.sensors.read_sensors) mounts the IMU with a roll and a
pitch T = Ry(pitch) Rx(roll) on the body (IMU orientation = body orientation * T) and adds a
constant bias to the gyro, which reads the body's angular velocity in the IMU's frame. Standing
level, the body's orientation is a yaw alone, so the gravity direction the IMU reads is T^T (0, 0,
-1) = (sin p, -sin r cos p, -cos r cos p) whatever the yaw, and the gyro reads its bias. The
correction is the inverse: body orientation = IMU orientation * T^-1, angular velocity = T (gyro -
bias). A yaw of the mounting is not observable from gravity and is not corrected. Policies are
trained with mounting tilts up to env_recipes.SENSOR_MODEL's imu_tilt_rad and biases up to its
gyro_bias_rps; a calibrated robot shows them what the level-ground reading leaves (how level the
floor and the home stance are, the bias's drift since).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from quadson_mjx.quat import quat_conj, quat_mul, quat_rotate, quat_rotate_inverse, tilt_quat

# Refusals of a calibration (ValueError). A robot that moved while it was read: the mean gravity
# direction of the first half of the readings and of the second more than 0.5 deg apart, or the
# gyro's RMS deviation from its mean over 0.2 rad/s (the sensor noise of a fusion filter, ~1 deg a
# reading, and of a gyro, <= 0.1 rad/s, pass; a step or a push does not). A mounting tilt of more
# than 10 deg: a robot that is not level, or an IMU mounted askew that should be fixed on the frame.
MAX_SPREAD_RAD = math.radians(0.5)
# The mounting tilt an uncalibrated robot may have: a hand-mounted IMU board sits within ~2 deg of
# the body frame (env_recipes.SENSOR_MODEL's imu_tilt_rad, what policies train with by default). A
# policy trained with a narrower range (e.g. --env.sensor.imu_tilt_rad=0.01: a calibrated robot's
# residual) needs the calibration: the deploy loop refuses to walk it without one
# (needs_calibration).
MOUNT_TOLERANCE_RAD = 0.035
MAX_GYRO_DEVIATION_RPS = 0.2
MAX_TILT_RAD = math.radians(10.0)
_DOWN = np.array([0.0, 0.0, -1.0])


class ImuCalibration(NamedTuple):
    roll_pitch: np.ndarray  # (2,) the IMU's mounting roll and pitch on the body [rad]
    gyro_bias: np.ndarray  # (3,) [rad/s], in the IMU's frame
    samples: int
    spread_rad: float  # the angle between the mean gravity directions of the two halves

    @property
    def mount_quat(self) -> np.ndarray:
        """T = Ry(pitch) Rx(roll) as a wxyz quaternion (quat.tilt_quat, as the sensor model mounts it)."""
        return _mount(*(float(a) for a in self.roll_pitch))[0].copy()

    def apply(self, imu_quat_wxyz, gyro) -> tuple[np.ndarray, np.ndarray]:
        """A reading of the IMU -> (the body's orientation (4,), its angular velocity (3,) [rad/s])."""
        _, t_conj, t_mat = _mount(*(float(a) for a in self.roll_pitch))
        quat = quat_mul(np.asarray(imu_quat_wxyz, np.float64), t_conj)
        return quat, t_mat @ (np.asarray(gyro, np.float64) - self.gyro_bias)


@functools.lru_cache(maxsize=8)
def _mount(roll: float, pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mounting T of a calibration, computed once (apply runs every control tick): its wxyz
    quaternion, the conjugate and its rotation matrix (columns: T's images of the body axes)."""
    t = tilt_quat(np.array([roll, pitch]))
    mat = np.stack([quat_rotate(t, e) for e in np.eye(3)], axis=1)
    return t, quat_conj(t), mat


def calibrate_imu(imu_quats_wxyz, gyros) -> ImuCalibration:
    """Readings of a robot standing still on level ground (a second or two of ticks): imu_quats_wxyz
    (N, 4) orientations, gyros (N, 3) [rad/s] -> its ImuCalibration. ValueError, with what was
    wrong, for other shapes, non-finite readings, a quaternion whose norm is not near 1, a robot that
    moved (see MAX_SPREAD_RAD, MAX_GYRO_DEVIATION_RPS) or a tilt of more than 10 deg."""
    quats = np.asarray(imu_quats_wxyz, np.float64)
    gyros = np.asarray(gyros, np.float64)
    if quats.ndim != 2 or quats.shape[1] != 4 or len(quats) < 1:
        raise ValueError(f"calibrate_imu: imu_quats_wxyz must be (N, 4) with N >= 1, got {quats.shape}")
    if gyros.shape != (len(quats), 3):
        raise ValueError(
            f"calibrate_imu: gyros must be ({len(quats)}, 3) like the quaternions, got {gyros.shape}"
        )
    if not (np.all(np.isfinite(quats)) and np.all(np.isfinite(gyros))):
        raise ValueError("calibrate_imu: a reading is not finite")
    norms = np.linalg.norm(quats, axis=1)
    if np.any(np.abs(norms - 1.0) > 0.1):
        raise ValueError(f"calibrate_imu: quaternion norms {norms.min():.3f}-{norms.max():.3f}, not 1")
    down = quat_rotate_inverse(quats / norms[:, None], _DOWN)  # (N, 3) gravity in the IMU's frame
    mean = down.mean(axis=0)
    mean /= np.linalg.norm(mean)
    half = len(down) // 2
    spread = 0.0
    if half:
        a, b = down[:half].mean(axis=0), down[half:].mean(axis=0)
        spread = float(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))
    if spread > MAX_SPREAD_RAD:
        raise ValueError(
            f"calibrate_imu: the gravity readings moved by {math.degrees(spread):.1f} deg (at most "
            f"{math.degrees(MAX_SPREAD_RAD)}): the robot moved; calibrate it standing still"
        )
    bias = gyros.mean(axis=0)
    deviation = float(np.sqrt(np.mean(np.sum((gyros - bias) ** 2, axis=1))))
    if deviation > MAX_GYRO_DEVIATION_RPS:
        raise ValueError(
            f"calibrate_imu: the gyro deviates {deviation:.2f} rad/s RMS from its mean (at most "
            f"{MAX_GYRO_DEVIATION_RPS}): the robot moved; calibrate it standing still"
        )
    roll = math.atan2(-mean[1], -mean[2])
    pitch = math.asin(float(np.clip(mean[0], -1.0, 1.0)))
    tilt = math.acos(float(np.clip(-mean[2], -1.0, 1.0)))
    if tilt > MAX_TILT_RAD:
        raise ValueError(
            f"calibrate_imu: the IMU reads a tilt of {math.degrees(tilt):.1f} deg (at most "
            f"{math.degrees(MAX_TILT_RAD):.0f}): stand the robot on level ground, or fix the IMU's mounting"
        )
    return ImuCalibration(np.array([roll, pitch]), bias, len(quats), spread)


def needs_calibration(meta: dict) -> bool:
    """Whether the policy of a file with this metadata (export_meta) was trained for a calibrated
    IMU: a sensor-only policy, randomized, with mounting tilts narrower than MOUNT_TOLERANCE_RAD.
    Files without the trained sensor model (exported before it was recorded) need none."""
    trained = meta.get("trained_sensor_model") or {}
    tilt = (trained.get("sensor") or {}).get("imu_tilt_rad")
    if trained.get("observation") != "sensors" or not trained.get("randomize") or tilt is None:
        return False
    return float(tilt) < MOUNT_TOLERANCE_RAD
