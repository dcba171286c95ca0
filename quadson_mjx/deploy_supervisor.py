"""Getting up after a fall, on the robot: a supervisor over two loaded policies, the walking loop
(quadson_mjx.deploy.DeployLoop) and a get-up policy, that detects a fall from the IMU, hands the
motors to the get-up policy and back to walking once the robot stands.

    sup = Supervisor(DeployLoop(load_policy("walk.onnx")), load_policy("getup.onnx"))
    sup.reset(motor_pos=encoders)
    out = sup.step(imu_quat_wxyz, gyro, motor_pos, command=(0.3, 0.0, 0.0))   # once per tick
    send(out.motor_targets)                                 # (12,) [rad]; out.mode says who drives

Modes (Mode, a str), one per tick; tilt = the angle between the body's z axis and the world's
vertical, from the IMU quaternion (yaw-independent):
  walking        the walking loop drives. A tilt above fall_tilt_rad for fall_confirm_s -> fallen.
  fallen         the targets sent before the fall are held for settle_s (the robot comes to rest)
                 -> getting_up, a new attempt.
  getting_up     the get-up policy drives. Tilt at or below upright_tilt_rad -> standing_hold.
  standing_hold  the get-up policy still drives; after stand_dwell_s without a tick above
                 upright_tilt_rad -> walking (the walking loop restarts from the targets sent last,
                 its heading reset to the IMU's yaw then, as at the start of a walk).
                 A tilt above hold_exit_tilt_rad -> getting_up (the same attempt).
  resting        an attempt that has not reached walking within getup_timeout_s (counted in
                 getting_up and standing_hold; not while a dwell is running): the targets ease to
                 the rest pose over rest_ease_s and stay there until rest_s has passed -> getting_up,
                 a new attempt.
The thresholds form a hysteresis: walking is left above fall_tilt_rad and re-entered only after a
dwell below upright_tilt_rad, so a tilt oscillating around either threshold does not switch back
and forth. Every switch starts a blend: the targets go from the ones sent last to the new
controller's with a smoothstep over blend_s (rest_ease_s into the rest pose), so no switch jumps.

The get-up policy's observation (obs_spec.getup_observation, 30 values): gravity (3) the unit
gravity direction in the body frame from the IMU quaternion, gyro (3) [rad/s], motor_pos (12) the
encoders [rad], last_action (12) its previous action (0 at the start of an attempt). Its action
(obs_spec.getup_action): 12 values in [-1, 1], motor targets from the home stance (0) to each
motor's limits (-1, +1), inside the toe-in guard and the five-bar's assembly band (`getup_targets`,
chain_guard), then the robot's clamp and a safety layer
(deploy_safety: rate limit, hold and ease home on a fault) as the walking loop's.

Bad input: a tick whose sensors fail deploy_safety.check_sensors (a NaN IMU, a zero quaternion, an
encoder beyond its limit) changes no mode and no timer; while walking it takes the walking loop's
safety path, otherwise the supervisor's own safety layer holds, then eases home; the first good
tick after a fault that reached the ease blends from there to the mode's targets over blend_s.

Numpy only (and what the two policies need), like the walking loop.
"""

from __future__ import annotations

import dataclasses
import math
from enum import StrEnum
from typing import NamedTuple

import numpy as np

from quadson_mjx import obs_spec
from quadson_mjx.deploy_observation import ObservationBuilder
from quadson_mjx.deploy_safety import Fault, SafetyLayer, as_vector, check_sensors
from quadson_mjx.quat import quat_rotate_inverse
from quadson_mjx.robots.quadson import chain_guard, mirror

__all__ = [
    "GetupPolicy",
    "Mode",
    "Supervisor",
    "SupervisorConfig",
    "SupervisorResult",
    "getup_targets",
    "tilt",
]


class Mode(StrEnum):
    WALKING = "walking"
    FALLEN = "fallen"
    GETTING_UP = "getting_up"
    STANDING_HOLD = "standing_hold"
    RESTING = "resting"


