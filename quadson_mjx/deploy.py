"""The policy on the robot: every control tick (20 ms) sensors -> observation -> policy -> gait +
foot offsets -> five-bar IK -> 12 motor targets, exactly as the environment computes them.

    loop = DeployLoop(load_policy("policy.onnx"))       # ONNX Runtime; a .npz runs on numpy alone
    out = loop.step(imu_quat_wxyz, gyro, motor_pos, base_lin_vel, command)   # once per tick
    send(out.motor_targets, out.valid)                  # (12,) [rad], (4,) bool per leg

    python -m quadson_mjx.deploy policy.onnx --bench 2000   # time one step on this computer

Imports numpy, quadson_mjx.robots.quadson.constants / gait_np, quadson_mjx.quat / obs_spec / export
(numpy and array-api-compat) and, for an .onnx, onnxruntime:
no jax, mujoco or brax. The gait, its start ramp and the clamped IK are gait_np's numpy versions of
the simulator's JAX code; the env config (gait, swing, control period, ramp, action scale,
observation options) comes from the metadata the export wrote into the policy file.

Inputs of one step (SI, the body frame: x forward, y left, z up):
  imu_quat_wxyz (4,)  base orientation in a gravity-aligned world frame (z up), w first; the
                      observation's roll, pitch and yaw are its ZYX angles. yaw as the simulator saw
                      it: 0 at the start of the walk (reset the IMU's heading there).
  gyro (3,)           base angular velocity [rad/s], body frame (the IMU's gyroscope).
  motor_pos (12,)     motor angles [rad], legs FL FR RL RR x (motor0, motor1, motor5), the angle
                      convention of constants.py (the encoders, after their zero offsets).
  base_lin_vel (3,)   base linear velocity [m/s], body frame. No sensor measures it: it comes from
                      the robot's state estimator (e.g. leg odometry fused with the accelerometer),
                      which this loop takes as an input and does not provide. The policy observed
                      the simulator's true velocity in training (with noise if randomized).
  command (3,)        (vx [m/s], vy [m/s], yaw rate [rad/s]): sets the gait's step and, for a
                      command-tracking policy, is observed. Default: the gait's seed speed forward
                      (what a policy trained without commands walked at).
Output: StepResult with motor_targets (12,) [rad] in the order of motor_pos, valid (4,) (False: the
leg's foot target was out of reach or beyond a limit and its angles are clamped, as in the
simulator), the action, the observation and the foot targets (4, 3) [m].

The phase clock starts at 0 on reset() and advances one control period per step, as in an episode;
the first gait_ramp_s blend from the home stance into the gait. Call step() every ctrl_dt:
`run_loop` does, on a monotonic clock.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from quadson_mjx import obs_spec
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import gait_np

# --- the policy --------------------------------------------------------------------------------------


class OnnxPolicy:
    """An .onnx export run by ONNX Runtime on one CPU thread: obs (obs_size,) -> action (action_size,)."""

    def __init__(self, path: str | Path, threads: int = 1):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads  # an MLP of 4 x 128: threads would cost more than they save
        opts.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        props = self.session.get_modelmeta().custom_metadata_map
        if "meta_json" not in props:
            raise ValueError(f"{path}: not a quadson_mjx export (no meta_json in its metadata)")
        self.meta = json.loads(props["meta_json"])
        (inp,), (out,) = self.session.get_inputs(), self.session.get_outputs()
        self.obs_size, self.action_size = int(inp.shape[1]), int(out.shape[1])
        self._names = ([out.name], inp.name)

    def __call__(self, obs) -> np.ndarray:
        x = np.asarray(obs, np.float32).reshape(1, self.obs_size)
        return self.session.run(self._names[0], {self._names[1]: x})[0][0]


def load_policy(path: str | Path):
    """An exported policy: .onnx (ONNX Runtime) or .npz (numpy, quadson_mjx.export.NumpyPolicy)."""
    path = Path(path)
    if path.suffix.lower() == ".onnx":
        return OnnxPolicy(path)
    if path.suffix.lower() == ".npz":
        from quadson_mjx import export

        return export.load(path)
    raise ValueError(f"{path}: a policy file is *.onnx or *.npz (python -m quadson_mjx.export)")


# --- the loop ----------------------------------------------------------------------------------------


class LoopConfig(NamedTuple):
    """What the loop needs from the run's env config (export metadata "env_config")."""

    gait: gait_np.Gait
    ctrl_dt: float  # s
    gait_ramp_s: float  # s
    action_scale_m: float  # m per unit action
    command_tracking: bool
    gait_action: bool
    gait_action_range: float

    @classmethod
    def from_env_config(cls, cfg: dict) -> LoopConfig:
        """Raises ValueError for a policy of another robot than Quadson (the loop's gait and IK are
        Quadson's)."""
        robot = cfg.get("robot", "quadson")
        if robot != "quadson":
            raise ValueError(
                f"the deployment loop runs Quadson's gait and five-bar IK; this policy is {robot}'s"
            )
        return cls(
            gait=gait_np.gait_params(cfg["gait"], swing=cfg["swing"], scale=cfg.get("gait_scale")),
            ctrl_dt=float(cfg["ctrl_dt"]),
            gait_ramp_s=float(cfg["gait_ramp_s"]),
            action_scale_m=float(cfg["action_scale_m"]),
            command_tracking=bool(cfg["command_tracking"]),
            gait_action=bool(cfg.get("gait_action", False)),
            gait_action_range=float(cfg.get("gait_action_range", 0.5)),
        )

    @property
    def obs_spec(self) -> obs_spec.Spec:
        """The observation this loop assembles: the environment's (quadson_mjx.obs_spec) for Quadson."""
        return obs_spec.locomotion_observation(C.LEGS, C.MOTOR_JOINTS, self.command_tracking)

    @property
    def action_spec(self) -> obs_spec.Spec:
        return obs_spec.locomotion_action(C.LEGS, self.gait_action, self.action_scale_m)

    @property
    def obs_size(self) -> int:
        return self.obs_spec.size

    @property
    def action_size(self) -> int:
        return self.action_spec.size


