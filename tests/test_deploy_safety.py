"""The deploy loop's safety layer (quadson_mjx.deploy_safety) and the robot-side interface of the loop.

References: hand-derived hold / ease / rate-limit sequences; the motor limits of the robots'
constants; fault injection over long random sensor streams (NaN, inf, huge values, zero and
non-unit quaternions, NaN policy outputs) for both robots, where every target sent must be finite,
inside the limits and within the servo's rate of the previous one, and the loop must return to
the policy's targets once the fault clears.
"""

import json
import math

import numpy as np
import pytest

from quadson_mjx import deploy
from quadson_mjx.config import to_json
from quadson_mjx.deploy_safety import GYRO_RANGE_RPS, Fault, SafetyConfig, SafetyLayer
from quadson_mjx.env_config import env_config
from quadson_mjx.quat import quat_to_rpy


class _Policy:
    """Stands in for an exported policy: the env config's metadata; returns `self.action`, or the
    result of `self.fn(obs)` when set."""

    def __init__(self, cfg, meta_extra=None):
        loop_cfg = deploy.LoopConfig.from_env_config(json.loads(to_json(cfg)))
        self.meta = {
            "env_config": json.loads(to_json(cfg)),
            "obs_spec": loop_cfg.obs_spec.to_json(),
            **(meta_extra or {}),
        }
        self.obs_size, self.action_size = loop_cfg.obs_size, loop_cfg.action_size
        self.action = np.zeros(self.action_size, np.float32)
        self.fn = None
        self.seen = []

    def __call__(self, obs):
        self.seen.append(np.asarray(obs))
        return self.fn(obs) if self.fn is not None else self.action


def _sensor_cfg(robot="quadson", history=1):
    cfg = env_config(command_tracking=True, robot=robot)
    cfg.unlock()
    cfg.observation = "sensors"
    cfg.obs_history = history
    cfg.lock()
    return cfg


