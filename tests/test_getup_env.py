"""The get-up task (quadson_mjx.getup_env): its action guard against the five-bar's own closure test,
its starts and model against MuJoCo C, its success measure on hand-worked cases, and its observation
against the robot-side supervisor's on the same sensor stream."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from state_types import assert_evaluation_compiles_once

from quadson_mjx import obs_spec
from quadson_mjx.config import apply_overrides
from quadson_mjx.deploy_supervisor import getup_targets
from quadson_mjx.env_config import env_config
from quadson_mjx.getup_env import STANDING_CLASS, TOPPLED_CLASS, GetupEnv
from quadson_mjx.robots.quadson import chain_guard, fivebar, getup_start
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson.mirror import mirror_getup_observation, mirror_motors
from quadson_mjx.wrappers import wrap_for_training

ROOT = Path(__file__).resolve().parents[1]
N = 32  # environments of the compiled batch


@pytest.fixture(scope="session")
def getup():
    """The task's env (half the starts standing) with its reset and step jitted and vmapped once."""
    cfg = apply_overrides(
        env_config(task="getup", randomize=True),
        ["getup.stand_start_prob=0.5", "getup.servo_speed_limit=true"],  # every step through the limit
        prefix="env.",
    )
    env = GetupEnv(cfg)
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


@pytest.fixture(scope="session")
def rollout(getup):
    """60 ticks (1.2 s) of zero actions from N starts: (first state, per-tick metrics, last state)."""
    env, reset, step = getup
    s0 = reset(jax.random.split(jax.random.key(11), N))
    s, metrics = s0, []
    for _ in range(60):
        s = step(s, jnp.zeros((N, 12)))
        metrics.append({k: np.asarray(v) for k, v in s.metrics.items()})
    return s0, metrics, s


def test_chain_slack_agrees_with_the_five_bar_closure_test():
    """chain_slack >= 0 at zero margin is fivebar.chain_closes (its own law-of-cosines bound), on
    10^4 random motor angles inside and around the limits."""
    rng = np.random.default_rng(0)
    angles = rng.uniform(-1.0, 4.5, (10_000, 3))
    closes = np.asarray(fivebar.chain_closes(jnp.asarray(angles)))
    slack = chain_guard.chain_slack(angles, np, margin_m=0.0)
    assert 0.2 < closes.mean() < 0.95  # both sides sampled
    decided = np.abs(slack) > 1e-6  # float32 on the JAX side
    assert np.array_equal(slack[decided] >= 0.0, closes[decided])


def test_guarded_targets_are_reachable_and_numpy_equals_jax(getup):
    """Random actions (beyond [-1, 1] too): every target inside the limits, the toe-in guard and the
    chain band with its 5 mm margin; a target that already was is unchanged; the supervisor's numpy
    targets equal the environment's JAX ones (float32)."""
    env = getup[0]
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1.3, 1.3, (2000, 12))
    home = np.asarray(env._home_motor).reshape(12).astype(np.float64)
    np_targets = np.stack([getup_targets(a, home) for a in actions])
    jax_targets, moved = jax.jit(jax.vmap(env.motor_targets))(jnp.asarray(actions, jnp.float32))
    np.testing.assert_allclose(np.asarray(jax_targets), np_targets, atol=2e-5)
    legs = np_targets.reshape(-1, 4, 3)
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    assert np.all(legs >= lo - 1e-9) and np.all(legs <= hi + 1e-9)
    assert np.all(legs[..., 2] - legs[..., 1] <= C.TOE_IN_MAX + 1e-9)
    assert np.all(chain_guard.chain_slack(legs) >= -1e-9)
    moved = np.asarray(moved)
    assert 0.05 < moved.mean() < 0.95  # the guard both acts and stays out of the way
    raw = home + np.where(actions < 0, np.clip(actions, -1, 1) * (home - np.tile(lo, 4)), np.clip(actions, -1, 1) * (np.tile(hi, 4) - home))  # fmt: skip
    kept = chain_guard.range_and_toe_in(raw.reshape(-1, 4, 3))
    np.testing.assert_allclose(legs[~moved], kept[~moved], atol=1e-12)
    np.testing.assert_allclose(getup_targets(np.zeros(12), home), home, atol=1e-12)