class StepResult(NamedTuple):
    motor_targets: np.ndarray  # (12,) [rad], FL FR RL RR x (motor0, motor1, motor5)
    valid: np.ndarray  # (4,) bool per leg: False where the IK clamped the target
    action: np.ndarray  # (action_size,) in [-1, 1]
    obs: np.ndarray  # (obs_size,) float32, what the policy saw
    foot_targets: np.ndarray  # (4, 3) shoulder frames [m], gait + offsets


class DeployLoop:
    """One walk of a policy: the phase clock and the control step. Not thread-safe; one per robot."""

    def __init__(self, policy, config: LoopConfig | None = None):
        self.policy = policy
        self.config = config or LoopConfig.from_env_config(policy.meta["env_config"])
        c = self.config
        self._obs_spec = c.obs_spec
        if (policy.obs_size, policy.action_size) != (c.obs_size, c.action_size):
            raise ValueError(
                f"the policy takes {policy.obs_size} observations and gives {policy.action_size} actions; "
                f"its env config implies {c.obs_size} and {c.action_size}"
            )
        for key, spec in (("obs_spec", c.obs_spec), ("action_spec", c.action_spec)):
            # files exported before the spec existed carry none; their layout is the one above
            if key in policy.meta and obs_spec.Spec.from_json(policy.meta[key]) != spec:
                raise ValueError(
                    f"the policy file's {key} differs from the one this loop builds: "
                    f"file {obs_spec.Spec.from_json(policy.meta[key]).describe()}; loop {spec.describe()}"
                )
        self.default_command = np.array([gait_np.seed_speed(c.gait), 0.0, 0.0])
        self.reset()

    def reset(self) -> None:
        """Restart the phase clock and the start ramp (a new episode)."""
        self.progress = 0.0  # fraction of the gait cycle, as the env's info["gait_progress"]
        self.time_s = 0.0  # time since reset, as info["episode_time"]

    def observation(self, imu_quat_wxyz, gyro, motor_pos, base_lin_vel, command) -> np.ndarray:
        """env._get_obs from sensor readings (see the module docstring): the entries of
        config.obs_spec -> (obs_size,) float32."""
        g = self.config.gait
        phase = 2.0 * np.pi * gait_np.leg_phases(self.progress * g.cycle_s, g)
        parts = {
            "base_rpy": quat_to_rpy(np.asarray(imu_quat_wxyz, np.float64)),
            "base_lin_vel": np.asarray(base_lin_vel, np.float64).reshape(3),
            "base_ang_vel": np.asarray(gyro, np.float64).reshape(3),
            "motor_pos": np.asarray(motor_pos, np.float64).reshape(12),
            "phase_sin": np.sin(phase),
            "phase_cos": np.cos(phase),
        }
        if self.config.command_tracking:
            parts["command"] = np.asarray(command, np.float64).reshape(3)
        return self._obs_spec.assemble(parts).astype(np.float32)

    def targets(self, action, command) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """env._motor_targets at the current clock: -> (motor targets (12,), valid (4,), foot
        targets (4, 3), the cycle time [s] this step runs at)."""
        c = self.config
        action = np.minimum(np.maximum(np.asarray(action, np.float64), -1.0), 1.0)
        g, command = c.gait, np.asarray(command, np.float64)
        if c.gait_action:  # the policy scales step length and cycle frequency
            length_scale = 1.0 + c.gait_action_range * action[12]
            freq_scale = 1.0 + c.gait_action_range * action[13]
            g = g._replace(step_length_m=g.step_length_m * length_scale, cycle_s=g.cycle_s / freq_scale)
            command = command * length_scale * freq_scale
        feet = gait_np.ramped_gait_targets(self.progress, self.time_s, command, g, c.ctrl_dt, c.gait_ramp_s)
        feet = feet + c.action_scale_m * action[:12].reshape(4, 3)
        angles, valid = gait_np.motor_targets(feet)
        return angles.reshape(12), valid, feet, g.cycle_s

    def step(self, imu_quat_wxyz, gyro, motor_pos, base_lin_vel, command=None) -> StepResult:
        """One control tick: observe, act, compute the motor targets, advance the clock."""
        command = self.default_command if command is None else np.asarray(command, np.float64)
        obs = self.observation(imu_quat_wxyz, gyro, motor_pos, base_lin_vel, command)
        action = np.asarray(self.policy(obs), np.float32)
        motor, valid, feet, cycle_s = self.targets(action, command)
        self.progress = (self.progress + self.config.ctrl_dt / cycle_s) % 1.0
        self.time_s += self.config.ctrl_dt
        return StepResult(motor, valid, action, obs, feet)