def _rpy_quat(roll, pitch, yaw):
    """wxyz of R = Rz(yaw) Ry(pitch) Rx(roll) (hand-written product of the three half-angle quaternions)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ]
    )


LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


# --- the filter alone: hand-derived sequences ------------------------------------------------------


def test_hold_then_ease_home_then_home_with_the_rate_limit():
    limits = np.tile([[-1.0, 1.0]], (12, 1))
    home = np.zeros(12)
    cfg = SafetyConfig(max_rate_rps=5.0, hold_s=0.06, ease_s=0.1)  # 0.1 rad per 20 ms tick
    layer = SafetyLayer(cfg, limits, home, 0.02)
    layer.reset(np.full(12, 0.3))
    out, state = layer.filter(np.full(12, 0.35), np.ones(4, bool))
    assert state == Fault.OK and np.allclose(out, 0.35)  # 0.05 rad: under the rate limit
    out, state = layer.filter(np.full(12, 0.9), np.ones(4, bool))
    assert state == Fault.OK and np.allclose(out, 0.45)  # 0.55 rad asked, 0.1 rad per tick
    # a fault: hold the last valid target (0.9) for hold_s = 3 ticks, still rate limited
    seq = [layer.filter(None, None, ["imu_nonfinite"]) for _ in range(3)]
    assert [s for _, s in seq] == [Fault.HOLD] * 3
    np.testing.assert_allclose([o[0] for o, _ in seq], [0.55, 0.65, 0.75])
    # then ease from 0.9 to home over ease_s = 5 ticks: goal 0.9 (1 - w), w = 0.2, 0.4, ..., 1
    seq = [layer.filter(None, None, ["imu_nonfinite"]) for _ in range(6)]
    assert [s for _, s in seq] == [Fault.EASING_HOME] * 4 + [Fault.HOME] * 2
    # goals 0.72, 0.54, 0.36, 0.18, 0, 0 from 0.75: -0.03, then 0.1 per tick at most
    np.testing.assert_allclose([o[0] for o, _ in seq], [0.72, 0.62, 0.52, 0.42, 0.32, 0.22], atol=1e-12)
    assert layer.counts["imu_nonfinite"] == 9 and layer.fault_ticks == 9 and layer.restart_needed
    out, state = layer.filter(np.full(12, 0.25), np.ones(4, bool))  # the fault clears
    assert state == Fault.OK and np.allclose(out, 0.25) and not layer.in_fault


def test_an_invalid_leg_keeps_its_last_valid_targets():
    layer = SafetyLayer(SafetyConfig(max_rate_rps=100.0), np.tile([[-2.0, 2.0]], (12, 1)), np.zeros(12), 0.02)
    layer.filter(np.full(12, 0.5), np.ones(4, bool))
    valid = np.array([True, False, True, True])
    out, state = layer.filter(np.full(12, 1.0), valid)
    assert state == Fault.LEG_HOLD and layer.counts["ik_invalid_leg"] == 1
    np.testing.assert_allclose(out, np.where(np.repeat(valid, 3), 1.0, 0.5))
    out, state = layer.filter(np.full(12, 1.0), np.zeros(4, bool))  # no leg valid: a fault
    assert state == Fault.HOLD and layer.counts["ik_invalid_all"] == 1


@pytest.mark.parametrize(
    "bad", [{"max_rate_rps": 0.0}, {"hold_s": -1.0}, {"ease_s": math.nan}, {"gyro_range_rps": math.inf}]
)
def test_safety_config_refuses_unusable_limits(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        SafetyLayer(
            SafetyConfig(**{"max_rate_rps": 1.0, **bad}), np.tile([[-1.0, 1.0]], (12, 1)), np.zeros(12), 0.02
        )


# --- fault injection through the loop -----------------------------------------------------------------


def _random_stream(rng, n, limits, home):
    """n ticks of plausible readings with bursts of every kind of bad value (about a third of them)."""
    quat = rng.normal(size=(n, 4)) * [1.0, 0.1, 0.1, 0.3]
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    gyro = rng.normal(0.0, 1.0, (n, 3))
    motor = home + rng.normal(0.0, 0.05, (n, 12))
    motor = np.clip(motor, limits[:, 0], limits[:, 1])
    command = rng.uniform(-0.5, 0.5, (n, 3))
    bad = np.zeros(n, bool)
    t = 0
    while t < n:
        t += int(rng.integers(20, 200))
        length = int(rng.integers(1, 80))
        kind = int(rng.integers(0, 7))
        s = slice(t, min(t + length, n))
        if kind == 0:
            quat[s, rng.integers(0, 4)] = np.nan
        elif kind == 1:
            quat[s] = 0.0
        elif kind == 2:
            quat[s] *= 3.0  # not a unit quaternion
        elif kind == 3:
            gyro[s, rng.integers(0, 3)] = rng.choice([np.inf, -np.inf, 1e30, 2.0 * GYRO_RANGE_RPS])
        elif kind == 4:
            motor[s, rng.integers(0, 12)] = rng.choice([np.nan, 1e30, -1e3])
        elif kind == 5:
            command[s] = np.nan
        bad[s] = kind <= 5
        t += length
    return quat, gyro, motor, command, bad


@pytest.mark.parametrize("robot", ["quadson", "caramel"])
def test_fault_injection_over_a_long_random_stream(robot):
    cfg = _sensor_cfg(robot, history=2)
    policy = _Policy(cfg)
    rng = np.random.default_rng(7 if robot == "quadson" else 8)
    nan_burst = set()
    t = 0
    while t < 6000:  # policy outputs: random in [-1.5, 1.5], with bursts of NaN and inf
        t += int(rng.integers(30, 300))
        nan_burst.update(range(t, t + int(rng.integers(1, 40))))

    tick = [0]

    def act(obs):
        k = tick[0]
        a = rng.uniform(-1.5, 1.5, policy.action_size).astype(np.float32)
        if k in nan_burst:
            a[rng.integers(0, len(a))] = rng.choice([np.nan, np.inf])
        return a

    policy.fn = act
    loop = deploy.DeployLoop(policy)
    r = loop.config.robot
    lo, hi = r.motor_limits[:, 0], r.motor_limits[:, 1]
    max_step = r.servo_speed_rps * loop.config.ctrl_dt
    n = 6000
    quat, gyro, motor, command, bad = _random_stream(rng, n, r.motor_limits, r.home_motor)
    prev = r.home_motor.copy()
    states = []
    for k in range(n):
        tick[0] = k
        out = loop.step(quat[k], gyro[k], motor[k], command=command[k])
        m = out.motor_targets
        assert m.shape == (12,) and np.all(np.isfinite(m))
        assert np.all(m >= lo - 1e-12) and np.all(m <= hi + 1e-12)
        assert np.max(np.abs(m - prev)) <= max_step + 1e-9
        if r.name == "quadson":  # the knees never cross (toe-in guard)
            assert np.all(m.reshape(4, 3)[:, 2] - m.reshape(4, 3)[:, 1] <= 0.06 + 1e-12)
        if bad[k]:
            assert out.fault in (Fault.HOLD, Fault.EASING_HOME, Fault.HOME) and not out.valid.any()
        elif k not in nan_burst:
            assert out.fault in (Fault.OK, Fault.LEG_HOLD)  # recovered at the first good tick
        states.append(str(out.fault))
        prev = m
    seen = set(states)
    assert {"ok", "hold", "easing_home", "home"} <= seen  # every state was exercised
    counts = loop.fault_counts
    for reason in (
        "imu_nonfinite",
        "imu_quat_norm",
        "gyro_range",
        "encoder_range",
        "command_nonfinite",
        "policy_nonfinite",
    ):
        assert counts.get(reason, 0) > 0, reason
    print(f"{robot}: {n} ticks, states {dict((s, states.count(s)) for s in seen)}, faults {counts}")


def test_recovery_returns_to_the_policys_targets():
    """After a fault long enough to reach home, the first good ticks restart the walk from the
    encoders and the targets reach the unfiltered policy targets within the rate limit's time."""
    policy = _Policy(_sensor_cfg())
    loop = deploy.DeployLoop(policy)
    r = loop.config.robot
    for _ in range(10):
        loop.step(LEVEL, np.zeros(3), r.home_motor)
    for _ in range(80):  # 1.6 s > hold 0.2 + ease 1.0 s
        out = loop.step([0.0, 0.0, 0.0, 0.0], np.zeros(3), r.home_motor)
    assert out.fault == Fault.HOME and np.allclose(out.motor_targets, r.home_motor)
    outs = [loop.step(LEVEL, np.zeros(3), r.home_motor) for _ in range(40)]
    assert all(o.fault == Fault.OK for o in outs)
    assert loop.time_s == pytest.approx(40 * 0.02)  # restarted: the clock counts from the recovery
    fresh = deploy.DeployLoop(policy)  # an undisturbed walk from the same reading
    fresh.reset(motor_pos=r.home_motor)
    for o in outs:
        np.testing.assert_allclose(
            o.motor_targets, fresh.step(LEVEL, np.zeros(3), r.home_motor).motor_targets
        )