@dataclasses.dataclass(frozen=True)
class SupervisorConfig:
    """Thresholds of the supervisor, SI. Checked when built: ValueError (one line) naming the value."""

    # The fall is handed to the get-up policy early and at once, for a policy trained to catch
    # falls (the get-up task's toppled starts): held targets and a slow blend let a knocked robot
    # roll onto its back. Walking on the stone field with randomization and pushes tilted the base
    # by at most 6.5 deg (`quadson-knockdown --knock none --pushes --terrain stones`: 20 walks of
    # 17 s, no false alarm), so 25 deg leaves a margin of 3.8. Knock-downs in docs/getup.md
    # ("Knocked down while walking") compare these values with 50 deg, 0.1 s, 0.3 s of settling
    # and 0.25 s blends.
    fall_tilt_rad: float = math.radians(25.0)  # walking -> fallen above this tilt
    fall_confirm_s: float = 0.0  # ... held this long (0: the first tick above)
    upright_tilt_rad: float = math.radians(12.0)  # getting_up -> standing_hold at or below this tilt
    hold_exit_tilt_rad: float = math.radians(20.0)  # standing_hold -> getting_up above this tilt
    stand_dwell_s: float = 1.0  # upright this long in standing_hold -> walking
    settle_s: float = 0.0  # fallen: the targets held before the get-up starts
    getup_timeout_s: float = 6.0  # an attempt not walking by then -> resting
    rest_s: float = 2.0  # resting lasts this long, then a new attempt
    rest_ease_s: float = 1.0  # the blend into the rest pose (<= rest_s)
    blend_s: float = 0.05  # the blend at every other switch

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ValueError(f"SupervisorConfig.{f.name} must be a finite number >= 0, got {v!r}")
        for name in ("fall_tilt_rad", "upright_tilt_rad", "hold_exit_tilt_rad", "blend_s", "rest_ease_s"):
            if getattr(self, name) == 0:
                raise ValueError(f"SupervisorConfig.{name} must be > 0, got 0")
        if not self.upright_tilt_rad < self.hold_exit_tilt_rad < self.fall_tilt_rad <= math.pi:
            raise ValueError(
                "SupervisorConfig: need upright_tilt_rad < hold_exit_tilt_rad < fall_tilt_rad <= pi, got "
                f"{self.upright_tilt_rad:g} < {self.hold_exit_tilt_rad:g} < {self.fall_tilt_rad:g}"
            )
        if self.rest_ease_s > self.rest_s:
            raise ValueError(
                f"SupervisorConfig.rest_ease_s {self.rest_ease_s:g} exceeds rest_s {self.rest_s:g}"
            )
        if self.stand_dwell_s >= self.getup_timeout_s:
            raise ValueError(
                f"SupervisorConfig.stand_dwell_s {self.stand_dwell_s:g} must be below getup_timeout_s "
                f"{self.getup_timeout_s:g}"
            )

    def ticks(self, name: str, ctrl_dt: float) -> int:
        """Duration `name` [s] in control ticks, rounded up (a tick holds ctrl_dt)."""
        return int(math.ceil(getattr(self, name) / ctrl_dt - 1e-9))


class SupervisorResult(NamedTuple):
    motor_targets: np.ndarray  # (12,) [rad] to send: finite, in the limits, rate-limited
    mode: Mode  # who drove this tick
    tilt_rad: float  # the IMU's tilt this tick [rad] (nan on a tick with bad sensors)
    fault: Fault  # the safety layer's state this tick (the walking loop's while walking)
    action: np.ndarray | None  # the get-up policy's action (12,), None on other ticks


_DOWN = np.array([0.0, 0.0, -1.0])


def tilt(imu_quat_wxyz) -> float:
    """Angle [rad] between the body's z axis and the world's vertical, in [0, pi]: acos of the
    gravity direction's body z component (0 upright, pi on the back)."""
    q = np.asarray(imu_quat_wxyz, np.float64)
    g = quat_rotate_inverse(q / np.linalg.norm(q), _DOWN)
    return float(np.arccos(np.clip(-g[2], -1.0, 1.0)))


