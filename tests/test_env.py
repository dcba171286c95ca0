"""The MJX environment on CPU, few environments: sizes, determinism, rewards by hand, termination,
truncation, NaN safety, and the gait-only controller standing its first second.

Compiled functions are shared through module fixtures: one jitted reset and step of the seed
preset (with a termination weight, which the preset leaves at 0, so that the term shows), one wrapped
(vmapped, auto-reset) step over 2 environments.
"""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import rewards
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.quat import quat_rotate_inverse, quat_to_rpy
from quadson_mjx.wrappers import wrap_for_training

TERMINATION = -10.0
EMA_WEIGHT = -0.7  # lin_vel_ema_error, off in the presets: on here so that one compile tests it


@pytest.fixture(scope="module")
def env():
    overrides = [
        f"reward.weights.termination={TERMINATION}",
        f"reward.weights.lin_vel_ema_error={EMA_WEIGHT}",
    ]
    return LocomotionEnv(apply_overrides(env_config(), overrides))


@pytest.fixture(scope="module")
def fns(env):
    return jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def wrapped(env):
    w = wrap_for_training(env, episode_length=3)
    return w, jax.jit(w.reset), jax.jit(w.step)


def test_sizes_and_finite_first_step(env, fns):
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    assert env.observation_size == 29 and env.action_size == 12  # seed 000 section 8.2
    assert s.obs.shape == (29,) and s.obs.dtype == jnp.float32
    s = step(s, jnp.zeros(12))
    assert s.obs.shape == (29,) and bool(jnp.all(jnp.isfinite(s.obs)))
    assert float(s.done) == 0.0 and float(s.metrics["nan_reset"]) == 0.0
    assert float(s.metrics["reward/termination"]) == 0.0  # standing: no fall, nothing paid
    # phase features: sin/cos of 2 pi phase; trot FL/RR at phase 0.025 after one 0.02 s step of a 0.8 s cycle
    phase = 2 * math.pi * (0.02 / 0.8 + np.array([0.0, 0.5, 0.5, 0.0]))
    np.testing.assert_allclose(s.obs[21:25], np.sin(phase), atol=1e-5)
    np.testing.assert_allclose(s.obs[25:29], np.cos(phase), atol=1e-5)


def test_deterministic_under_fixed_key(fns):
    reset, step = fns
    a = jnp.linspace(-1, 1, 12)
    s1 = step(reset(jax.random.PRNGKey(3)), a)
    s2 = step(reset(jax.random.PRNGKey(3)), a)
    np.testing.assert_array_equal(s1.obs, s2.obs)
    np.testing.assert_array_equal(s1.pipeline_state.qpos, s2.pipeline_state.qpos)


def test_reset_without_forward_steps_as_after_a_full_forward(env, fns):
    # reset computes kinematics only; a step from it must equal a step from the same state after
    # MJX's full forward (forces, constraints, contacts), step for step
    from mujoco import mjx

    reset, step = fns
    s = reset(jax.random.PRNGKey(5))
    d = s.pipeline_state
    # the frames are there: MuJoCo C's kinematics of the same qpos
    m = env.mj_model
    c = mujoco.MjData(m)
    c.qpos[:] = np.asarray(d.qpos)
    mujoco.mj_kinematics(m, c)
    np.testing.assert_allclose(d.xpos, c.xpos, atol=1e-6)
    np.testing.assert_allclose(d.site_xpos, c.site_xpos, atol=1e-6)
    full = s.replace(pipeline_state=jax.jit(mjx.forward)(env.sys, d))
    assert float(jnp.abs(full.pipeline_state.qfrc_actuator).max()) > 0  # forward did add something
    a = jnp.linspace(-0.5, 0.5, 12)
    for _ in range(5):
        s, full = step(s, a), step(full, a)
        np.testing.assert_array_equal(s.pipeline_state.qpos, full.pipeline_state.qpos)
        np.testing.assert_array_equal(s.pipeline_state.qvel, full.pipeline_state.qvel)
        np.testing.assert_array_equal(s.obs, full.obs)
        np.testing.assert_array_equal(s.reward, full.reward)