def test_starts_are_inside_the_limits_and_clear_of_the_ground_in_mujoco_c(rollout, getup):
    """Every drop: motor angles inside the limits and the toe-in guard, chains closed, legs apart,
    and in MuJoCo C (the task's own model, legs touching the ground) no contact at all; the
    standing starts stand on their feet."""
    env = getup[0]
    s0 = rollout[0]
    m = env.mj_model
    d = mujoco.MjData(m)
    qpos = np.asarray(s0.pipeline_state.qpos, np.float64)
    cls = np.asarray(s0.info["start_class"])
    home = np.isin(cls, [STANDING_CLASS, TOPPLED_CLASS])  # the task's toppled starts stand at home too
    assert 0 < np.sum(cls == STANDING_CLASS) < N and 0 < np.sum(cls == TOPPLED_CLASS) < N
    motor = qpos[:, np.asarray(env._motor_qpos)].reshape(-1, 4, 3)
    assert np.all(np.asarray(fivebar.within_limits(jnp.asarray(motor))))
    assert np.all(np.asarray(jax.vmap(getup_start.self_clearance)(jnp.asarray(motor[~home]))) > 0.0)
    feet = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in env.robot.foot_geoms()}
    for q, c in zip(qpos, home, strict=True):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        geoms = {int(g) for g in d.contact.geom.ravel()[: 2 * d.ncon]} - {0}
        if c:
            assert geoms <= feet  # only the feet touch
        else:
            assert d.ncon == 0
            lowest = min(float(d.geom_xpos[g, 2]) for g in range(1, m.ngeom))
            assert lowest > 0.15  # every geom centre well above the ground (drops are 0.2-0.5 m)


def test_zero_action_success_by_hand(rollout, getup):
    """Zero actions hold the home stance: a standing start stands from the first tick, so its 1 s
    hold completes on tick 50 (1.0 s / 20 ms), once, and the stand began at 0 s. A drop onto the back
    with the legs at home stays on its back (tilt > 90 deg) and never succeeds."""
    env = getup[0]
    s0, metrics, last = rollout
    cls = np.asarray(s0.info["start_class"])
    stand = cls == STANDING_CLASS
    success = np.stack([mt["success"] for mt in metrics])  # (60, N)
    assert np.all(success[49, stand] == 1.0) and np.all(success[:, stand].sum(0) == 1.0)
    assert np.all(np.stack([mt["time_to_stand"] for mt in metrics])[49, stand] == 0.0)
    np.testing.assert_allclose(np.asarray(last.info["success_s"])[stand], 0.0)
    height = metrics[-1]["base_height"][stand]
    assert np.all(np.abs(height - env.stand_height) < 0.02)
    back = cls == getup_start.CLASSES.index("back")
    assert back.any()
    assert np.all(success[:, back] == 0.0) and np.all(metrics[-1]["tilt"][back] > np.pi / 2)
    assert all(np.all(mt["nan_reset"] == 0) for mt in metrics)


