"""The get-up supervisor on the robot (quadson_mjx.deploy_supervisor), on hand-made sensor streams.

References: hand-derived tick numbers of every switch (the config's durations over the 20 ms tick),
the tilt acos(cos(roll) cos(pitch)) of a rolled and pitched body, the smoothstep blend's first
value, the motor limits of the robot's constants, and a plain DeployLoop fed the same stream.
"""

import json
import math

import numpy as np
import pytest

from quadson_mjx import deploy, obs_spec
from quadson_mjx.config import to_json
from quadson_mjx.deploy_safety import Fault
from quadson_mjx.deploy_supervisor import (
    Mode,
    Supervisor,
    SupervisorConfig,
    getup_targets,
    tilt,
)
from quadson_mjx.env_config import env_config
from quadson_mjx.robots.quadson import constants as C


class _Walk:
    """Stands in for an exported walking policy (sensor observation, command tracking)."""

    def __init__(self):
        cfg = env_config(command_tracking=True)
        cfg.unlock()
        cfg.observation = "sensors"
        cfg.lock()
        loop_cfg = deploy.LoopConfig.from_env_config(json.loads(to_json(cfg)))
        self.meta = {"env_config": json.loads(to_json(cfg)), "obs_spec": loop_cfg.obs_spec.to_json()}
        self.obs_size, self.action_size = loop_cfg.obs_size, loop_cfg.action_size
        self.calls = 0

    def __call__(self, obs):
        self.calls += 1
        return 0.3 * np.sin(np.arange(self.action_size) + self.calls).astype(np.float32)


class _Getup:
    """Stands in for an exported get-up policy: returns `action`; records what it saw."""

    obs_size, action_size = 30, 12

    def __init__(self, action=None):
        self.action = np.zeros(12, np.float32) if action is None else np.asarray(action, np.float32)
        self.seen = []

    def __call__(self, obs):
        self.seen.append(np.array(obs))
        return self.action


def _quat(roll, pitch=0.0, yaw=0.0):
    """wxyz of Rz(yaw) Ry(pitch) Rx(roll), the half-angle product written out."""
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


def _config(**changes):
    """The thresholds the hand-made streams below were written for (the defaults before the get-up
    policy learned to catch a fall): 50 deg over 5 ticks, 15 ticks of settling, 0.25 s blends."""
    slow = {"fall_tilt_rad": math.radians(50.0), "fall_confirm_s": 0.1, "settle_s": 0.3}
    slow |= {"hold_exit_tilt_rad": math.radians(25.0), "blend_s": 0.25}
    return SupervisorConfig(**(slow | changes))


def _sup(config=None, getup=None):
    config = config if config is not None else _config()
    return Supervisor(deploy.DeployLoop(_Walk()), getup if getup is not None else _Getup(), config)


HOME = _sup().walking.config.robot.home_motor.copy()  # the home stance's motor targets (12,) [rad]


def _run(sup, rolls, motor=None):
    """Steps sup through the roll angles [rad] (level otherwise) -> list of results."""
    out = []
    for r in rolls:
        m = HOME if motor is None else motor
        out.append(sup.step(_quat(r), np.zeros(3), m, command=(0.2, 0.0, 0.0)))
    return out


D = math.radians


def test_tilt_is_the_angle_from_vertical_whatever_the_yaw():
    for roll, pitch in ((0.0, 0.0), (0.3, 0.0), (0.0, -0.7), (0.4, 0.5), (math.pi, 0.0), (1.2, -1.0)):
        for yaw in (0.0, 1.0, -2.5):
            expected = math.acos(math.cos(roll) * math.cos(pitch))
            assert tilt(_quat(roll, pitch, yaw)) == pytest.approx(expected, abs=1e-9)
    assert tilt(2.0 * _quat(0.3)) == pytest.approx(0.3)  # a non-unit quaternion is normalised


def test_upright_stream_never_switches_and_sends_the_walking_loops_targets():
    sup = _sup()
    rng = np.random.default_rng(0)
    rolls = rng.uniform(-D(40), D(40), 150)  # bumpy, always below the 50 deg fall threshold
    ref = deploy.DeployLoop(_Walk())  # the walking loop alone, the same stream
    for r in rolls:
        got = sup.step(_quat(r), np.zeros(3), HOME, command=(0.2, 0.0, 0.0))
        want = ref.step(_quat(r), np.zeros(3), HOME, command=(0.2, 0.0, 0.0))
        assert got.mode == Mode.WALKING and got.action is None
        np.testing.assert_allclose(got.motor_targets, want.motor_targets, atol=1e-12)
    assert sup.getup.policy.seen == []