def getup_targets(action, home_motor) -> np.ndarray:
    """action (12,) in [-1, 1] (clipped), home_motor (12,) [rad] -> motor targets (12,) [rad]: 0 the
    home stance, -1 / +1 each motor's lower / upper limit, then the toe-in guard and the five-bar's
    assembly band (chain_guard.getup_targets, as the get-up environment computes them)."""
    targets, _ = chain_guard.getup_targets(np.asarray(action, np.float64), np.asarray(home_motor, np.float64))
    return targets


class GetupPolicy:
    """A loaded get-up policy and its observation: policy(obs (30,)) -> action (12,) (an exported
    file from deploy_policy.load_policy, or any callable with obs_size, action_size and, optionally,
    meta). robot: the walking loop's RobotKinematics (motor names, limits, clamp).

    mirror_to "left" (or "right"): an attempt whose first tick has the body's right (left) side
    lower, gravity's body y below (above) 0, runs the policy on the robot's mirror image
    (robots.quadson.mirror: observation mirrored in, action mirrored out), so that it always meets
    the fall of the side it gets up from better; None: never; mirror.TRAINED (the default): the side
    the policy was trained on (its file's env.getup.mirror_to; None for a policy trained on both
    sides). A policy trained on one side refuses another mirror_to (mirror.resolve_mirror_to)."""

    def __init__(self, policy, robot, ctrl_dt: float, mirror_to: str | None = mirror.TRAINED):
        self.mirrored: bool | None = None  # this attempt's choice; None until its first tick
        self.policy, self.robot, self.ctrl_dt = policy, robot, float(ctrl_dt)
        self.obs_spec = obs_spec.getup_observation(robot.motor_names)
        self.action_spec = obs_spec.getup_action(robot.motor_names)
        sizes = (getattr(policy, "obs_size", None), getattr(policy, "action_size", None))
        if sizes != (self.obs_spec.size, self.action_spec.size):
            raise ValueError(
                f"get-up policy: takes {sizes[0]} observations and gives {sizes[1]} actions; "
                f"the get-up task has {self.obs_spec.size} and {self.action_spec.size}"
            )
        meta = getattr(policy, "meta", None) or {}
        self.mirror_to = mirror.resolve_mirror_to(mirror_to, mirror.trained_mirror_to(meta.get("env_config")))
        for key, spec in (("obs_spec", self.obs_spec), ("action_spec", self.action_spec)):
            if key in meta and obs_spec.Spec.from_json(meta[key]) != spec:
                raise ValueError(
                    f"get-up policy: the file's {key} is not the get-up task's: file "
                    f"{obs_spec.Spec.from_json(meta[key]).describe()}; task {spec.describe()}"
                )
        self.observer = ObservationBuilder(self.obs_spec, robot, self.action_spec.size)

    def reset(self) -> None:
        """A new attempt: last action 0; mirrored or not is decided on its first tick."""
        self.observer.reset()
        self.mirrored = None

    def act(self, quat, gyro, motor_pos, resync: bool = False):
        """Checked readings -> (motor targets (12,) [rad] clamped, action (12,), obs (30,)), or None
        when the policy's output is not 12 finite numbers. action and obs are the robot's (not
        mirrored)."""
        obs = self.observer.observe(quat, gyro, motor_pos, np.zeros(3), None, 0.0, self.ctrl_dt, resync)
        if self.mirrored is None:
            self.mirrored = bool(mirror.wants_mirror(float(obs[1]), self.mirror_to))  # gravity.y
        seen = mirror.mirror_getup_observation(obs) if self.mirrored else obs
        action = np.asarray(self.policy(seen), np.float32).reshape(-1)
        if action.shape != (self.action_spec.size,) or not np.all(np.isfinite(action)):
            return None
        action = np.clip(action, -1.0, 1.0)
        if self.mirrored:
            action = mirror.mirror_motors(action)
        self.observer.commit(action)
        targets = getup_targets(action, self.robot.home_motor)
        return self.robot.clamp(targets), action, obs