def test_toppled_starts_tip_about_the_feet_and_fast_ones_fall_in_mujoco_c(getup):
    """A toppled start's velocity by hand: the angular velocity horizontal, of a rate inside
    topple_rate_rps, the base moving at rate x standing height along u, perpendicular to the axis
    and toward the tip (z x u = axis). In MuJoCo C (the task's model, the home targets held) the
    slow tips (below 2.5 rad/s) stay within 20 deg over 1 s and the fast ones (above 6 rad/s) go over
    90 deg: the start is a knock-over, not a wobble. Starts not toppled have no velocity."""
    env = getup[0]
    g = env.config.getup
    keys = jax.random.split(jax.random.key(5), 64)
    toppled, qvel = jax.jit(jax.vmap(env._topple))(keys, jnp.ones(64, bool))
    toppled, qvel = np.asarray(toppled), np.asarray(qvel, np.float64)
    assert 0 < toppled.sum() < 64  # topple_prob 0.5 of the standing starts
    assert np.all(qvel[~toppled] == 0.0)
    v, w = qvel[toppled, 0:3], qvel[toppled, 3:6]
    rate = np.linalg.norm(w, axis=1)
    assert np.all(w[:, 2] == 0.0) and np.all(v[:, 2] == 0.0)
    assert np.all((rate >= g.topple_rate_rps[0]) & (rate <= g.topple_rate_rps[1]))
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), rate * env.stand_height, rtol=1e-5)
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(np.cross([0.0, 0.0, 1.0], u), w / rate[:, None], atol=1e-5)
    m = env.mj_model
    d = mujoco.MjData(m)
    ctrl = np.asarray(env._home_ctrl, np.float64)
    tilts = []
    for vel in qvel[toppled]:
        mujoco.mj_resetData(m, d)
        d.qpos[:] = np.asarray(env._home_qpos, np.float64)
        d.qpos[:2] = 0.0
        d.qvel[:] = vel
        d.ctrl[:] = ctrl
        top = 0.0
        for _ in range(int(round(1.0 / m.opt.timestep))):
            mujoco.mj_step(m, d)
            top = max(top, float(np.arccos(np.clip(d.xmat[env.base_body, 8], -1.0, 1.0))))
        tilts.append(top)
    rates, tilts = np.linalg.norm(qvel[toppled, 3:6], axis=1), np.degrees(tilts)
    assert np.sum(rates < 2.5) and np.sum(rates > 6.0)
    assert np.all(tilts[rates < 2.5] < 20.0), tilts[rates < 2.5]
    assert np.all(tilts[rates > 6.0] > 90.0), tilts[rates > 6.0]


def test_legs_touch_the_ground_in_the_task_model(rollout, getup):
    """A drop lands on its links and hips, not only on its feet: in MuJoCo C, 1 s after a drop of
    the batch, contacts involve leg geoms other than the feet, and no geom centre is below the
    ground by more than its size (nothing falls through)."""
    env = getup[0]
    s0 = rollout[0]
    m = env.mj_model
    d = mujoco.MjData(m)
    cls = np.asarray(s0.info["start_class"])
    k = int(np.flatnonzero(cls == getup_start.CLASSES.index("back"))[0])
    d.qpos[:] = np.asarray(s0.pipeline_state.qpos[k], np.float64)
    d.ctrl[:] = np.asarray(s0.pipeline_state.ctrl[k], np.float64)
    feet = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in env.robot.foot_geoms()}
    touched = set()
    for _ in range(250):  # 1 s at 4 ms
        mujoco.mj_step(m, d)
        touched |= {int(g) for g in d.contact.geom.ravel()[: 2 * d.ncon]}
    assert touched - feet - {0}, "no leg link or hip touched the ground"
    assert np.min(d.geom_xpos[1:, 2] + m.geom_rbound[1:]) > 0.0


def test_a_step_keeps_the_state_types_so_the_evaluation_compiles_once(getup):
    """Regression: the reset's success_s was weakly typed and the step's not, so brax's evaluation
    of the get-up task compiled twice."""
    env = getup[0]
    assert_evaluation_compiles_once(wrap_for_training(env, 10), env.action_size, 2)


def test_actor_sees_the_robots_sensors_and_the_critic_more(getup):
    env = getup[0]
    assert env.obs_spec == obs_spec.getup_observation(C.MOTOR_JOINTS)
    assert env.observation_size == {"state": (30,), "privileged_state": (env.critic_spec.size,)}
    actor_names = set(env.obs_spec.names)
    critic_names = set(env.critic_spec.names)
    assert actor_names < critic_names
    assert not {n for n in critic_names - actor_names if not n.startswith(("true_", "base_height", "foot_", "ground_", "physics", "sensor_model"))}  # fmt: skip