def test_a_fall_switches_exactly_when_expected():
    cfg = _config()  # 50 deg, confirmed over 5 ticks; settle 15 ticks
    getup = _Getup()
    sup = _sup(cfg, getup)
    rolls = [D(2.0 * k + 1.0) for k in range(60)]  # 1, 3, ... deg: first above 50 deg at k = 25
    modes = [o.mode for o in _run(sup, rolls)]
    # k = 25..29 above the threshold: the 5th (k = 29) is the fall; fallen k = 29..43; get-up from 44
    assert modes[:29] == [Mode.WALKING] * 29
    assert modes[29:44] == [Mode.FALLEN] * 15
    assert modes[44:] == [Mode.GETTING_UP] * 16
    assert len(getup.seen) == 16  # the get-up policy ran on the getting_up ticks only


def test_hysteresis_no_chatter_around_either_threshold():
    # around the fall threshold: 45 / 55 deg alternating never stays above for 5 ticks
    sup = _sup()
    assert {o.mode for o in _run(sup, [D(45), D(55)] * 50)} == {Mode.WALKING}
    # without confirmation the first tick above falls, and 49 deg after it does not walk again
    sup = _sup(_config(fall_confirm_s=0.0, settle_s=0.0))
    modes = [o.mode for o in _run(sup, [D(51), D(49)] * 50)]
    assert modes[0] == Mode.GETTING_UP and set(modes) == {Mode.GETTING_UP}
    # around the upright threshold (12 deg) while standing up: stays in standing_hold (exit at
    # 25 deg), and the dwell restarts at every tick above 12 deg, so it never walks
    sup = _sup(_config(fall_confirm_s=0.0, settle_s=0.0, getup_timeout_s=100.0))
    modes = [o.mode for o in _run(sup, [D(90)] + [D(11), D(13)] * 100)]
    assert modes[0] == Mode.GETTING_UP and set(modes[1:]) == {Mode.STANDING_HOLD}


def test_timeout_eases_to_rest_then_retries():
    cfg = _config(
        fall_confirm_s=0.0, settle_s=0.0, stand_dwell_s=0.5, getup_timeout_s=1.0, rest_s=0.6, rest_ease_s=0.4
    )
    getup = _Getup(np.full(12, 0.5))
    sup = _sup(cfg, getup)
    outs = _run(sup, [D(120)] * 110)  # on its side, never getting up
    modes = [o.mode for o in outs]
    # getting_up 50 ticks (1 s), resting 30 ticks (0.6 s), then a new attempt of 50 ticks
    assert modes[:50] == [Mode.GETTING_UP] * 50
    assert modes[50:80] == [Mode.RESTING] * 30
    assert modes[80:110] == [Mode.GETTING_UP] * 30
    # the ease reaches the rest pose (the home stance) after rest_ease_s (20 ticks) and holds it
    np.testing.assert_allclose(outs[69].motor_targets, HOME, atol=1e-12)
    np.testing.assert_allclose(outs[79].motor_targets, HOME, atol=1e-12)
    assert not np.allclose(outs[68].motor_targets, HOME)
    # a new attempt starts with last_action 0 (the first attempt's first tick too)
    last = obs_spec.getup_observation(C.MOTOR_JOINTS).slices()["last_action"]
    assert np.all(getup.seen[0][last] == 0) and np.all(getup.seen[50][last] == 0)
    assert np.allclose(getup.seen[51][last], 0.5)


def test_back_to_walking_after_the_dwell():
    cfg = _config(fall_confirm_s=0.0, settle_s=0.0, stand_dwell_s=0.5)
    sup = _sup(cfg)
    # fallen for 10 ticks, then upright (5 deg): standing_hold for 25 ticks, then walking
    outs = _run(sup, [D(100)] * 10 + [D(5)] * 40)
    modes = [o.mode for o in outs]
    assert modes[:10] == [Mode.GETTING_UP] * 10
    assert modes[10:35] == [Mode.STANDING_HOLD] * 25
    assert modes[35:] == [Mode.WALKING] * 15
    assert sup.walking.time_s == pytest.approx(15 * 0.02)  # the walk restarted at the switch
    # its heading too: standing up facing yaw 0.7 rad, the walk's observed yaw is 0 again
    sup = _sup(cfg)
    for r, yaw in [(0.0, 0.0)] * 5 + [(D(100), 0.3)] * 10 + [(D(5), 0.7)] * 30:  # walked at yaw 0
        sup.step(_quat(r, 0.0, yaw), np.zeros(3), HOME)
    assert sup.mode == Mode.WALKING
    np.testing.assert_allclose(
        sup.walking.observer.heading, [math.cos(-0.35), 0, 0, math.sin(-0.35)], atol=1e-9
    )


