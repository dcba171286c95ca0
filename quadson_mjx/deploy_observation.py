"""The policy's observation on the robot, built from the policy file's spec (quadson_mjx.obs_spec)
exactly as the environment builds it from the simulator's sensors.

Entries, by name:
  gravity (3)        R(q)^T (0, 0, -1): the unit gravity direction in the body frame, from the IMU's
                     quaternion (normalised; yaw-independent).
  gyro, base_ang_vel (3)   the gyro reading [rad/s].
  motor_pos (12)     the encoders [rad].
  motor_vel (12)     (motor_pos - motor_pos of the previous tick) / ctrl_dt; 0 on the first tick.
  last_action        the previous tick's action, clipped to [-1, 1]; 0 after reset.
  name@-k            entry `name` k ticks ago, newest first; before the first tick the first tick's
                     values (so 0 for motor_vel and last_action).
  base_rpy (3)       ZYX angles of the IMU quaternion, yaw relative to the heading reset.
  base_lin_vel (3)   the estimator's velocity [m/s] (true_state policies).
  phase_sin, phase_cos (4)   sin, cos of 2 pi x each leg's gait phase at the loop's clock.
  command (3)        the command.
  yaw_error (1)      obs_spec.yaw_error_step of the gyro's z and the command's yaw rate: 0 at the
                     first tick after a reset or a resync, then integrated every committed tick.
  servo_latency (1)  the servos' latency measured on the robot [s] (servo_latency_s), every tick.
After a fault the history restarts from the next good tick (as after reset, the last action kept).
"""

from __future__ import annotations

import numpy as np

from quadson_mjx.obs_spec import yaw_error_step
from quadson_mjx.quat import quat_mul, quat_rotate_inverse, quat_to_rpy

_DOWN = np.array([0.0, 0.0, -1.0])


def _max_lag(spec) -> int:
    lags = [int(e.name.partition("@-")[2] or 0) for e in spec.entries]
    return max(lags, default=0)


class ObservationBuilder:
    """The observation's state between ticks: history, previous encoders, last action, heading."""

    def __init__(self, spec, robot, action_size: int, yaw_error_tau_s: float = 0.0):
        self.spec, self.robot, self.action_size = spec, robot, action_size
        self.yaw_error_tau_s = float(yaw_error_tau_s)
        if "yaw_error" in {e.name for e in spec.entries} and not self.yaw_error_tau_s > 0:
            raise ValueError("the observation has a yaw_error entry but no yaw_error_tau_s > 0")
        self.lags = _max_lag(spec)
        self.imu_calibration = None  # deploy_imu.ImuCalibration applied to every reading, or None
        self.servo_latency_s = None  # the servo_latency entry's value [s], or None
        self.heading = None  # (4,) quaternion rotating the world by -yaw0 about z, or None
        self._pending_heading = False
        self._last_quat = None
        self.reset()

    def reset(self) -> None:
        self.history = None  # [tick 0 (now), tick -1, ...] of the history entries
        self.prev_motor = None
        self.last_action = np.zeros(self.action_size, np.float64)
        self.yaw_error = np.zeros(1)
        self._pending = None

    def reset_heading(self, imu_quat_wxyz=None) -> None:
        q = imu_quat_wxyz if imu_quat_wxyz is not None else self._last_quat
        if q is None:
            self._pending_heading = True
            return
        q = np.asarray(q, np.float64)
        norm = float(np.linalg.norm(q))
        if q.shape != (4,) or not np.isfinite(norm) or norm < 0.5:
            raise ValueError(f"reset_heading: {q!r} is not an orientation quaternion")
        if imu_quat_wxyz is not None and self.imu_calibration is not None:
            q = self.imu_calibration.apply(q, np.zeros(3))[0]
        yaw = float(quat_to_rpy(q / norm)[2])
        self.heading = np.array([np.cos(-0.5 * yaw), 0.0, 0.0, np.sin(-0.5 * yaw)])
        self._pending_heading = False

    def observe(self, quat, gyro, motor_pos, command, base_lin_vel, progress, ctrl_dt, resync=False):
        """Checked readings (deploy_safety.check_sensors) -> (obs_size,) float32. The history moves
        on only at commit() (a tick whose policy output is not used leaves it as it was). With an
        imu_calibration, its mounting tilt and gyro bias are taken out of the readings first."""
        if self.imu_calibration is not None:
            quat, gyro = self.imu_calibration.apply(quat, gyro)
        q = quat / np.linalg.norm(quat)
        self._last_quat = q  # the body's orientation (calibrated), for reset_heading()
        if self._pending_heading:
            self.reset_heading()
        if self.heading is not None:
            q = quat_mul(self.heading, q)
        if resync:
            self.history, self.prev_motor = None, None
        first = self.prev_motor is None
        vel = np.zeros(12) if first else (motor_pos - self.prev_motor) / ctrl_dt
        yaw_error = np.zeros(1)
        if self.yaw_error_tau_s and not first:
            yaw_error = yaw_error_step(self.yaw_error, gyro[2:], command[2:], ctrl_dt, self.yaw_error_tau_s)
        now = {
            "gravity": quat_rotate_inverse(q, _DOWN),
            "gyro": gyro,
            "motor_pos": motor_pos,
            "motor_vel": vel,
            "last_action": self.last_action,
        }
        history = [now] + (self.history or [now] * self.lags)[: self.lags]
        r = self.robot
        phase = 2.0 * np.pi * r.leg_phases(progress * r.gait.cycle_s, r.gait)
        known = {
            "base_rpy": lambda: quat_to_rpy(q),
            "base_lin_vel": lambda: base_lin_vel,
            "base_ang_vel": lambda: gyro,
            "phase_sin": lambda: np.sin(phase),
            "phase_cos": lambda: np.cos(phase),
            "command": lambda: command,
            "yaw_error": lambda: yaw_error,
            "servo_latency": self._servo_latency,
        }
        parts = {}
        for e in self.spec.entries:
            name, _, lag = e.name.partition("@-")
            parts[e.name] = history[int(lag or 0)][name] if name in now else known[name]()
            parts[e.name] = np.asarray(parts[e.name], np.float64).reshape(e.size)
        self._pending = (history, motor_pos, yaw_error)
        return self.spec.assemble(parts).astype(np.float32)

    def _servo_latency(self):
        if self.servo_latency_s is None:
            raise ValueError("the observation has a servo_latency entry but no servo_latency_s was given")
        return self.servo_latency_s

    def commit(self, action) -> None:
        """The tick's policy output was used: the history moves on; action (clipped) is the next
        tick's last_action."""
        self.history, self.prev_motor, self.yaw_error = self._pending
        self.last_action = np.asarray(action, np.float64)