def test_training_on_one_side_is_the_mirror_image_of_the_plain_task(getup):
    """env.getup.mirror_to=left against the same task without it, from the same keys: the same
    starts; where the right side is lower at the start (a drop: the IMU's gravity y < 0; a
    knock-over: tipping toward -y) the actor sees the mirrored observation and its action reaches
    the robot mirrored; elsewhere, and for the critic, reward and physics, nothing changes."""
    env, reset, step = getup
    one_side = GetupEnv(apply_overrides(env.config, ["getup.mirror_to=left"], prefix="env."))
    assert "mirrored" in one_side.restart_info and "mirrored" not in env.restart_info
    l_reset, l_step = jax.jit(jax.vmap(one_side.reset)), jax.jit(jax.vmap(one_side.step))
    keys = jax.random.split(jax.random.key(21), N)
    s, sl = reset(keys), l_reset(keys)
    np.testing.assert_array_equal(sl.pipeline_state.qpos, s.pipeline_state.qpos)
    m = np.asarray(sl.info["mirrored"])
    toppled = np.asarray(s.info["start_class"]) == TOPPLED_CLASS
    lower_right = np.where(
        toppled, np.asarray(s.pipeline_state.qvel[:, 1]) < 0, np.asarray(s.obs["state"][:, 1]) < 0
    )
    np.testing.assert_array_equal(m, lower_right)
    assert 0 < m.sum() < N and (m & toppled).any() and (~m & toppled).any()  # every case occurs

    def seen(plain_obs):  # what the one-sided env's actor must see of the plain env's observation
        o = np.asarray(plain_obs)
        return np.where(m[:, None], mirror_getup_observation(o), o)

    np.testing.assert_array_equal(np.asarray(sl.obs["state"]), seen(s.obs["state"]))
    np.testing.assert_array_equal(sl.obs["privileged_state"], s.obs["privileged_state"])
    a = jax.random.uniform(jax.random.key(3), (N, 12), minval=-1.0, maxval=1.0)
    for _ in range(3):
        s = step(s, jnp.where(m[:, None], mirror_motors(a), a))  # the plain env given the robot's action
        sl = l_step(sl, a)
    np.testing.assert_allclose(sl.pipeline_state.qpos, s.pipeline_state.qpos, atol=1e-6)
    np.testing.assert_allclose(np.asarray(sl.obs["state"]), seen(s.obs["state"]), atol=1e-6)
    np.testing.assert_allclose(sl.obs["privileged_state"], s.obs["privileged_state"], atol=1e-6)
    np.testing.assert_allclose(sl.reward, s.reward, atol=1e-6)
    np.testing.assert_array_equal(sl.info["mirrored"], m)


def test_env_and_supervisor_build_one_observation():
    """The environment's observation of a physics state (no sensor noise) and the supervisor's
    get-up observer fed that state's IMU quaternion, gyro and encoders agree to float32."""
    from quadson_mjx.deploy import DeployLoop
    from quadson_mjx.deploy_supervisor import GetupPolicy

    env = GetupEnv(env_config(task="getup"))
    s = env.reset(jax.random.key(4))
    info = dict(s.info)
    info["last_action"] = jnp.linspace(-1.0, 1.0, 12)
    qpos = np.asarray(s.pipeline_state.qpos, np.float64)
    qvel = np.zeros(env.sys.nv)
    qvel[3:6] = [0.3, -0.2, 0.1]
    obs = np.asarray(env.observation(qpos, qvel, info))

    class _Policy:
        obs_size, action_size = 30, 12

        def __call__(self, o):
            return np.asarray(info["last_action"], np.float32)

    from tests.test_deploy_supervisor import _Walk  # the walking loop's stand-in

    robot = DeployLoop(_Walk()).config.robot
    g = GetupPolicy(_Policy(), robot, 0.02)
    res = env.config.sensor.encoder_resolution_rad  # what 12-bit encoders report of the true angles
    encoders = np.round(qpos[np.asarray(env._motor_qpos)] / res) * res
    g.act(qpos[3:7], qvel[3:6], encoders)  # commits last_action
    want = g.act(qpos[3:7], qvel[3:6], encoders)[2]
    np.testing.assert_allclose(obs, want, atol=1e-6)


