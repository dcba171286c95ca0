"""The policy on the robot: every control tick (20 ms) sensors -> observation -> policy -> gait +
foot offsets -> IK (Quadson's five-bar, Caramel's serial legs) -> safety layer -> 12 motor targets,
as the environment computes them.

    loop = DeployLoop(load_policy("policy.onnx"))      # the robot, gait and observation from the file
    loop.reset(motor_pos=encoders)                     # a walk starts from the encoders' reading
    loop.imu_calibration = deploy_imu.calibrate_imu(quats, gyros)  # once, standing still, level
    loop.reset_heading()                               # the IMU's yaw now is 0 (true_state policies)
    out = loop.step(imu_quat_wxyz, gyro, motor_pos, command=(0.3, 0.0, 0.0))   # once per tick
    send(out.motor_targets)                            # (12,) [rad]: always finite, in the limits

    python -m quadson_mjx.deploy policy.onnx --bench 2000   # check the file, time one step here

Imports numpy, quadson_mjx.quat / obs_spec / export / deploy_* and the robot's numpy gait
(robots/quadson/gait_np.py, robots/caramel/gait_np.py) and, for an .onnx, onnxruntime: no jax,
mujoco or brax. The env config (robot, gait, control period, ramp, action scale, observation) comes
from the metadata the export wrote into the policy file.

Inputs of one step (SI, the body frame: x forward, y left, z up), each of exactly its length
(ValueError otherwise):
  imu_quat_wxyz (4,)  base orientation in a gravity-aligned world frame (z up), w first.
  gyro (3,)           base angular velocity [rad/s], body frame.
  motor_pos (12,)     encoder angles [rad] in the file's motor order (metadata "motors"), the angle
                      convention of the robot's constants (after the encoders' zero offsets).
  command (3,)        (vx [m/s], vy [m/s], yaw rate [rad/s]); None: stand still (zero command).
                      A command-tracking policy observes it (clipped to the trained command range);
                      for a policy trained without commands it only sets the gait's step: pass
                      loop.gait_command for the speed it was trained at.
  base_lin_vel (3,)   only for a policy whose observation has an "estimator" entry (the old
                      true_state policies): the base velocity [m/s] from a state estimator. A
                      sensor-only policy refuses it.
The observation is built from the file's spec (quadson_mjx.obs_spec) as deploy_observation does.
Output: StepResult (motor_targets, valid, action, obs (alias observation), foot_targets, fault).

The phase clock starts at 0 on reset() and advances one control period per step that runs the
policy (it stops while a fault holds). The first gait_ramp_s blend from the home stance into the
gait as in an episode; the encoders' offset from the home stance at reset() fades out with the same
smoothstep, so a walk starts from where the motors are (see reset()).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from quadson_mjx import obs_spec
from quadson_mjx.deploy_imu import ImuCalibration, calibrate_imu, needs_calibration
from quadson_mjx.deploy_observation import ObservationBuilder
from quadson_mjx.deploy_policy import check_buildable, check_meta, load_policy
from quadson_mjx.deploy_robots import RobotKinematics, robot_kinematics
from quadson_mjx.deploy_safety import Fault, SafetyConfig, SafetyLayer, as_vector, check_sensors

__all__ = ["DeployLoop", "Fault", "LoopConfig", "SafetyConfig", "StepResult", "load_policy", "run_loop"]


class LoopConfig(NamedTuple):
    """What the loop needs from the run's env config (export metadata "env_config")."""

    robot: RobotKinematics
    ctrl_dt: float  # s
    gait_ramp_s: float  # s
    action_scale_m: float  # m per unit action
    command_tracking: bool
    gait_action: bool
    gait_action_range: float
    observation: str  # "sensors" or "true_state" (env_config.OBSERVATIONS)
    obs_history: int
    yaw_error_tau_s: float  # s; 0: no yaw_error entry (obs_spec.yaw_error_step)
    observe_servo_latency: bool  # the servo_latency entry (obs_spec.SERVO_LATENCY)
    command_range: np.ndarray  # (3, 2) the trained command range (vx, vy, yaw rate)

    @classmethod
    def from_env_config(cls, cfg: dict, meta: dict | None = None) -> LoopConfig:
        """cfg: the env config as a dict; meta: the file's metadata (Caramel's geometry and gait)."""
        rng = cfg.get("command_range", {})
        return cls(
            robot=robot_kinematics(cfg, meta),
            ctrl_dt=float(cfg["ctrl_dt"]),
            gait_ramp_s=float(cfg["gait_ramp_s"]),
            action_scale_m=float(cfg["action_scale_m"]),
            command_tracking=bool(cfg["command_tracking"]),
            gait_action=bool(cfg.get("gait_action", False)),
            gait_action_range=float(cfg.get("gait_action_range", 0.5)),
            observation=str(cfg.get("observation", "true_state")),
            obs_history=int(cfg.get("obs_history", 1)),
            yaw_error_tau_s=float(cfg.get("yaw_error_tau_s", 0.0)),
            observe_servo_latency=bool(cfg.get("observe_servo_latency", False)),
            command_range=np.array([rng.get(k, (-np.inf, np.inf)) for k in ("vx", "vy", "yaw_rate")], float),
        )

    @property
    def gait(self):
        return self.robot.gait

    @property
    def obs_spec(self) -> obs_spec.Spec:
        """The observation this loop assembles: the environment's (quadson_mjx.obs_spec)."""
        r = self.robot
        if self.observation == "sensors":
            return obs_spec.sensor_observation(
                r.legs,
                r.motor_names,
                self.action_size,
                self.obs_history,
                self.command_tracking,
                yaw_error=bool(self.yaw_error_tau_s),
                servo_latency=self.observe_servo_latency,
            )
        return obs_spec.locomotion_observation(r.legs, r.motor_names, self.command_tracking)

    @property
    def action_spec(self) -> obs_spec.Spec:
        return obs_spec.locomotion_action(self.robot.legs, self.gait_action, self.action_scale_m)

    @property
    def obs_size(self) -> int:
        return self.obs_spec.size

    @property
    def action_size(self) -> int:
        return self.action_spec.size