def test_every_switch_blends_and_no_tick_jumps():
    blend_s = 0.2  # 10 ticks: the first blended tick moves smoothstep(0.1) = 0.028 of the way
    cfg = _config(fall_confirm_s=0.0, settle_s=0.1, stand_dwell_s=0.2, blend_s=blend_s)
    getup = _Getup(np.ones(12))  # every motor to its upper limit: far from the walking targets
    sup = _sup(cfg, getup)
    outs = _run(sup, [0.0] * 20 + [D(170)] * 30 + [D(3)] * 40)
    sent = np.array([o.motor_targets for o in outs])
    modes = [o.mode for o in outs]
    k = modes.index(Mode.GETTING_UP)
    held = sent[k - 1]  # fallen held the targets of the tick before the fall
    np.testing.assert_allclose(sent[20:k], np.broadcast_to(sent[19], (k - 20, 12)), atol=1e-12)
    r = sup.walking.config.robot
    target = r.clamp(getup_targets(np.ones(12), r.home_motor))  # all-upper, then the guards
    w1 = 0.1 * 0.1 * (3.0 - 2.0 * 0.1)
    np.testing.assert_allclose(sent[k], held + w1 * (target - held), atol=1e-12)
    np.testing.assert_allclose(sent[k + 9], target, atol=1e-12)  # the blend ends after 10 ticks
    back = modes.index(Mode.WALKING, k)
    np.testing.assert_allclose(sent[back], sent[back - 1], atol=0.1)  # walking starts where it was
    steps = np.max(np.abs(np.diff(sent, axis=0)), axis=1)
    assert np.max(steps) <= r.servo_speed_rps * 0.02 + 1e-9
    # the blend keeps every tick's change a fraction of the way: the largest is the smoothstep's
    # steepest step (1.5 / 10 of the way) and well below the rate limit
    assert np.max(steps) <= 0.151 * np.max(np.abs(target - held)) + 0.1


def test_nan_imu_takes_the_safety_path_and_freezes_the_modes():
    cfg = _config(fall_confirm_s=0.0, settle_s=0.0)
    sup = _sup(cfg)
    nan_q = np.array([np.nan, 0.0, 0.0, 0.0])
    last = _run(sup, [0.0] * 5)[-1]
    out = sup.step(nan_q, np.zeros(3), HOME)  # while walking: the walking loop's hold
    assert out.mode == Mode.WALKING and out.fault == Fault.HOLD and math.isnan(out.tilt_rad)
    np.testing.assert_allclose(out.motor_targets, last.motor_targets, atol=1e-12)
    last = _run(sup, [D(90)] * 3)[-1]
    assert last.mode == Mode.GETTING_UP
    ticks = (sup.mode_ticks, sup.attempt_ticks)
    outs = [sup.step(nan_q, np.zeros(3), HOME) for _ in range(3)]
    assert all(o.mode == Mode.GETTING_UP and o.fault == Fault.HOLD and o.action is None for o in outs)
    for o in outs:
        np.testing.assert_allclose(o.motor_targets, last.motor_targets, atol=1e-12)
    assert (sup.mode_ticks, sup.attempt_ticks) == ticks  # no timer ran on the bad ticks
    assert sup.fault_counts["imu_nonfinite"] == 4
    # a fault long enough to ease home (hold 0.2 s + 0.6 s of the 1 s ease): the first good tick
    # blends from the eased targets toward the policy's again (smoothstep(1 / 13) of the way)
    eased = [sup.step(nan_q, np.zeros(3), HOME) for _ in range(40)][-1]
    assert eased.fault == Fault.EASING_HOME
    r = sup.walking.config.robot
    target = r.clamp(getup_targets(np.zeros(12), r.home_motor))
    back = sup.step(_quat(D(90)), np.zeros(3), HOME)
    w = (1 / 13) ** 2 * (3 - 2 / 13)
    np.testing.assert_allclose(back.motor_targets, eased.motor_targets + w * (target - eased.motor_targets))
    # a NaN action from the get-up policy holds as well
    sup.getup.policy.action = np.full(12, np.nan, np.float32)
    out = sup.step(_quat(D(90)), np.zeros(3), HOME)
    assert out.fault == Fault.HOLD and sup.fault_counts["policy_nonfinite"] == 1