def test_eval_cli_bad_input_is_one_line_and_exit_2(tmp_path):
    cases = [
        (["--run", str(tmp_path)], "not a training run directory"),
        (["--run", str(ROOT / "results/tiles_h100")], "not getup"),
        (["--run", str(ROOT / "results/getup_h100"), "--ground", "mud"], "--ground mud"),
        (["--run", str(ROOT / "results/getup_h100"), "--drops", "0"], "--drops 0"),
        (
            ["--run", str(ROOT / "results/getup_h100"), "--servo-speed-limit", "fast"],
            "--servo-speed-limit fast",
        ),
    ]
    for argv, words in cases:
        res = subprocess.run([sys.executable, str(ROOT / "eval/getup.py"), *argv], capture_output=True, text=True, cwd=ROOT)  # fmt: skip
        assert res.returncode == 2, res.stderr
        assert res.stderr.count("\n") == 1 and words in res.stderr, res.stderr


def test_eval_servo_speed_limit_option_sets_the_physics_key():
    """--servo-speed-limit on/off sets env.getup.servo_speed_limit of the run's config (which the
    environment's substep reads, see test_servo_speed_limit_is_sim2sims_servo_model); trained keeps it."""
    from quadson_mjx.cli.getup_eval import with_servo_speed_limit
    from quadson_mjx.training import load_run_config

    env_cfg, _ = load_run_config(ROOT / "results/getup_mirror_ft_h200")
    assert env_cfg.getup.servo_speed_limit is False
    assert with_servo_speed_limit(env_cfg, "on").getup.servo_speed_limit is True
    assert with_servo_speed_limit(env_cfg, "off").getup.servo_speed_limit is False
    assert with_servo_speed_limit(env_cfg, "trained") is env_cfg
    # the committed fine-tune with the limit (its config only, no checkpoint)
    servo_run = json.loads(
        (ROOT / "results/getup_mirror_ft_h200/servo_limit_h200/run_config.json").read_text()
    )
    assert servo_run["env"]["getup"]["servo_speed_limit"] is True


def test_committed_policy_evaluates_on_the_cpu():
    """The committed run's policy through the evaluation (the production path: wrappers, randomized
    models, the jitted scan), 4 drops on flat ground: one row per class, counts add up."""
    from quadson_mjx.getup_eval import evaluate_getup
    from quadson_mjx.training import load_policy

    policy, env_cfg, _, _ = load_policy(ROOT / "results/getup_h100")
    rows, total = evaluate_getup(env_cfg, policy, "flat", drops=4, seed=0)
    assert [r["start_class"] for r in rows] == list(getup_start.CLASSES)
    assert sum(r["drops"] for r in rows) == total["drops"] == 4
    assert total["non_finite_resets"] == 0 and 0 <= total["successes"] <= 4
    assert 0 <= total["failures_on_back"] <= 4 - total["successes"]
    assert total["failures_on_back"] == sum(r["failures_on_back"] for r in rows)
    from quadson_mjx.stats import success_interval  # tested against published intervals

    assert total["success_95"] == success_interval(total["successes"], 4)
    for r in rows:  # a class without a drop has no interval
        assert (
            r["success_95"] is None
            if r["drops"] == 0
            else r["success_95"][0] <= r["success"] <= r["success_95"][1]
        )
    # the breakdown by the tilt at the drop covers every drop once, in the bins it names
    from quadson_mjx.getup_eval import START_TILT_BINS_DEG

    bins = total["by_start_tilt"]
    assert [b["start_tilt_deg"] for b in bins] == [
        [lo, hi] for lo, hi in zip(START_TILT_BINS_DEG[:-1], START_TILT_BINS_DEG[1:], strict=True)
    ]
    for key in ("drops", "successes", "failures_on_back"):
        assert sum(b[key] for b in bins) == total[key], key
    saved = json.loads((ROOT / "results/getup_h100/eval_gpu.json").read_text())
    assert set(saved["grounds"]) == {"flat", "stones"}


