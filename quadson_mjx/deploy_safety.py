"""The deploy loop's safety layer: what reaches the servos is always finite, inside the motor limits
and no faster than the servos move, whatever the sensors or the policy give.

Every control tick the loop (quadson_mjx.deploy) checks the sensor readings (`check_sensors`),
runs the policy and the inverse kinematics only on readings that pass, and hands the result to
`SafetyLayer.filter`, which decides what is sent:

  * "ok": the policy's targets.
  * "leg_hold": some legs' IK was invalid (target out of reach or beyond a limit): those legs keep
    their last valid targets, the others follow the policy. When some leg stays invalid for longer
    than hold_s, it becomes a fault (below) until every leg is valid again.
  * "hold": a fault this tick (non-finite or implausible sensor, non-finite policy output, a tick
    without sensors): every motor keeps the last valid targets.
  * "easing_home": the fault has lasted hold_s: the targets move in a straight line (joint space)
    from the held ones to the home stance over ease_s.
  * "home": the fault goes on after the ease: the home stance is held.

Then every target moves at most max_rate_rps x ctrl_dt per tick from the target sent the tick before
(the servo's speed: a faster command would only build up position error) and is clipped into the
motor limits. The first tick after a fault with good sensors is "ok" again (the loop restarts its
walk from the encoders' reading when the fault reached easing_home, see deploy.DeployLoop).

Numpy and the standard library only (the robot's computer loads it).
"""

from __future__ import annotations

import math
from collections import Counter
from enum import StrEnum
from typing import NamedTuple

import numpy as np

GYRO_RANGE_RPS = math.radians(2000.0)  # the widest full scale of MEMS gyros (MPU-6050, BMI088): 34.9 rad/s


class Fault(StrEnum):
    """The safety layer's state for one tick (a str: Fault.OK == "ok")."""

    OK = "ok"
    LEG_HOLD = "leg_hold"
    HOLD = "hold"
    EASING_HOME = "easing_home"
    HOME = "home"


class SafetyConfig(NamedTuple):
    """Limits of the safety layer. max_rate_rps None: the robot's servo speed (deploy_robots)."""

    max_rate_rps: float | None = None  # largest target change per second of each motor [rad/s]
    hold_s: float = 0.2  # how long a fault holds the last valid targets before easing home [s]
    ease_s: float = 1.0  # duration of the move from the held targets to the home stance [s]
    quat_norm_tol: float = 0.1  # | |q| - 1 | beyond this: not an orientation (a zero quaternion)
    gyro_range_rps: float = GYRO_RANGE_RPS  # |gyro| component beyond this: not a reading [rad/s]
    encoder_margin_rad: float = 0.1  # encoder beyond a motor limit by more than this: a fault [rad]
    max_lin_vel_mps: float = 10.0  # |base_lin_vel| component beyond this: not an estimate [m/s]
    # an invalid leg IK: "hold" that leg's last valid targets (leg_hold), or "clamp": send the IK's
    # clamped angles as the simulator does (what the policy trained with)
    ik_invalid: str = "hold"

    def checked(self) -> SafetyConfig:
        """self, or ValueError naming a value that is not a positive finite number."""
        if self.ik_invalid not in ("hold", "clamp"):
            raise ValueError(f"SafetyConfig.ik_invalid is {self.ik_invalid!r}; choose 'hold' or 'clamp'")
        for name, value in self._asdict().items():
            if name == "ik_invalid" or (name == "max_rate_rps" and (value is None or value == math.inf)):
                continue  # max_rate_rps inf: no rate limit
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"SafetyConfig.{name} must be a finite number, got {value!r}")
            if value < 0 or (value == 0 and name not in ("hold_s", "encoder_margin_rad")):
                raise ValueError(
                    f"SafetyConfig.{name} must be {'>= 0' if name == 'hold_s' else '> 0'}, got {value!r}"
                )
        return self