def test_getup_observation_and_targets_from_hand_values():
    getup = _Getup(np.linspace(-1.0, 1.0, 12))
    sup = _sup(_config(fall_confirm_s=0.0, settle_s=0.0), getup)
    motor = HOME + 0.01
    gyro = np.array([0.1, -0.2, 0.3])
    sup.step(_quat(D(90)), gyro, motor)
    sup.step(_quat(D(90)), gyro, motor)
    obs = obs_spec.getup_observation(C.MOTOR_JOINTS).split(getup.seen[1])
    # rolled 90 deg about x: gravity (0, 0, -1) in the body frame is (0, -sin 90, -cos 90)
    np.testing.assert_allclose(obs["gravity"], [0.0, -1.0, 0.0], atol=1e-7)
    np.testing.assert_allclose(obs["gyro"], gyro, rtol=1e-6)
    np.testing.assert_allclose(obs["motor_pos"], motor, rtol=1e-6)
    np.testing.assert_allclose(obs["last_action"], getup.action, rtol=1e-6)
    # 0 the home stance; t0 alone (the leg plane's swing) reaches its limits: -pi/2 at -1, +pi/2 at +1
    limits = np.tile(C.MOTOR_RANGES, (4, 1))
    np.testing.assert_allclose(getup_targets(np.zeros(12), HOME), HOME, atol=1e-12)
    t0 = np.zeros(12)
    t0[0::3] = 1.0
    np.testing.assert_allclose(getup_targets(t0, HOME), HOME + t0 * (limits[:, 1] - HOME), atol=1e-12)
    np.testing.assert_allclose(getup_targets(-t0, HOME), HOME - t0 * (HOME - limits[:, 0]), atol=1e-12)
    np.testing.assert_allclose(getup_targets(-t0, HOME)[0::3], -np.pi / 2, atol=1e-12)
    # +5 clips to +1: every motor at its upper limit, then the toe-in guard (t5 <= t1 + 0.06)
    out = getup_targets(np.full(12, 5.0), HOME).reshape(4, 3)
    np.testing.assert_allclose(out[:, 0], np.pi / 2, atol=1e-12)
    assert np.all(out[:, 2] - out[:, 1] <= C.TOE_IN_MAX + 1e-12)


def test_config_and_policy_errors_are_one_line():
    for kwargs, name in (
        ({"fall_tilt_rad": math.nan}, "fall_tilt_rad"),
        ({"blend_s": 0.0}, "blend_s"),
        ({"settle_s": -1.0}, "settle_s"),
        ({"upright_tilt_rad": D(30)}, "upright_tilt_rad <"),
        ({"rest_ease_s": 3.0}, "rest_ease_s"),
        ({"stand_dwell_s": 7.0}, "stand_dwell_s"),
        ({"fall_tilt_rad": True}, "fall_tilt_rad"),
    ):
        with pytest.raises(ValueError, match=name) as e:
            SupervisorConfig(**kwargs)
        assert "\n" not in str(e.value)
    bad = _Getup()
    bad.obs_size = 29
    with pytest.raises(ValueError, match="takes 29 observations"):
        _sup(getup=bad)
    wrong = _Getup()
    wrong.meta = {"obs_spec": obs_spec.getup_action(C.MOTOR_JOINTS).to_json()}
    with pytest.raises(ValueError, match="obs_spec is not the get-up task's"):
        _sup(getup=wrong)
    with pytest.raises(ValueError, match="rest_motor"):
        Supervisor(deploy.DeployLoop(_Walk()), _Getup(), rest_motor=np.full(12, 9.0))