# --- regressions (issue: NaN and implausible readings reached the servos as a limit pose) -----------

_TRUE_STATE = env_config()


def _true_state_loop():
    return deploy.DeployLoop(_Policy(_TRUE_STATE))


def test_regression_nan_sensors_never_command_a_limit_pose():
    loop = _true_state_loop()
    r = loop.config.robot
    first = loop.step(LEVEL, np.zeros(3), r.home_motor, base_lin_vel=np.zeros(3))
    for bad in ("quat", "gyro", "motor", "vel"):
        for value in (np.nan, np.inf):
            q, g, m, v = LEVEL.copy(), np.zeros(3), r.home_motor.copy(), np.zeros(3)
            {"quat": q, "gyro": g, "motor": m, "vel": v}[bad][0] = value
            out = loop.step(q, g, m, base_lin_vel=v)
            assert out.fault == Fault.HOLD and not out.valid.any(), (bad, value)
            # the old loop sent [0, 0.785, 0] on every leg (motor 1 at its lower limit)
            np.testing.assert_allclose(out.motor_targets, first.motor_targets, atol=1e-12)


def test_regression_zero_quaternion_and_huge_gyro_are_faults():
    loop = _true_state_loop()
    home = loop.config.robot.home_motor
    out = loop.step(np.zeros(4), np.zeros(3), home, base_lin_vel=np.zeros(3))
    assert out.fault == Fault.HOLD and loop.fault_counts == {"imu_quat_norm": 1}
    out = loop.step(LEVEL, np.array([1e30, 0.0, 0.0]), home, base_lin_vel=np.zeros(3))
    assert out.fault == Fault.HOLD and loop.fault_counts["gyro_range"] == 1
    out = loop.step(LEVEL, np.array([0.0, 0.0, 0.99 * GYRO_RANGE_RPS]), home, base_lin_vel=np.zeros(3))
    assert out.fault == Fault.OK  # inside the sensor's range


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"command": np.zeros(2)}, "command"),
        ({"command": np.zeros(4)}, "command"),
        ({"gyro": np.zeros(4)}, "gyro"),
        ({"motor_pos": np.zeros(11)}, "motor_pos"),
        ({"imu_quat_wxyz": np.zeros(3)}, "imu_quat_wxyz"),
        ({"base_lin_vel": np.zeros(2)}, "base_lin_vel"),
    ],
)
def test_regression_wrong_input_length_is_one_clear_error(kwargs, name):
    loop = _true_state_loop()
    args = {
        "imu_quat_wxyz": LEVEL,
        "gyro": np.zeros(3),
        "motor_pos": loop.config.robot.home_motor,
        "base_lin_vel": np.zeros(3),
    }
    with pytest.raises(ValueError, match=rf"^{name} must have \d+ values, got shape"):
        loop.step(**{**args, **kwargs})