def test_reward_terms_by_hand(env, fns):
    reset, _ = fns
    s = reset(jax.random.PRNGKey(0))
    lin_vel = jnp.array([0.3, 0.1, -0.2])
    ang_vel = jnp.array([0.0, 0.5, 1.0])
    rpy = jnp.array([0.1, -0.2, 0.3])
    info = dict(s.info, last_action=jnp.zeros(12))
    z = float(s.pipeline_state.qpos[2])  # flat ground: the height above the ground is z
    contact = jnp.array([True, True, False, True])
    stance = jnp.array([True, False, False, True])
    # the table one step before and after: FR's stance ends this step (it was down one step ago)
    stance_near = jnp.stack([jnp.array([True, True, False, True]), stance, stance])
    terms = env._get_reward(
        s.pipeline_state, jnp.full(12, 0.5), info, rpy, lin_vel, ang_vel, z, contact, stance_near, True
    )
    # forward (sigma 0.25): exp(-(0.3 - 0.5)^2 / (2 * 0.0625)) = exp(-0.32); lateral: 0.5*0.01 + 0.3*0.25 = 0.08;
    # vertical: 0.5*0.04 + 0.3*1 = 0.32; orientation: 40*0.01 + 30*0.04 + 5*0.09 = 2.05;
    # action rate: 12 * 0.25 = 3; height: (z - 0.2)^2 with z the home base height.
    assert float(terms["forward_velocity_exp"]) == pytest.approx(math.exp(-0.32), rel=1e-6)
    assert float(terms["lateral_l2"]) == pytest.approx(0.08, rel=1e-6)
    assert float(terms["vertical_l2"]) == pytest.approx(0.32, rel=1e-6)
    assert float(terms["orientation_l2"]) == pytest.approx(2.05, rel=1e-6)
    assert float(terms["action_rate_l2"]) == pytest.approx(3.0, rel=1e-6)
    assert float(terms["height_l2"]) == pytest.approx((z - 0.2) ** 2, rel=1e-5)
    assert float(terms["contact_phase"]) == pytest.approx(0.75)  # 3 of 4 feet agree with the table
    # FR is down one step after the table lifted it: inside the one-step tolerance, so all four agree
    assert float(terms["contact_pattern"]) == 1.0
    assert float(terms["swing_touch"]) == 0.0  # FR's touch is inside the tolerance too
    assert float(terms["stance_lift"]) == 0.0  # no foot is up where the table says stance
    assert float(terms["termination"]) == 1.0  # the step's fall flag, as given
    # yaw-rate error squared: (1.0 - the command's yaw rate)^2
    wz_cmd = float(info["command"][2])
    assert float(terms["yaw_rate_error_l2"]) == pytest.approx((1.0 - wz_cmd) ** 2, rel=1e-6)
    # the seed preset's weights: its four terms as printed, tracking terms off
    w = env.config.reward.weights
    assert (w.forward_velocity_exp, w.lateral_l2, w.vertical_l2, w.orientation_l2) == (1.0, -0.8, -0.8, -1.0)
    assert w.lin_vel_tracking_exp == 0.0 and w.ang_vel_tracking_exp == 0.0 and w.yaw_rate_error_l2 == 0.0
    assert w.swing_touch == 0.0 and w.stance_lift == 0.0


def test_velocity_average_term_by_hand(env, fns):
    """lin_vel_ema_error: the planar velocity's moving average, from 0 at the reset, one step of
    v dt / tau per control step, and its distance to the command, against values computed here from
    the state's own base velocity (body frame) and command."""
    reset, step = fns
    s0 = reset(jax.random.PRNGKey(3))
    assert "vel_ema" in env.restart_info and np.all(np.asarray(s0.info["vel_ema"]) == 0.0)
    tau, dt = env.config.reward.velocity_ema_s, env.ctrl_dt
    assert (tau, dt) == (0.5, 0.02)
    s, ema = s0, np.zeros(2)
    for _ in range(3):
        s = step(s, jnp.full(12, 0.3))
        qpos, qvel = np.asarray(s.pipeline_state.qpos), np.asarray(s.pipeline_state.qvel)
        v = np.asarray(quat_rotate_inverse(jnp.asarray(qpos[3:7]), jnp.asarray(qvel[:3])))
        ema = ema + (v[:2] - ema) * dt / tau
        np.testing.assert_allclose(np.asarray(s.info["vel_ema"]), ema, rtol=1e-5, atol=1e-7)
        want = EMA_WEIGHT * np.linalg.norm(ema - np.asarray(s.info["command"])[:2])
        assert float(s.metrics["reward/lin_vel_ema_error"]) == pytest.approx(want, rel=1e-5, abs=1e-7)
    assert np.any(np.abs(ema) > 1e-4)  # the base moved: the check above was not of zeros
    # off (the presets): no average is kept and the term is 0
    off = LocomotionEnv(env_config())
    assert "vel_ema" not in off.restart_info and off.config.reward.weights.lin_vel_ema_error == 0.0
    terms = rewards.locomotion_terms(
        off.config.reward, 0.5, lin_vel=jnp.ones(3), ang_vel=jnp.ones(3), rpy=jnp.zeros(3), height=0.2,
        action=jnp.zeros(12), last_action=jnp.zeros(12), actuator_force=jnp.zeros(12),
        command=jnp.zeros(3), contact=jnp.ones(4, bool), stance=jnp.ones(4, bool),
        stance_near=jnp.ones((3, 4), bool), fallen=False,
    )  # fmt: skip
    assert float(terms["lin_vel_ema_error"]) == 0.0
    # a hand case: average (0.3, -0.4) against command (0, 0, 1): |(0.3, -0.4)| = 0.5
    assert float(
        rewards.lin_vel_ema_error(jnp.array([0.3, -0.4]), jnp.array([0.0, 0.0, 1.0]))
    ) == pytest.approx(0.5)