def test_an_exported_getup_file_loads_and_drives(tmp_path):
    """A get-up .npz written by the export's own array writer (random weights, the get-up task's
    specs in its metadata) loads with deploy_policy.load_policy and drives the getting_up ticks:
    its targets are getup_targets of the file's own numpy inference, clamped."""
    from quadson_mjx.deploy_policy import load_policy
    from quadson_mjx.export import export_arrays

    rng = np.random.default_rng(5)
    sizes = [30, 16, 24]  # tanh_normal: the last layer gives (mean, scale) of 12 actions
    params = {f"hidden_{i}": {"kernel": rng.normal(0, 0.5, (a, b)), "bias": rng.normal(0, 0.1, b)} for i, (a, b) in enumerate(zip(sizes, sizes[1:], strict=False))}  # fmt: skip
    meta = {
        "env_config": {"robot": "quadson", "task": "getup"},
        "obs_spec": obs_spec.getup_observation(C.MOTOR_JOINTS).to_json(),
        "action_spec": obs_spec.getup_action(C.MOTOR_JOINTS).to_json(),
    }
    arrays = export_arrays((None, {"params": params}), 30, 12, False, meta)
    np.savez(tmp_path / "getup.npz", **arrays)
    policy = load_policy(tmp_path / "getup.npz")
    sup = _sup(_config(fall_confirm_s=0.0, settle_s=0.0, blend_s=0.02), policy)
    out = sup.step(_quat(D(180)), np.zeros(3), HOME)  # on its back: getting_up at once, no blend
    # the observation on its back, by hand: gravity (0, 0, 1) in the body, gyro 0, home, no action yet
    obs = np.concatenate([[0.0, 0.0, 1.0], np.zeros(3), HOME, np.zeros(12)]).astype(np.float32)
    action = policy(obs)
    np.testing.assert_allclose(out.action, np.clip(action, -1, 1), atol=1e-6)
    r = sup.walking.config.robot
    want = r.clamp(getup_targets(action, r.home_motor))
    step = r.servo_speed_rps * 0.02  # the rate limit from the targets sent before (home)
    np.testing.assert_allclose(out.motor_targets, HOME + np.clip(want - HOME, -step, step), atol=1e-5)


def test_closed_loop_in_mujoco_c_fall_getup_stand_walk():
    """The supervisor on sim2sim's plant (MuJoCo C, full contacts, servo model, exact sensors):
    walking, a roll kick throws the robot on its back, the fall is detected on the 5th tick whose
    true tilt is above 50 deg, get-up starts 15 ticks later; the robot is then set upright (the
    plant's reset stands in for a trained get-up policy) and walking resumes after the 1 s dwell
    and stays up. Every target sent is in the limits, within the servo's rate and keeps the toe-in
    guard; the chains stay closed."""
    from quadson_mjx import sim2sim_plant as P
    from quadson_mjx.robots import get_robot
    from quadson_mjx.sim2sim_model import plant_model

    robot = get_robot("quadson")
    plant = P.Plant(robot, plant_model(robot, "flat"), P.ServoParams(), P.SensorParams(enabled=False))
    plant.reset()
    sup = _sup()
    r = sup.walking.config.robot
    lo, hi = r.motor_limits[:, 0], r.motor_limits[:, 1]
    sup.getup.policy.action = np.zeros(12, np.float32)  # the home stance
    sup.reset(plant.read().motor_pos)
    modes, true_tilt, sent = [], [], [sup.sent]
    for k in range(230):
        if k == 30:
            plant.d.qvel[3] = 30.0  # roll rate [rad/s]: over onto the back
        if k == 120:
            plant.reset()  # upright on the home stance
        rd = plant.read()
        out = sup.step(rd.imu_quat_wxyz, rd.gyro, rd.motor_pos, command=(0.2, 0.0, 0.0))
        roll, pitch, _ = plant.truth()["rpy"]
        true_tilt.append(math.acos(math.cos(roll) * math.cos(pitch)))
        modes.append(out.mode)
        sent.append(out.motor_targets)
        plant.send(out.motor_targets)
        plant.advance(0.02)
        assert np.all(np.isfinite(plant.d.qpos)) and np.max(plant.closure_gaps()) < 2e-3
    above = np.array(true_tilt) > D(50)
    fall = next(k for k in range(4, 230) if above[k - 4 : k + 1].all())
    assert modes.index(Mode.FALLEN) == fall and 30 < fall < 60
    assert modes[fall + 15] == Mode.GETTING_UP and max(true_tilt[fall + 15 : 120]) > D(150)  # on its back
    assert modes[120:170] == [Mode.STANDING_HOLD] * 50 and modes[170:] == [Mode.WALKING] * 60
    assert max(true_tilt[170:]) < D(30)
    sent = np.array(sent)
    assert np.all(sent >= lo - 1e-12) and np.all(sent <= hi + 1e-12)
    assert np.max(np.abs(np.diff(sent, axis=0))) <= r.servo_speed_rps * 0.02 + 1e-9
    assert np.all(sent.reshape(-1, 4, 3)[:, :, 2] - sent.reshape(-1, 4, 3)[:, :, 1] <= C.TOE_IN_MAX + 1e-12)


def test_the_supervisor_imports_neither_jax_nor_mujoco():
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys; from quadson_mjx import deploy, deploy_supervisor;"
        "print(sorted(n for n in ('jax', 'brax', 'flax', 'mujoco') if n in sys.modules))"
    )
    root = Path(__file__).resolve().parents[1]
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root)
    assert res.stdout.strip() == "[]"