def _smoothstep(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


class Supervisor:
    """Walking, fall detection, get-up and back (see the module's docstring). Not thread-safe; one
    per robot. walking: a DeployLoop; getup_policy: a loaded get-up policy (or a GetupPolicy);
    rest_motor (12,) [rad]: the pose of resting (default the walking loop's home stance);
    getup_mirror_to: GetupPolicy's mirror_to for a loaded get-up policy (default: as trained)."""

    def __init__(
        self,
        walking,
        getup_policy,
        config: SupervisorConfig | None = None,
        rest_motor=None,
        getup_mirror_to: str | None = mirror.TRAINED,
    ):
        self.walking = walking
        self.cfg = config if config is not None else SupervisorConfig()
        if not isinstance(self.cfg, SupervisorConfig):
            raise ValueError(f"config must be a SupervisorConfig, got {type(self.cfg).__name__}")
        r = walking.config.robot
        self.dt = float(walking.config.ctrl_dt)
        if isinstance(getup_policy, GetupPolicy):
            self.getup = getup_policy
        else:
            self.getup = GetupPolicy(getup_policy, r, self.dt, getup_mirror_to)
        self.safety = SafetyLayer(walking.safety.cfg, r.motor_limits, r.home_motor, self.dt, clamp=r.clamp)
        rest = r.home_motor if rest_motor is None else as_vector(rest_motor, 12, "rest_motor")
        if (
            not np.all(np.isfinite(rest))
            or np.any(rest < r.motor_limits[:, 0])
            or np.any(rest > r.motor_limits[:, 1])
        ):
            raise ValueError("rest_motor: every angle must be finite and inside the motor limits")
        self.rest_motor = r.clamp(rest)
        ticks = {n: self.cfg.ticks(n, self.dt) for n in ("fall_confirm_s", "settle_s", "stand_dwell_s")}
        ticks |= {
            n: self.cfg.ticks(n, self.dt) for n in ("getup_timeout_s", "rest_s", "rest_ease_s", "blend_s")
        }
        self._ticks = ticks
        self.reset()

    def reset(self, motor_pos=None) -> None:
        """Walking from motor_pos (12,) [rad] (the encoders; None: the home stance), as
        DeployLoop.reset, which checks the reading."""
        self.walking.reset(motor_pos)
        self.sent = self.walking.safety.sent.copy()
        self.safety.reset(self.sent)
        self.getup.reset()
        self.mode = Mode.WALKING
        self.mode_ticks = 0  # ticks completed in the current mode
        self.above_ticks = 0  # consecutive walking ticks above fall_tilt_rad
        self.attempt_ticks = 0  # ticks completed in the current get-up attempt
        self.dwell_ticks = 0  # consecutive standing_hold ticks at or below upright_tilt_rad
        self._blend = (self.sent.copy(), 1, 1)  # (from, ticks done, ticks of the blend)
        self._new_walk = False

    @property
    def fault_counts(self) -> dict:
        """Reason -> ticks, the walking loop's and the supervisor's safety layers' together."""
        return dict(self.walking.safety.counts + self.safety.counts)

    def _switch(self, mode: Mode) -> None:
        if self.mode is Mode.WALKING:
            self.safety.reset(self.sent)  # the get-up side starts from what was sent
        if mode is Mode.GETTING_UP and self.mode in (Mode.FALLEN, Mode.RESTING):
            self.getup.reset()
            self.attempt_ticks = 0
        if mode is Mode.WALKING:
            self.walking.reset(self.sent)  # checked: sent targets are inside the limits
            self._new_walk = True  # step() resets the walk's heading to this tick's IMU yaw
        if mode is Mode.STANDING_HOLD:
            self.dwell_ticks = 0
        # between getting_up and standing_hold the same policy drives: no blend
        same = {self.mode, mode} == {Mode.GETTING_UP, Mode.STANDING_HOLD}
        if not same:
            n = self._ticks["rest_ease_s"] if mode is Mode.RESTING else self._ticks["blend_s"]
            self._blend = (self.sent.copy(), 0, max(n, 1))
        self.mode, self.mode_ticks = mode, 0

    def _advance(self, tilt_rad: float) -> None:
        """The mode of this tick from its tilt and the timers (ticks completed before this one)."""
        c, t = self.cfg, self._ticks
        if self.mode is Mode.WALKING:
            self.above_ticks = self.above_ticks + 1 if tilt_rad > c.fall_tilt_rad else 0
            if self.above_ticks >= max(t["fall_confirm_s"], 1):
                self.above_ticks = 0
                self._switch(Mode.FALLEN)
        if self.mode is Mode.FALLEN and self.mode_ticks >= t["settle_s"]:  # settle_s 0: this tick
            self._switch(Mode.GETTING_UP)
        if self.mode is Mode.RESTING and self.mode_ticks >= t["rest_s"]:
            self._switch(Mode.GETTING_UP)
        if self.mode is Mode.GETTING_UP and tilt_rad <= c.upright_tilt_rad:
            self._switch(Mode.STANDING_HOLD)
        elif self.mode is Mode.STANDING_HOLD:
            if tilt_rad > c.hold_exit_tilt_rad:
                self._switch(Mode.GETTING_UP)
            elif tilt_rad > c.upright_tilt_rad:
                self.dwell_ticks = 0
            elif self.dwell_ticks >= t["stand_dwell_s"]:
                self._switch(Mode.WALKING)
        dwelling = self.mode is Mode.STANDING_HOLD and tilt_rad <= c.upright_tilt_rad
        if self.mode in (Mode.GETTING_UP, Mode.STANDING_HOLD) and not dwelling:
            if self.attempt_ticks >= t["getup_timeout_s"]:
                self._switch(Mode.RESTING)

    def _blended(self, goal) -> np.ndarray:
        start, done, n = self._blend
        done = min(done + 1, n)
        self._blend = (start, done, n)
        w = _smoothstep(done / n)
        return goal if w >= 1.0 else start + w * (np.asarray(goal, np.float64) - start)

    def step(self, imu_quat_wxyz, gyro, motor_pos, command=None, base_lin_vel=None) -> SupervisorResult:
        """One control tick: the mode from the IMU, then the mode's controller, the blend, the limits."""
        quat = as_vector(imu_quat_wxyz, 4, "imu_quat_wxyz")
        gyro = as_vector(gyro, 3, "gyro")
        motor_pos = as_vector(motor_pos, 12, "motor_pos")
        r = self.walking.config.robot
        reasons = check_sensors(self.safety.cfg, r.motor_limits, quat, gyro, motor_pos)
        tilt_rad = math.nan if reasons else tilt(quat)
        if not reasons:
            self._new_walk = False
            self._advance(tilt_rad)
            if self._new_walk:  # as at the start of a walk: the IMU's yaw now is 0
                self.walking.reset_heading(quat)
            if self.mode is not Mode.WALKING and self.safety.restart_needed:
                # back from a fault that eased home: blend again from there, as at a switch
                self._blend = (self.sent.copy(), 0, max(self._ticks["blend_s"], 1))
        action, mode = None, self.mode
        if mode is Mode.WALKING:
            out = self.walking.step(quat, gyro, motor_pos, command, base_lin_vel)
            goal, fault = self._blended(out.motor_targets), out.fault
            step = np.clip(goal - self.sent, -self.safety.max_step, self.safety.max_step)
            sent = r.clamp(self.sent + step)
        elif reasons:
            sent, fault = self.safety.filter(None, None, reasons)
        else:
            if mode is Mode.FALLEN:
                goal = self._blend[0]  # hold what was sent before the fall
            elif mode is Mode.RESTING:
                goal = self._blended(self.rest_motor)
            else:
                got = self.getup.act(quat, gyro, motor_pos, resync=self.safety.in_fault)
                if got is None:
                    goal = None
                else:
                    goal, action, _ = got
                    goal = self._blended(goal)
            sent, fault = self.safety.filter(goal, None, [] if goal is not None else ["policy_nonfinite"])
        if not reasons:
            self.mode_ticks += 1
            if mode in (Mode.GETTING_UP, Mode.STANDING_HOLD):
                self.attempt_ticks += 1
            if mode is Mode.STANDING_HOLD and tilt_rad <= self.cfg.upright_tilt_rad:
                self.dwell_ticks += 1
        self.sent = sent
        return SupervisorResult(sent.copy(), mode, tilt_rad, fault, action)
