"""The deploy loop as the robot drives it, for sim2sim (the one place that knows the loop's
interface): reset at a walk's start from the encoders with the heading zeroed, one step per control
tick with the sensor readings and the command, the base velocity only for a policy that observes
it, and the gait's phase table at the loop's clock."""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import numpy as np

from quadson_mjx import deploy, obs_spec
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.quat import quat_mul, quat_to_rpy

VELOCITY_SOURCES = obs_spec.VELOCITY_SOURCES


class LoopAdapter:
    """quadson_mjx.deploy's loop for one policy file: reset at the walk's start (encoders, heading),
    step with the sensor readings and the command, the base velocity only for a policy that observes
    it (velocity_source). Works with the loop's present interface and with the planned one
    (reset(motor_pos=...), reset_heading(), step(..., command=None, base_lin_vel=None))."""

    def __init__(self, policy_path, velocity_source: str = "true"):
        if velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"unknown velocity source {velocity_source!r}: {', '.join(VELOCITY_SOURCES)}")
        # a file, or a loaded policy (obs_size, action_size, meta, __call__) as deploy.load_policy gives
        is_path = isinstance(policy_path, str | Path)
        self.policy = deploy.load_policy(policy_path) if is_path else policy_path
        self.meta = self.policy.meta
        self.env_config = self.meta["env_config"]
        self.loop = deploy.DeployLoop(self.policy)
        needs = getattr(self.loop, "needs_lin_vel", None)  # the loop says whether it takes a velocity
        if needs is None:
            spec = obs_spec.Spec.from_json(self.meta["obs_spec"]) if "obs_spec" in self.meta else None
            needs = spec is None or "estimator" in spec.sensors()  # files without a spec: true_state
        self.observes_velocity = bool(needs)
        self.velocity_source = velocity_source if self.observes_velocity else "none"
        self._reset_takes_motor = "motor_pos" in inspect.signature(self.loop.reset).parameters
        self._heading = np.array([1.0, 0.0, 0.0, 0.0])  # applied to the IMU while the loop has no reset

    @property
    def ctrl_dt(self) -> float:
        return float(self.env_config["ctrl_dt"])

    @property
    def tracks_commands(self) -> bool:
        """The policy observes a command (else it was trained on its gait's own forward command)."""
        return bool(self.env_config.get("command_tracking", False))

    @property
    def gait_command(self) -> tuple[float, float, float]:
        """Forward at the gait's own speed: the command a policy without commands walked at."""
        return tuple(float(x) for x in self.loop.gait_command)

    def scheduled_stance(self) -> np.ndarray:
        """(4,) bool: the gait's phase table puts each leg in stance at the loop's phase clock now
        (after a step: its end, as the env's scheduled_stance of info["gait_progress"])."""
        r = self.loop.config.robot
        return r.leg_phases(self.loop.progress * r.gait.cycle_s, r.gait) < r.gait.duty

    def reset(self, readings: P.Readings) -> None:
        if self._reset_takes_motor:
            self.loop.reset(motor_pos=readings.motor_pos)
        else:
            self.loop.reset()
        if hasattr(self.loop, "reset_heading"):
            self.loop.reset_heading(readings.imu_quat_wxyz)
        else:  # the loop expects yaw 0 at the walk's start: the robot's code zeroes the IMU heading
            yaw = float(quat_to_rpy(readings.imu_quat_wxyz)[2])
            self._heading = np.array([math.cos(-yaw / 2), 0.0, 0.0, math.sin(-yaw / 2)])

    def step(self, readings: P.Readings, command, true_lin_vel):
        kw = {
            "imu_quat_wxyz": quat_mul(self._heading, readings.imu_quat_wxyz),
            "gyro": readings.gyro,
            "motor_pos": readings.motor_pos,
            "command": command,
        }
        if self.observes_velocity:
            kw["base_lin_vel"] = {
                "true": true_lin_vel,
                "zero": np.zeros(3),
                "command": np.array([command[0], command[1], 0.0]),
            }[self.velocity_source]
        return self.loop.step(**kw)

    @staticmethod
    def faulty(out) -> bool:
        """The safety layer held or homed the motors this tick (a loop without one: never)."""
        fault = getattr(out, "fault", None)
        return fault is not None and str(fault) != "ok"