def test_regression_nan_policy_output_holds():
    policy = _Policy(_TRUE_STATE)
    loop = deploy.DeployLoop(policy)
    home = loop.config.robot.home_motor
    first = loop.step(LEVEL, np.zeros(3), home, base_lin_vel=np.zeros(3))
    policy.action = np.full(policy.action_size, np.nan, np.float32)
    out = loop.step(LEVEL, np.zeros(3), home, base_lin_vel=np.zeros(3))
    assert out.fault == Fault.HOLD and loop.fault_counts == {"policy_nonfinite": 1}
    np.testing.assert_allclose(out.motor_targets, first.motor_targets)
    assert np.all(np.isfinite(out.action))  # the last finite action is reported


def test_regression_run_loop_sends_only_safe_targets(monkeypatch):
    loop = _true_state_loop()
    r = loop.config.robot
    readings = iter(
        [
            {
                "imu_quat_wxyz": LEVEL,
                "gyro": np.zeros(3),
                "motor_pos": r.home_motor,
                "base_lin_vel": np.zeros(3),
            },
            {
                "imu_quat_wxyz": LEVEL * np.nan,
                "gyro": np.zeros(3),
                "motor_pos": r.home_motor,
                "base_lin_vel": np.zeros(3),
            },
            None,  # the bus fails: read_sensors raises
        ]
    )

    def read():
        value = next(readings)
        if value is None:
            raise TimeoutError("servo bus timeout")
        return value

    sent = []
    monkeypatch.setattr(deploy.time, "sleep", lambda s: None)
    deploy.run_loop(loop, read, sent.append, n_steps=3)
    assert [str(o.fault) for o in sent] == ["ok", "hold", "hold"]
    assert loop.fault_counts == {"imu_nonfinite": 1, "sensor_read_error": 1}
    for o in sent:
        assert np.all(np.isfinite(o.motor_targets))
        np.testing.assert_allclose(o.motor_targets, sent[0].motor_targets)


# --- the robot-side interface ----------------------------------------------------------------------