def test_back_reach_bounds_against_mujoco_c_and_hand_values():
    """The back's reachability report: the left/right mirror of the robot makes the sideways range
    of the centre of mass symmetric, the home stance's centre of mass (MuJoCo C's subtree_com at
    the home keyframe) lies inside both ranges, and the hip box alone cannot reach the ground: its
    largest extent across the leg plane is sqrt(0.025^2 + 0.02^2) = 32 mm < the box's 40 mm, so the
    reach (links and feet) stays within a leg's radius and a foot's of the top face."""
    from quadson_mjx.robots.quadson import getup_reach
    from quadson_mjx.robots.quadson import model as quadson_model

    m = quadson_model.load_model("flat")
    r = getup_reach.back_reach(m, samples=400, seed=1)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home"))
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    home = d.subtree_com[1] - d.qpos[:3]  # body frame: the home keyframe's base is not rotated
    assert r["com_y_m"][0] < home[1] < r["com_y_m"][1] and r["com_x_m"][0] < home[0] < r["com_x_m"][1]
    assert abs(r["com_y_m"][0] + r["com_y_m"][1]) < 2e-3  # mirror symmetric (400 draws per leg)
    assert np.hypot(0.025, 0.02) < C.BASE_HALF_SIZE[2]
    assert all(0.0 < x < C.LINK_RADIUS + 2 * C.FOOT_RADIUS for x in r["reach_m"])
    assert r["can_push"] and not r["can_tip_sideways"] and not r["can_tip_lengthwise"]


def test_servo_speed_limit_is_sim2sims_servo_model(getup):
    """The torque of the task's position servos under env_model.motoring_forcerange, computed by
    MuJoCo C's actuation, equals sim2sim_plant.servo_torque (the deploy-side servo model, numpy)
    with Quadson's line (stall twice the peak, no-load speed twice MOTOR_VELOCITY_LIMIT), at speeds
    from -70 to 65 rad/s with the error driving with and against the motion."""
    from quadson_mjx.env_model import motoring_forcerange
    from quadson_mjx.sim2sim_plant import MOTOR_TORQUE_SPEED, servo_torque

    env = getup[0]
    m = env.mj_model
    d = mujoco.MjData(m)
    act = np.asarray(env._actuator_of_motor)
    dof = np.asarray(env._motor_dof)
    qadr = np.asarray(env._motor_qpos)
    speed = np.array([-70.0, -50.0, -40.0, -20.0, 0.0, 10.0, 20.0, 35.0, 45.0, 55.0, 65.0, 5.0])
    no_load, stall = MOTOR_TORQUE_SPEED["quadson"]
    assert no_load == pytest.approx(2 * C.MOTOR_VELOCITY_LIMIT)
    nominal = m.actuator_forcerange.copy()
    for push in (1.0, -1.0):  # the error along the motion of the positive speeds, then against
        mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home"))
        d.qvel[dof] = speed
        target = d.qpos[qadr] + push * np.sign(speed + 1e-9) * 0.5
        d.ctrl[act] = target
        m.actuator_forcerange[:] = nominal
        m.actuator_forcerange[act] = np.asarray(
            motoring_forcerange(nominal[act], speed, C.MOTOR_VELOCITY_LIMIT), np.float64
        )
        mujoco.mj_forward(m, d)
        kp, kd, peak = m.actuator_gainprm[act, 0], -m.actuator_biasprm[act, 2], nominal[act, 1]
        assert stall == pytest.approx(2 * peak[0])
        want = servo_torque(target, d.qpos[qadr], speed, kp, kd, peak, stall, no_load, 0.0)
        np.testing.assert_allclose(d.actuator_force[act], want, atol=1e-9)
    m.actuator_forcerange[:] = nominal
    # by hand: motoring at 45 rad/s leaves peak (2 - 45 / 31.4); at 65 rad/s nothing
    assert d.actuator_force[act][8] == pytest.approx(-peak[8], rel=1e-6)  # braking: the full peak (float32)
    top = np.asarray(motoring_forcerange(nominal[act], speed, C.MOTOR_VELOCITY_LIMIT))
    assert (
        top[8, 1] == pytest.approx(peak[8] * (2 - 45.0 / C.MOTOR_VELOCITY_LIMIT), rel=1e-6)
        and top[10, 1] == 0.0
    )