def as_vector(value, size: int, name: str) -> np.ndarray:
    """value -> float64 (size,); ValueError naming the input for another length (not a broadcast)."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (size,):
        raise ValueError(f"{name} must have {size} values, got shape {arr.shape}")
    return arr


def check_sensors(
    cfg: SafetyConfig, motor_limits, imu_quat_wxyz, gyro, motor_pos, base_lin_vel=None
) -> list[str]:
    """The reasons (empty: none) why these readings must not reach the policy: non-finite values, a
    quaternion whose norm is not 1 within quat_norm_tol (a zero quaternion), a gyro reading beyond
    gyro_range_rps, an encoder beyond its limit (motor_limits (12, 2)) by encoder_margin_rad, a
    velocity estimate beyond max_lin_vel_mps. Arrays of the right lengths (as_vector)."""
    reasons = []
    if not np.all(np.isfinite(imu_quat_wxyz)):
        reasons.append("imu_nonfinite")
    elif abs(float(np.linalg.norm(imu_quat_wxyz)) - 1.0) > cfg.quat_norm_tol:
        reasons.append("imu_quat_norm")
    if not np.all(np.isfinite(gyro)):
        reasons.append("gyro_nonfinite")
    elif np.any(np.abs(gyro) > cfg.gyro_range_rps):
        reasons.append("gyro_range")
    if not np.all(np.isfinite(motor_pos)):
        reasons.append("encoder_nonfinite")
    elif np.any(motor_pos < motor_limits[:, 0] - cfg.encoder_margin_rad) or np.any(
        motor_pos > motor_limits[:, 1] + cfg.encoder_margin_rad
    ):
        reasons.append("encoder_range")
    if base_lin_vel is not None:
        if not np.all(np.isfinite(base_lin_vel)):
            reasons.append("lin_vel_nonfinite")
        elif np.any(np.abs(base_lin_vel) > cfg.max_lin_vel_mps):
            reasons.append("lin_vel_range")
    return reasons


class SafetyLayer:
    """The state of the safety filter of one walk: the last valid and the last sent targets, the
    fault timer and the fault counts. Not thread-safe; one per DeployLoop."""

    def __init__(self, cfg: SafetyConfig, motor_limits, home, ctrl_dt: float, clamp=None):
        """motor_limits (12, 2) [rad], home (12,) home-stance targets [rad], ctrl_dt [s]; clamp: the
        robot's (12,) -> (12,) projection into its limits (deploy_robots), default a clip."""
        if cfg.max_rate_rps is None:
            raise ValueError("SafetyConfig.max_rate_rps: give the servo's speed")
        self.cfg = cfg.checked()
        self.limits = np.asarray(motor_limits, np.float64).reshape(-1, 2)
        self.lo, self.hi = self.limits[:, 0], self.limits[:, 1]
        self._clamp = clamp
        self.home = self._clip(np.asarray(home, np.float64))
        self.ctrl_dt = float(ctrl_dt)
        self.max_step = float(cfg.max_rate_rps) * self.ctrl_dt  # rad per tick
        self.counts: Counter = Counter()  # reason -> ticks it was seen
        self.fault_ticks = 0  # ticks in hold, easing_home or home since the layer was made
        self.reset(self.home)

    def _clip(self, targets) -> np.ndarray:
        out = np.minimum(np.maximum(targets, self.lo), self.hi)
        return self._clamp(out) if self._clamp is not None else out

    def reset(self, start) -> None:
        """A new walk: the last valid and the last sent targets become `start` (12,) (the encoders'
        reading, clipped into the limits); no fault."""
        start = self._clip(np.nan_to_num(np.asarray(start, np.float64), nan=0.0))
        self.last_valid = start.copy()
        self.sent = start.copy()
        self.fault_s = 0.0  # time in the current fault [s]
        self.leg_hold_s = 0.0  # time some leg's IK has been invalid without a break [s]
        self.ease_from = None

    @property
    def in_fault(self) -> bool:
        return self.fault_s > 0.0

    @property
    def restart_needed(self) -> bool:
        """The current fault has lasted beyond hold_s: the walk restarts when it clears."""
        return self.fault_s > self.cfg.hold_s

    def filter(self, targets=None, valid=None, reasons=()) -> tuple[np.ndarray, Fault]:
        """One tick: targets (12,) the policy's motor targets or None (no usable output this tick),
        valid (4,) IK validity per leg (3 motors each), reasons: the faults of this tick (counted)
        -> (the targets to send (12,), the tick's Fault)."""
        for r in reasons:
            self.counts[r] += 1
        usable = targets is not None and not reasons
        if usable:
            targets = np.asarray(targets, np.float64)
            legs = np.asarray(valid, bool) if valid is not None else np.ones(len(targets) // 3, bool)
            if self.cfg.ik_invalid == "clamp":
                if not legs.all():
                    self.counts["ik_clamped_leg"] += 1
                legs = np.ones_like(legs)
            per_motor = np.repeat(legs, len(targets) // len(legs)) & np.isfinite(targets)
            if not per_motor.any():
                usable = False
                self.counts["ik_invalid_all"] += 1
        if usable and not per_motor.all():  # some legs' IK invalid: hold them, for hold_s at most
            self.leg_hold_s += self.ctrl_dt
            if self.leg_hold_s > self.cfg.hold_s:
                usable = False
                self.counts["ik_invalid_persistent"] += 1
        elif usable:
            self.leg_hold_s = 0.0
        if usable:
            self.fault_s, self.ease_from = 0.0, None
            goal = np.where(per_motor, targets, self.last_valid)
            self.last_valid = self._clip(goal)
            state = Fault.OK if per_motor.all() else Fault.LEG_HOLD
            if state is Fault.LEG_HOLD:
                self.counts["ik_invalid_leg"] += 1
        else:
            self.fault_ticks += 1
            self.fault_s += self.ctrl_dt
            over = self.fault_s - self.cfg.hold_s
            if over <= 0:
                goal, state = self.last_valid, Fault.HOLD
            else:
                if self.ease_from is None:
                    self.ease_from = self.last_valid.copy()
                w = min(over / self.cfg.ease_s, 1.0)
                goal = self.ease_from + w * (self.home - self.ease_from)
                state = Fault.EASING_HOME if w < 1.0 else Fault.HOME
        step = np.minimum(np.maximum(goal - self.sent, -self.max_step), self.max_step)
        out = self._clip(self.sent + step)
        if not np.all(np.isfinite(out)):  # unreachable by construction; never send it
            out = self.sent.copy()
        self.sent = out
        return out.copy(), state