@pytest.mark.parametrize("robot", ["quadson", "caramel"])
def test_first_tick_targets_are_the_encoder_reading(robot):
    """The start ramp begins where the motors are: the encoders' offset from the home stance fades
    with the env's smoothstep, so the first tick moves by only the env's first step from home
    (smoothstep(0.02 / 0.5) = 0.5 % of the way into the gait, with a zero action)."""
    loop = deploy.DeployLoop(_Policy(_sensor_cfg(robot)))
    r = loop.config.robot
    rng = np.random.default_rng(1)
    span = r.motor_limits[:, 1] - r.motor_limits[:, 0]
    encoders = np.clip(r.home_motor + rng.uniform(-0.15, 0.15, 12) * np.minimum(span, 1.0), *r.motor_limits.T)
    loop.reset(motor_pos=encoders)
    out = loop.step(LEVEL, np.zeros(3), encoders)
    assert out.fault == Fault.OK
    err = float(np.max(np.abs(out.motor_targets - encoders)))
    print(f"{robot}: first tick targets - encoders: max {err:.2e} rad")
    assert err < 0.01
    for _ in range(int(loop.config.gait_ramp_s / loop.config.ctrl_dt)):  # after the ramp: no offset left
        out = loop.step(LEVEL, np.zeros(3), encoders)
    raw, _, _, _ = loop.targets(np.zeros(loop.config.action_size), np.zeros(3))
    loop.start_offset[:] = 0.0
    np.testing.assert_allclose(
        raw, loop.targets(np.zeros(loop.config.action_size), np.zeros(3))[0], atol=1e-12
    )


def test_reset_refuses_an_unusable_encoder_reading():
    loop = deploy.DeployLoop(_Policy(_sensor_cfg()))
    home = loop.config.robot.home_motor
    with pytest.raises(ValueError, match="motor_pos must have 12 values"):
        loop.reset(motor_pos=np.zeros(3))
    with pytest.raises(ValueError, match="encoder_nonfinite"):
        loop.reset(motor_pos=np.where(np.arange(12) == 4, np.nan, home))


def test_no_command_stands_still():
    policy = _Policy(_sensor_cfg())
    loop = deploy.DeployLoop(policy)
    home = loop.config.robot.home_motor
    out = loop.step(LEVEL, np.zeros(3), home)
    spec = loop.config.obs_spec
    np.testing.assert_array_equal(spec.split(out.obs)["command"], np.zeros(3))
    other = deploy.DeployLoop(policy)
    ref = other.step(LEVEL, np.zeros(3), home, command=np.zeros(3))
    np.testing.assert_array_equal(out.foot_targets, ref.foot_targets)
    assert loop.gait_command[0] > 0  # the command a command-free policy was trained to walk at


def test_heading_reset_zeroes_the_observed_yaw_only():
    loop = _true_state_loop()
    home = loop.config.robot.home_motor
    q = _rpy_quat(0.1, -0.2, 2.5)
    np.testing.assert_allclose(quat_to_rpy(q), [0.1, -0.2, 2.5], atol=1e-12)  # the hand-written quaternion
    out = loop.step(q, np.zeros(3), home, base_lin_vel=np.zeros(3))
    assert out.obs[2] == pytest.approx(2.5, abs=1e-6)
    loop.reset_heading()  # the last step's yaw becomes 0
    out = loop.step(_rpy_quat(0.1, -0.2, 2.5 + 0.3), np.zeros(3), home, base_lin_vel=np.zeros(3))
    np.testing.assert_allclose(out.obs[:3], [0.1, -0.2, 0.3], atol=1e-6)
    loop.reset_heading(_rpy_quat(0.0, 0.0, -3.0))  # across +-pi: yaw 3.0 - (-3.0) wraps to 6 - 2 pi
    out = loop.step(_rpy_quat(0.0, 0.0, 3.0), np.zeros(3), home, base_lin_vel=np.zeros(3))
    assert out.obs[2] == pytest.approx(6.0 - 2 * math.pi, abs=1e-6)


def test_base_lin_vel_is_required_by_an_estimator_policy_and_refused_by_a_sensor_policy():
    with pytest.raises(ValueError, match="base_lin_vel is required"):
        _true_state_loop().step(LEVEL, np.zeros(3), np.zeros(12) + 1.0)
    loop = deploy.DeployLoop(_Policy(_sensor_cfg()))
    with pytest.raises(ValueError, match="observes only the robot's sensors"):
        loop.step(LEVEL, np.zeros(3), loop.config.robot.home_motor, base_lin_vel=np.zeros(3))