def test_step_reward_is_the_weighted_sum_of_logged_terms(fns):
    reset, step = fns
    s = step(reset(jax.random.PRNGKey(1)), jnp.zeros(12))
    total = sum(float(v) for k, v in s.metrics.items() if k.startswith("reward/"))
    assert float(s.reward) == pytest.approx(total, rel=1e-5, abs=1e-6)


def test_quaternion_helpers_by_hand():
    # 90 deg yaw: q = (cos 45, 0, 0, sin 45); world +x velocity is body -y.
    q = jnp.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    np.testing.assert_allclose(quat_to_rpy(q), [0.0, 0.0, math.pi / 2], atol=1e-6)
    np.testing.assert_allclose(
        quat_rotate_inverse(q, jnp.array([1.0, 0.0, 0.0])), [0.0, -1.0, 0.0], atol=1e-6
    )
    # roll 0.3 then pitch -0.2 (ZYX): q = q_y(-0.2) * q_x(0.3)
    cr, sr, cp, sp = math.cos(0.15), math.sin(0.15), math.cos(-0.1), math.sin(-0.1)
    q = jnp.array([cp * cr, cp * sr, sp * cr, -sp * sr])
    np.testing.assert_allclose(quat_to_rpy(q), [0.3, -0.2, 0.0], atol=1e-6)


def test_flipped_robot_terminates(fns):
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    d = s.pipeline_state
    roll = math.radians(60)
    quat = jnp.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
    s = s.replace(pipeline_state=d.replace(qpos=d.qpos.at[3:7].set(quat)))
    s = step(s, jnp.zeros(12))
    assert float(s.done) == 1.0 and float(s.metrics["nan_reset"]) == 0.0
    # a fall, paid once by the termination term
    assert float(s.metrics["fall"]) == 1.0
    assert float(s.metrics["reward/termination"]) == TERMINATION


def test_nan_state_ends_episode_counted_and_clean(fns, wrapped):
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    d = s.pipeline_state
    s = s.replace(pipeline_state=d.replace(qvel=d.qvel.at[0].set(jnp.nan)))
    s = step(s, jnp.zeros(12))
    assert float(s.done) == 1.0 and float(s.metrics["nan_reset"]) == 1.0
    assert bool(jnp.all(s.obs == 0.0)) and float(s.reward) == 0.0
    # through the training wrappers the environment comes back from its first state, finite
    _, wreset, wstep = wrapped
    ws = wreset(jax.random.split(jax.random.PRNGKey(0), 2))
    d = ws.pipeline_state
    ws = ws.replace(pipeline_state=d.replace(qvel=d.qvel.at[1, 0].set(jnp.nan)))
    ws = wstep(ws, jnp.zeros((2, 12)))
    np.testing.assert_array_equal(ws.done, [0.0, 1.0])
    assert bool(jnp.all(jnp.isfinite(ws.pipeline_state.qvel))) and bool(jnp.all(jnp.isfinite(ws.obs)))
    np.testing.assert_array_equal(ws.info["steps"], [1, 1])