class StepResult(NamedTuple):
    motor_targets: np.ndarray  # (12,) [rad] to send: finite, in the limits, rate-limited
    valid: np.ndarray  # (4,) bool per leg: the IK solved the policy's target (False on a fault tick)
    action: np.ndarray  # (action_size,) in [-1, 1] (the last one on a fault tick)
    obs: np.ndarray  # (obs_size,) float32, what the policy saw (the last one on a fault tick)
    foot_targets: np.ndarray  # (4, 3) gait frames [m], gait + offsets
    fault: Fault = Fault.OK  # the safety layer's state this tick (deploy_safety.Fault, a str)

    @property
    def observation(self) -> np.ndarray:
        return self.obs


def _servo_latency_range(meta: dict) -> tuple[float, float]:
    """The measured servo latencies [s] a policy was trained to observe: the trained actuation
    latency range widened by the calibration's error (export metadata "trained_sensor_model")."""
    trained = meta.get("trained_sensor_model") or {}
    lo, hi = trained.get("actuation_latency_s") or (0.0, 0.0)
    error = float((trained.get("sensor") or {}).get("servo_latency_error_s", 0.0))
    return max(float(lo) - error, 0.0), float(hi) + error


def _smoothstep(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


class DeployLoop:
    """One walk of a policy: phase clock, observation history, safety layer. Not thread-safe; one
    per robot. safety: deploy_safety.SafetyConfig (default: its defaults, the robot's servo speed)."""

    def __init__(self, policy, config: LoopConfig | None = None, safety: SafetyConfig | None = None):
        self.policy = policy
        meta = getattr(policy, "meta", {})
        self.config = c = config or LoopConfig.from_env_config(meta["env_config"], meta)
        if (policy.obs_size, policy.action_size) != (c.obs_size, c.action_size):
            raise ValueError(
                f"the policy takes {policy.obs_size} observations and gives {policy.action_size} actions; "
                f"its env config implies {c.obs_size} and {c.action_size}"
            )
        if "format_version" in meta:
            check_meta(meta, "policy")
        for key, spec in (("obs_spec", c.obs_spec), ("action_spec", c.action_spec)):
            # files exported before the spec existed carry none; their layout is the one above
            if key in meta and obs_spec.Spec.from_json(meta[key]) != spec:
                raise ValueError(
                    f"the policy file's {key} differs from the one this loop builds: "
                    f"file {obs_spec.Spec.from_json(meta[key]).describe()}; loop {spec.describe()}"
                )
        check_buildable(c.obs_spec)
        self.needs_lin_vel = "estimator" in c.obs_spec.sensors()
        # trained for a calibrated IMU (deploy_imu.needs_calibration): no walk before imu_calibration
        self.needs_imu_calibration = needs_calibration(meta)
        # observes the servos' latency measured on the robot: no walk before servo_latency_s is set
        self.needs_servo_latency = "servo_latency" in {e.name for e in c.obs_spec.entries}
        self.servo_latency_range = _servo_latency_range(meta) if self.needs_servo_latency else None
        r = c.robot
        safety = safety or SafetyConfig()
        if safety.max_rate_rps is None:
            safety = safety._replace(max_rate_rps=r.servo_speed_rps)
        self.safety = SafetyLayer(safety, r.motor_limits, r.home_motor, c.ctrl_dt, clamp=r.clamp)
        self.observer = ObservationBuilder(c.obs_spec, r, c.action_size, c.yaw_error_tau_s)
        # the command a policy trained without commands walked at (the gait's own speed)
        self.gait_command = np.array([r.seed_speed, 0.0, 0.0])
        self.reset()

    # --- the walk's state ---------------------------------------------------------------------------
    def reset(self, motor_pos=None) -> None:
        """A new walk: phase clock and start ramp to 0, observation history and last action cleared,
        the safety layer's targets set to motor_pos (12,) [rad] (the encoders now; None: the home
        stance). The encoders' offset from the home stance is added to the targets and fades out
        with the env's start-ramp smoothstep, so the first tick's targets are the encoders' reading
        plus the env's first move from home. ValueError for a wrong length, a non-finite reading
        or one beyond the limits by more than the safety margin."""
        r = self.config.robot
        start = r.home_motor.copy()
        if motor_pos is not None:
            start = as_vector(motor_pos, 12, "motor_pos")
            why = check_sensors(self.safety.cfg, r.motor_limits, np.array([1.0, 0, 0, 0]), np.zeros(3), start)
            if why:
                raise ValueError(f"reset(motor_pos): the encoder reading is not usable ({', '.join(why)})")
            start = r.clamp(start)
        self._restart(start)
        self.safety.reset(start)

    def _restart(self, start) -> None:
        self.progress = 0.0  # fraction of the gait cycle, as the env's info["gait_progress"]
        self.time_s = 0.0  # time since reset, as info["episode_time"]
        self.start_offset = np.asarray(start, np.float64) - self.config.robot.home_motor
        self.observer.reset()
        self._last = (
            np.zeros(self.config.action_size, np.float32),
            np.zeros(self.config.obs_size, np.float32),
            self.config.robot.home_feet.copy(),
        )

    @property
    def imu_calibration(self):
        """deploy_imu.ImuCalibration taken out of every IMU reading the policy observes (the safety
        checks see the raw readings), or None (the default)."""
        return self.observer.imu_calibration

    @imu_calibration.setter
    def imu_calibration(self, cal) -> None:
        if cal is not None and not isinstance(cal, ImuCalibration):
            raise ValueError(
                f"imu_calibration: a deploy_imu.ImuCalibration or None, not {type(cal).__name__}"
            )
        self.observer.imu_calibration = cal

    @property
    def servo_latency_s(self):
        """The servos' actuation latency measured on the robot [s] (a policy whose observation has
        a servo_latency entry), or None (the default)."""
        return self.observer.servo_latency_s

    @servo_latency_s.setter
    def servo_latency_s(self, latency_s) -> None:
        if not self.needs_servo_latency:
            raise ValueError("servo_latency_s: this policy does not observe the servos' latency")
        lo, hi = self.servo_latency_range
        value = float(latency_s)
        if not lo <= value <= hi:  # also refuses NaN
            raise ValueError(
                f"servo_latency_s {value!r}: the policy was trained for a measured latency in "
                f"[{lo:g}, {hi:g}] s"
            )
        self.observer.servo_latency_s = value

    def reset_heading(self, imu_quat_wxyz=None) -> None:
        """The IMU's yaw becomes 0: the given orientation's, else the last step's, else the next
        step's. Roll and pitch are kept; only a true_state policy observes yaw."""
        self.observer.reset_heading(imu_quat_wxyz)

    @property
    def fault_counts(self) -> dict:
        """Reason -> ticks it was seen since the loop was made: deploy_safety.check_sensors' names
        (imu_nonfinite, imu_quat_norm, gyro_*, encoder_*, lin_vel_*), command_nonfinite,
        policy_nonfinite, no_sensors / sensor_read_error, ik_invalid_leg, ik_invalid_persistent,
        ik_invalid_all, ik_clamped_leg (ik_invalid="clamp")."""
        return dict(self.safety.counts)

    @property
    def fault_ticks(self) -> int:
        """Ticks spent in hold, easing_home or home."""
        return self.safety.fault_ticks

    # --- one tick ------------------------------------------------------------------------------------
    def observation(self, imu_quat_wxyz, gyro, motor_pos, base_lin_vel=None, command=None) -> np.ndarray:
        """The observation step() would build now from these readings (no checks, the history
        unchanged) -> (obs_size,) float32."""
        c = self.config
        quat = as_vector(imu_quat_wxyz, 4, "imu_quat_wxyz")
        command = np.zeros(3) if command is None else as_vector(command, 3, "command")
        lin_vel = None if base_lin_vel is None else as_vector(base_lin_vel, 3, "base_lin_vel")
        gyro, motor_pos = as_vector(gyro, 3, "gyro"), as_vector(motor_pos, 12, "motor_pos")
        return self.observer.observe(quat, gyro, motor_pos, command, lin_vel, self.progress, c.ctrl_dt)

    def targets(self, action, command) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """env._motor_targets at the current clock (before the safety layer): -> (motor targets
        (12,) [rad], valid (4,), foot targets (4, 3), the cycle time [s] this step runs at)."""
        c, r = self.config, self.config.robot
        action = np.minimum(np.maximum(np.asarray(action, np.float64), -1.0), 1.0)
        g, command = r.gait, np.asarray(command, np.float64)
        if c.gait_action:  # the policy scales step length and cycle frequency
            length_scale = 1.0 + c.gait_action_range * action[12]
            freq_scale = 1.0 + c.gait_action_range * action[13]
            g = r.scaled_gait(length_scale, freq_scale)
            command = command * length_scale * freq_scale
        s = _smoothstep((self.time_s + c.ctrl_dt) / c.gait_ramp_s)
        gait = r.foot_targets(self.progress * g.cycle_s, command, g)
        feet = r.home_feet + s * (gait - r.home_feet)
        feet = feet + c.action_scale_m * action[:12].reshape(4, 3)
        angles, valid = r.motor_targets(feet)
        angles = angles.reshape(12)
        if s < 1.0 and np.any(self.start_offset):
            angles = r.clamp(angles + (1.0 - s) * self.start_offset)
        return angles, valid, feet, g.cycle_s

    def step(self, imu_quat_wxyz, gyro, motor_pos, command=None, base_lin_vel=None) -> StepResult:
        """One control tick: check, observe, act, compute and filter the motor targets."""
        c = self.config
        quat = as_vector(imu_quat_wxyz, 4, "imu_quat_wxyz")
        gyro = as_vector(gyro, 3, "gyro")
        motor_pos = as_vector(motor_pos, 12, "motor_pos")
        command = np.zeros(3) if command is None else as_vector(command, 3, "command")
        if base_lin_vel is not None:
            if not self.needs_lin_vel:
                raise ValueError("base_lin_vel: this policy observes only the robot's sensors; pass none")
            base_lin_vel = as_vector(base_lin_vel, 3, "base_lin_vel")
        elif self.needs_lin_vel:
            raise ValueError(
                "base_lin_vel is required: this policy observes the base velocity (an estimator's)"
            )
        if self.needs_imu_calibration and self.imu_calibration is None:
            tilt = self.policy.meta["trained_sensor_model"]["sensor"]["imu_tilt_rad"]
            raise ValueError(
                f"this policy was trained for a calibrated IMU (mounting tilt within {tilt} rad): set "
                "loop.imu_calibration = deploy_imu.calibrate_imu(quats, gyros) from the robot standing "
                "still on level ground first"
            )
        if self.needs_servo_latency and self.servo_latency_s is None:
            raise ValueError(
                "this policy observes the servos' latency: set loop.servo_latency_s to the latency "
                "measured on the robot first"
            )
        reasons = check_sensors(self.safety.cfg, c.robot.motor_limits, quat, gyro, motor_pos, base_lin_vel)
        if not np.all(np.isfinite(command)):
            reasons.append("command_nonfinite")
        if reasons:
            return self._fault(reasons)
        if self.safety.restart_needed:  # back from a long fault: a new walk from where the motors are
            self._restart(c.robot.clamp(motor_pos))
        if c.command_tracking:
            command = np.minimum(np.maximum(command, c.command_range[:, 0]), c.command_range[:, 1])
        resync = self.safety.in_fault
        obs = self.observer.observe(
            quat, gyro, motor_pos, command, base_lin_vel, self.progress, c.ctrl_dt, resync
        )
        action = np.asarray(self.policy(obs), np.float32).reshape(-1)
        if action.shape != (c.action_size,) or not np.all(np.isfinite(action)):
            return self._fault(["policy_nonfinite"])
        motor, valid, feet, cycle_s = self.targets(action, command)
        sent, fault = self.safety.filter(motor, valid)
        action = np.minimum(np.maximum(action, -1.0), 1.0)
        self.observer.commit(action)
        self.progress = (self.progress + c.ctrl_dt / cycle_s) % 1.0
        self.time_s += c.ctrl_dt
        self._last = (action, obs, feet)
        return StepResult(sent, valid, action, obs, feet, fault)

    def _fault(self, reasons) -> StepResult:
        sent, fault = self.safety.filter(None, None, reasons)
        action, obs, feet = self._last
        return StepResult(sent, np.zeros(4, bool), action, obs, feet, fault)

    def step_without_sensors(self, reason: str = "no_sensors") -> StepResult:
        """A tick whose sensors could not be read: hold, then ease home (the safety layer)."""
        return self._fault([reason])


def run_loop(loop: DeployLoop, read_sensors, send_targets, n_steps: int | None = None, clock=time.monotonic):
    """Every ctrl_dt on `clock`: send_targets(loop.step(**read_sensors())), for n_steps steps (None:
    forever). read_sensors() -> dict of step()'s arguments; when it raises an Exception the tick
    holds (loop.step_without_sensors). Only the safety layer's targets are sent (StepResult's
    motor_targets: finite, in the limits). A step that overruns its tick is not made up: the next
    step waits for the next tick boundary. -> number of overruns."""
    dt = loop.config.ctrl_dt
    start = clock()
    tick = done = overruns = 0
    while n_steps is None or done < n_steps:
        try:
            sensors = read_sensors()
        except Exception:  # a bus error must not stop the servos' targets coming
            out = loop.step_without_sensors("sensor_read_error")
        else:
            out = loop.step(**sensors)
        send_targets(out)
        done += 1
        tick += 1
        now = clock()
        if now > start + tick * dt:
            overruns += 1
            tick = int((now - start) // dt) + 1
        time.sleep(max(0.0, start + tick * dt - now))
    return overruns


def bench(path: str | Path, n_steps: int = 2000) -> dict:
    """Times DeployLoop.step on this computer with the home pose as the sensor reading ->
    {"median_ms", "p99_ms", "max_ms", "policy_median_ms"} over n_steps steps."""
    loop = DeployLoop(load_policy(path))
    sensors = {
        "imu_quat_wxyz": np.array([1.0, 0.0, 0.0, 0.0]),
        "gyro": np.zeros(3),
        "motor_pos": loop.config.robot.home_motor.copy(),
    }
    if loop.needs_lin_vel:
        sensors["base_lin_vel"] = np.zeros(3)
    if loop.needs_servo_latency:  # any value in the trained range times the same
        loop.servo_latency_s = sum(loop.servo_latency_range) / 2
    if loop.needs_imu_calibration:  # the level, still reading the bench feeds: no correction
        loop.imu_calibration = calibrate_imu(np.tile(sensors["imu_quat_wxyz"], (50, 1)), np.zeros((50, 3)))
    for _ in range(50):  # warm-up: first calls allocate
        loop.step(**sensors)
    steps, policy = [], []
    for _ in range(n_steps):
        t0 = time.perf_counter()
        out = loop.step(**sensors)
        t1 = time.perf_counter()
        loop.policy(out.obs)
        policy.append(time.perf_counter() - t1)
        steps.append(t1 - t0)
    ms = np.asarray(steps) * 1e3
    return {
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "policy_median_ms": float(np.median(policy) * 1e3),
    }


def describe(loop: DeployLoop) -> str:
    """One line: robot, observation, sizes, control period, and what the loop needs besides the
    sensors (an estimator's base velocity, an IMU calibration)."""
    c = loop.config
    needs = [
        *(["base_lin_vel from an estimator"] if loop.needs_lin_vel else []),
        *(["an IMU calibration (loop.imu_calibration)"] if loop.needs_imu_calibration else []),
        *(["the servos' measured latency (loop.servo_latency_s)"] if loop.needs_servo_latency else []),
    ]
    return (
        f"{c.robot.name}, {c.observation} observation ({c.obs_size} values), {c.action_size} actions, "
        f"ctrl_dt {c.ctrl_dt} s, rate limit {loop.safety.cfg.max_rate_rps:g} rad/s"
        + (f"; needs {' and '.join(needs)}" if needs else "")
    )


def main(argv=None) -> int:
    from quadson_mjx.errors import UsageError, one_line_errors

    @one_line_errors
    def run(argv):
        from quadson_mjx.errors import ArgumentParser

        p = ArgumentParser(
            prog="python -m quadson_mjx.deploy", description="Check a policy file and time the control step."
        )
        p.add_argument("policy", help="exported policy, *.onnx or *.npz")
        p.add_argument("--bench", type=int, default=2000, help="steps to time")
        a = p.parse_args(argv)
        if a.bench < 1:
            raise UsageError(f"--bench {a.bench}: need at least 1 step")
        try:
            loop = DeployLoop(load_policy(a.policy))
        except ValueError as e:
            raise UsageError(str(e)) from None
        r = bench(a.policy, a.bench)
        print(f"{a.policy}: {describe(loop)}")
        print(
            f"{a.policy}: control step median {r['median_ms']:.3f} ms, p99 {r['p99_ms']:.3f} ms, "
            f"max {r['max_ms']:.3f} ms (policy alone {r['policy_median_ms']:.3f} ms), {a.bench} steps"
        )
        return 0

    return run(argv)


if __name__ == "__main__":
    raise SystemExit(main())