def test_sensor_observation_entries_from_hand_computed_readings():
    """gravity = R(q)^T (0, 0, -1), motor_vel by difference, last_action, lagged entries newest first
    (the first tick's values before it), from a pitched IMU."""
    policy = _Policy(_sensor_cfg(history=3))
    loop = deploy.DeployLoop(policy)
    spec = loop.config.obs_spec
    home = loop.config.robot.home_motor
    pitch = 0.3  # R = Ry(0.3), nose down: gravity in the body frame Ry(-p) (0, 0, -1) = (sin p, 0, -cos p)
    q = _rpy_quat(0.0, pitch, 1.0)  # yaw does not change it
    a1 = np.linspace(-0.5, 0.5, policy.action_size).astype(np.float32)
    policy.action = a1
    o1 = spec.split(loop.step(q, np.array([0.1, 0.2, 0.3]), home).obs)
    np.testing.assert_allclose(o1["gravity"], [math.sin(pitch), 0.0, -math.cos(pitch)], atol=1e-6)
    np.testing.assert_allclose(o1["motor_vel"], 0.0)
    np.testing.assert_allclose(o1["last_action"], 0.0)
    np.testing.assert_allclose(o1["gyro@-2"], [0.1, 0.2, 0.3], atol=1e-7)  # before the first tick
    policy.action = np.zeros(policy.action_size, np.float32)
    moved = home + 0.01
    o2 = spec.split(loop.step(q, np.zeros(3), moved).obs)
    np.testing.assert_allclose(o2["motor_vel"], 0.01 / 0.02, rtol=1e-5)
    np.testing.assert_allclose(o2["last_action"], a1, atol=1e-7)
    np.testing.assert_allclose(o2["gyro@-1"], [0.1, 0.2, 0.3], atol=1e-7)
    np.testing.assert_allclose(o2["motor_vel@-1"], 0.0)
    o3 = spec.split(loop.step(q, np.zeros(3), moved).obs)
    np.testing.assert_allclose(o3["motor_vel@-1"], 0.5, rtol=1e-5)
    np.testing.assert_allclose(o3["last_action@-1"], a1, atol=1e-7)
    np.testing.assert_allclose(o3["motor_pos@-2"], home, atol=1e-6)


def test_a_leg_invalid_for_longer_than_hold_s_becomes_a_fault():
    cfg = SafetyConfig(max_rate_rps=100.0, hold_s=0.06, ease_s=0.04)  # 3 ticks, then 2 ticks of ease
    layer = SafetyLayer(cfg, np.tile([[-2.0, 2.0]], (12, 1)), np.zeros(12), 0.02)
    layer.filter(np.full(12, 0.5), np.ones(4, bool))
    one_bad = np.array([True, True, False, True])
    states = [layer.filter(np.full(12, 0.6), one_bad)[1] for _ in range(9)]
    assert states == [Fault.LEG_HOLD] * 3 + [Fault.HOLD] * 3 + [Fault.EASING_HOME, Fault.HOME, Fault.HOME]
    assert layer.counts["ik_invalid_persistent"] == 6
    out, state = layer.filter(np.full(12, 0.6), np.ones(4, bool))  # every leg valid again
    assert state == Fault.OK and np.allclose(out, 0.6)


def test_clamp_mode_sends_the_simulators_clamped_targets_and_inf_turns_the_rate_limit_off():
    cfg = SafetyConfig(max_rate_rps=math.inf, ik_invalid="clamp")
    layer = SafetyLayer(cfg, np.tile([[-2.0, 2.0]], (12, 1)), np.zeros(12), 0.02)
    out, state = layer.filter(np.full(12, 1.9), np.array([True, False, True, True]))
    assert state == Fault.OK and np.allclose(out, 1.9)  # no hold, no rate limit
    assert layer.counts["ik_clamped_leg"] == 1
    out, state = layer.filter(np.full(12, np.nan), np.ones(4, bool))  # still never a non-finite target
    assert state == Fault.HOLD and np.allclose(out, 1.9)
    with pytest.raises(ValueError, match="ik_invalid"):
        SafetyLayer(
            SafetyConfig(max_rate_rps=1.0, ik_invalid="ignore"),
            np.tile([[-1.0, 1.0]], (12, 1)),
            np.zeros(12),
            0.02,
        )