def test_time_limit_is_truncation_not_failure(wrapped):
    _, wreset, wstep = wrapped
    ws = wreset(jax.random.split(jax.random.PRNGKey(0), 2))
    for _ in range(3):
        ws = wstep(ws, jnp.zeros((2, 12)))
    np.testing.assert_array_equal(ws.done, [1.0, 1.0])
    np.testing.assert_array_equal(ws.info["truncation"], [1.0, 1.0])  # ended by the limit, not a fall
    np.testing.assert_array_equal(ws.metrics["reward/termination"], [0.0, 0.0])  # and not paid as one
    ws = wstep(ws, jnp.zeros((2, 12)))
    np.testing.assert_array_equal(ws.info["steps"], [1, 1])  # auto-reset started a new episode


def test_seed_episode_length(env):
    assert env.episode_length == round(18.75 / 0.02)  # seed 000: 4500 steps at 240 Hz


def test_gait_only_controller_survives_first_second(fns):
    reset, step = fns
    s = reset(jax.random.PRNGKey(0))
    for _ in range(50):  # 1 s at 50 Hz
        s = step(s, jnp.zeros(12))
        assert float(s.done) == 0.0
    assert float(s.pipeline_state.qpos[2]) > 0.15
    assert float(s.metrics["ik_invalid_legs"]) == 0.0


def test_reward_kernels_by_hand():
    assert float(rewards.tracking_exp(0.25**2, 0.25)) == pytest.approx(math.exp(-0.5))
    cmd = jnp.array([0.2, -0.1, 0.5])
    v = jnp.array([0.2, -0.1, 0.0])
    assert float(rewards.lin_vel_tracking_exp(v, cmd, 0.25)) == pytest.approx(1.0)
    assert float(rewards.ang_vel_tracking_exp(jnp.array([0.0, 0.0, 0.25]), cmd, 0.25)) == pytest.approx(
        math.exp(-0.5)
    )


def test_config_errors_are_clear():
    with pytest.raises(ValueError, match="terrain"):
        env_config(terrain="moon")
    with pytest.raises(ValueError, match="unknown gait"):
        env_config(gait="skip")


def test_sensor_noise_is_fresh_every_step():
    # Regression: the noise key was only advanced by pushes, so with randomize on and pushes off
    # every step carried the same noise (a constant bias, not noise). Noise = noisy observation -
    # the noiseless observation of the same state (an env without randomization).
    env = LocomotionEnv(env_config(randomize=True))
    clean_env = LocomotionEnv(env_config())
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    s1 = step(reset(jax.random.PRNGKey(0)), jnp.zeros(12))
    s2 = step(s1, jnp.zeros(12))
    noise = [np.asarray(s.obs - clean_env._get_obs(s.pipeline_state, s.info))[:21] for s in (s1, s2)]
    assert np.std(noise[0]) > 0.0 and np.std(noise[1]) > 0.0
    assert not np.allclose(noise[0], noise[1])


def test_base_terrain_contact_off_leaves_only_the_feet():
    # The flat scene's contact slots: base box-plane (4) + 4 foot spheres; without the base, 4.
    from mujoco import mjx

    for on, slots in ((True, 8), (False, 4)):
        e = LocomotionEnv(apply_overrides(env_config(), [f"base_terrain_contact={on}"]))
        contact = mjx.make_data(e.sys)._impl.contact
        assert contact.dist.shape == (slots,)
        geom = mujoco.mj_name2id(e.mj_model, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
        assert bool(e.mj_model.geom_conaffinity[geom]) is on


def test_device_constants_convert_on_the_host():
    """env_model.device_constant: the values as jnp.asarray gives them (canonical dtype: float32,
    int32), on the default device, without compiling a device program (jnp.asarray compiles one per
    new shape and dtype); an explicit dtype is honoured."""
    from jax._src import monitoring

    from quadson_mjx.env_model import device_constant

    compiled = []

    def on_compile(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kw.get("fun_name"))

    values = (np.linspace(0.1, 0.7, 13), np.arange(11), [1.5, 2.5], np.ones((3, 7), np.float64))
    jax.monitoring.register_event_duration_secs_listener(on_compile)
    try:
        got = [device_constant(v) for v in values] + [device_constant(np.arange(5), jnp.float32)]
    finally:
        monitoring.unregister_event_duration_listener(on_compile)
    assert compiled == []
    for v, g in zip(values, got, strict=False):
        want = jnp.asarray(v)
        assert isinstance(g, jax.Array) and g.dtype == want.dtype and g.devices() == want.devices()
        np.testing.assert_array_equal(np.asarray(g), np.asarray(want))
    assert got[-1].dtype == jnp.float32 and np.asarray(got[-1]).tolist() == [0, 1, 2, 3, 4]