def run_loop(loop: DeployLoop, read_sensors, send_targets, n_steps: int | None = None, clock=time.monotonic):
    """Every ctrl_dt on `clock`: send_targets(loop.step(**read_sensors())), for n_steps steps (None:
    forever). read_sensors() -> dict of step()'s arguments. A step that overruns its tick is not made
    up: the next step waits for the next tick boundary. -> number of overruns."""
    dt = loop.config.ctrl_dt
    start = clock()
    tick = done = overruns = 0
    while n_steps is None or done < n_steps:
        send_targets(loop.step(**read_sensors()))
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
    feet = gait_np.home_feet()
    motor, _ = gait_np.motor_targets(feet)
    sensors = {
        "imu_quat_wxyz": np.array([1.0, 0.0, 0.0, 0.0]),
        "gyro": np.zeros(3),
        "motor_pos": motor.reshape(12),
        "base_lin_vel": np.zeros(3),
    }
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


def main(argv=None) -> int:
    import argparse
    import sys

    p = argparse.ArgumentParser(prog="python -m quadson_mjx.deploy", description="Time the control step.")
    p.add_argument("policy", help="exported policy, *.onnx or *.npz")
    p.add_argument("--bench", type=int, default=2000, help="steps to time")
    a = p.parse_args(argv)
    if not Path(a.policy).is_file() or a.bench < 1:
        print(f"{p.prog}: error: need an existing policy file and --bench >= 1", file=sys.stderr)
        return 2
    r = bench(a.policy, a.bench)
    print(
        f"{a.policy}: control step median {r['median_ms']:.3f} ms, p99 {r['p99_ms']:.3f} ms, "
        f"max {r['max_ms']:.3f} ms (policy alone {r['policy_median_ms']:.3f} ms), {a.bench} steps"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
