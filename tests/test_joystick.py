"""The joystick recipe: command resampling and zero share, tracking metrics, the base box against the
ground under it, the stone field's edge as a truncation, old configs, and the robust preset under
brax's training wrappers with domain randomization.

Two compiled steps, shared through module fixtures: the joystick env on flat ground (a command every
2-3 control steps, and a clearance threshold of 0.2 m that a standing robot's base box is below),
and the robust preset on the stone field under the training wrappers (2 randomized environments).
"""

import functools
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from state_types import assert_evaluation_compiles_once

from quadson_mjx import terrain
from quadson_mjx.config import apply_overrides, from_json
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import ENV_KEYS_ADDED, env_config
from quadson_mjx.randomize import randomization_fn
from quadson_mjx.wrappers import wrap_for_training

ROOT = Path(__file__).resolve().parents[1]
CLEARANCE = 0.2  # m: a standing base (home: origin 0.215 m up, box half height 0.04 m) is below this


@pytest.fixture(scope="module")
def joy():
    cfg = env_config(joystick=True)
    cfg = apply_overrides(
        cfg, ["command_resample_s=(0.04, 0.06)", f"termination.base_clearance_m={CLEARANCE}"]
    )
    env = LocomotionEnv(cfg)
    return env, jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def robust():
    # train/ppo_mjx.py --env-preset robust --terrain rough, under the training wrappers
    env = LocomotionEnv(
        env_config(joystick=True, randomize=True, pushes=True, terrain="rough", base_terrain_contact=False)
    )
    w = wrap_for_training(
        env,
        50,
        randomization_fn=functools.partial(
            randomization_fn(env.config.randomization, env.base_body),
            rng=jax.random.split(jax.random.PRNGKey(1), 2),
        ),
    )
    return env, w, jax.jit(w.reset), jax.jit(w.step)


def test_zero_share_and_range_of_sampled_commands(joy):
    env, _, _ = joy
    cmd, timer = jax.jit(jax.vmap(env.sample_command))(jax.random.split(jax.random.PRNGKey(0), 4000))
    cmd, timer = np.asarray(cmd), np.asarray(timer)
    zero = np.all(cmd == 0.0, axis=1)
    # binomial(4000, 0.1): std sqrt(4000 * 0.1 * 0.9) = 19 commands; 4 std = 0.019 of the share
    assert abs(zero.mean() - 0.1) < 0.019
    lo, hi = np.array([-0.3, -0.2, -0.8]), np.array([0.5, 0.2, 0.8])  # the command sweep
    nz = cmd[~zero]
    assert np.all(nz >= lo) and np.all(nz <= hi)
    assert np.all(nz.min(0) < lo + 0.01) and np.all(nz.max(0) > hi - 0.01)  # the whole range is used
    assert timer.min() >= 0.04 and timer.max() <= 0.06


def test_command_is_resampled_mid_episode_and_observed(joy):
    env, reset, step = joy
    s = reset(jax.random.PRNGKey(2))
    commands = [np.asarray(s.info["command"])]
    for _ in range(8):
        s = step(s, jnp.zeros(12))
        commands.append(np.asarray(s.info["command"]))
        np.testing.assert_array_equal(s.obs[-3:], s.info["command"])  # the observation's tail
    # a new command every 0.04-0.06 s = 2-3 control steps of 0.02 s: at least 8 // 3 = 2 changes
    changes = sum(not np.array_equal(a, b) for a, b in zip(commands, commands[1:], strict=False))
    assert changes >= 2


def test_tracking_metrics_by_mujoco(joy):
    env, reset, step = joy
    s = reset(jax.random.PRNGKey(3))
    command = np.asarray(s.info["command"])
    s = step(s, jnp.zeros(12))
    # reference: body-frame velocity from MuJoCo C's rotation of the free joint's world velocity
    q, v = np.asarray(s.pipeline_state.qpos, np.float64), np.asarray(s.pipeline_state.qvel, np.float64)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q[3:7])
    lin_body = mat.reshape(3, 3).T @ v[:3]
    expected = (lin_body[0] - command[0]) ** 2, (lin_body[1] - command[1]) ** 2, (v[5] - command[2]) ** 2
    got = [float(s.metrics[k]) for k in ("vx_sq_err", "vy_sq_err", "yaw_rate_sq_err")]
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-7)
    assert float(s.metrics["base_height"]) == pytest.approx(q[2], abs=1e-6)  # flat: ground at 0


def test_base_box_below_the_clearance_ends_the_episode(joy):
    env, reset, step = joy
    s = reset(jax.random.PRNGKey(4))
    standing = step(s, jnp.zeros(12))  # bottom face ~0.175 m up: below the 0.2 m test clearance
    assert float(standing.metrics["base_below_terrain"]) == 1.0
    assert float(standing.done) == 1.0 and float(standing.metrics["fall"]) == 1.0
    data = s.pipeline_state
    lifted = s.replace(pipeline_state=data.replace(qpos=data.qpos.at[2].add(0.1)))  # bottom face 0.275 m up
    flying = step(lifted, jnp.zeros(12))
    assert float(flying.metrics["base_below_terrain"]) == 0.0 and float(flying.done) == 0.0


def test_base_clearance_against_mujoco_on_the_stone_field(robust):
    # reference: the base box's pose from MuJoCo C (geom_xpos, geom_xmat after mj_kinematics), the
    # ground under each point of its bottom face by mj_ray
    env = robust[0]
    m = env.mj_model
    d = mujoco.MjData(m)
    geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
    floor_group = np.zeros(6, np.uint8)
    floor_group[m.geom_group[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")]] = 1
    hx, hy, hz = m.geom_size[geom]
    local = np.array([[x, y, -hz] for x in np.linspace(-hx, hx, 5) for y in np.linspace(-hy, hy, 3)])
    clearance = jax.jit(env.base_clearance)
    rng = np.random.default_rng(0)
    for _ in range(10):
        d.qpos[:] = m.qpos0
        d.qpos[:3] = [*rng.uniform(-3, 3, 2), rng.uniform(0.02, 0.1)]
        quat = np.zeros(4)
        mujoco.mju_euler2Quat(quat, rng.uniform(-0.5, 0.5, 3), "XYZ")
        d.qpos[3:7] = quat
        mujoco.mj_kinematics(m, d)
        pts = d.geom_xpos[geom] + local @ d.geom_xmat[geom].reshape(3, 3).T
        ground = []
        for p in pts:
            dist = mujoco.mj_ray(
                m,
                d,
                np.array([p[0], p[1], 1.0]),
                np.array([0, 0, -1.0]),
                floor_group,
                1,
                -1,
                np.zeros(1, np.int32),
            )
            ground.append(1.0 - dist)
        ref = np.min(pts[:, 2] - np.array(ground))
        assert float(clearance(jnp.asarray(d.qpos, jnp.float32))) == pytest.approx(ref, abs=2e-6)


def test_robust_preset_steps_under_training_wrappers(robust):
    env, w, reset, step = robust
    state = reset(jnp.stack([jax.random.PRNGKey(0)] * 2))
    assert state.obs.shape == (2, 32)
    for _ in range(3):
        state = step(state, jnp.zeros((2, 12)))
    assert np.all(np.isfinite(np.asarray(state.obs)))
    assert float(jnp.sum(state.metrics["fall"])) == 0.0
    # ground under the start (the flat patch around the origin) is 0: base_height = z
    np.testing.assert_allclose(state.metrics["base_height"], state.pipeline_state.qpos[:, 2], atol=1e-6)


def test_a_step_keeps_the_state_types_so_the_evaluation_compiles_once(robust):
    env, w, _, _ = robust
    assert_evaluation_compiles_once(w, env.action_size, 2)


def test_the_field_edge_is_a_truncation_not_a_fall(robust):
    env, w, reset, step = robust
    state = reset(jnp.stack([jax.random.PRNGKey(0)] * 2))
    margin = env.config.termination.off_field_margin_m
    half = 4.0  # constants.ROUGH_SIZE
    qpos = state.pipeline_state.qpos.at[0, 0].set(half - margin + 0.05)  # env 0 beyond the margin
    state = state.replace(pipeline_state=state.pipeline_state.replace(qpos=qpos))
    state = step(state, jnp.zeros((2, 12)))
    np.testing.assert_array_equal(state.metrics["off_field"], [1.0, 0.0])
    np.testing.assert_array_equal(state.done, [1.0, 0.0])
    np.testing.assert_array_equal(state.info["truncation"], [1.0, 0.0])
    np.testing.assert_array_equal(state.metrics["fall"], [0.0, 0.0])
    assert bool(terrain.on_field(terrain.heightfield(env.mj_model), state.pipeline_state.qpos[0, :2]))


def test_old_run_configs_load_with_their_behaviour():
    # a config saved before the joystick keys existed gets the values that reproduce its run
    for path in (
        ROOT / "results" / "policy_h200_seed" / "config.json",
        ROOT / "tests" / "data" / "legacy_run" / "config.json",
    ):
        old = from_json(json.dumps(json.loads(path.read_text())["env"]))
        env = LocomotionEnv(old)
        for dotted, value in ENV_KEYS_ADDED.items():
            node = env.config
            for part in dotted.split("."):
                node = node[part]
            assert tuple(node) == tuple(value) if isinstance(value, tuple) else node == value
    # and the seed preset's defaults are those of the published run, new keys aside
    published = json.loads((ROOT / "results" / "policy_h200_seed" / "config.json").read_text())["env"]
    now = json.loads(json.dumps(env_config().to_dict(), default=list))
    for dotted in ENV_KEYS_ADDED:
        *path, leaf = dotted.split(".")
        node = now
        for p in path:
            node = node[p]
        del node[leaf]

    def prune(node):  # a group whose every key is new (gait_scale, getup.weights) goes too
        if not isinstance(node, dict):
            return node
        kept = {k: prune(v) for k, v in node.items()}
        return {k: v for k, v in kept.items() if v != {}}

    now = prune(now)
    assert now == published
    assert math.isinf(float(LocomotionEnv(env_config()).sample_command(jax.random.PRNGKey(0))[1]))


def test_gait_reach_over_the_joystick_range():
    # Pins the README's measurement: the trot's foot targets over one cycle (200 samples x 4 legs)
    # for a 9 x 5 x 9 grid over vx [-0.3, 0.5], vy [-0.2, 0.2], yaw rate [-0.8, 0.8]; the IK's
    # validity flags say which were clamped.
    from quadson_mjx.robots.quadson import gait

    p = gait.gait_params("trot", swing="bezier_seed")
    t = jnp.linspace(0.0, float(p.cycle_s), 200, endpoint=False)

    @jax.jit
    @jax.vmap
    def clamped(cmd):
        return jnp.sum(~gait.motor_targets(gait.foot_targets(t, cmd, p))[1])

    g = np.meshgrid(
        np.linspace(-0.3, 0.5, 9), np.linspace(-0.2, 0.2, 5), np.linspace(-0.8, 0.8, 9), indexing="ij"
    )
    grid = np.stack([a.ravel() for a in g], axis=-1)
    n = np.asarray(clamped(jnp.asarray(grid, jnp.float32)))
    assert int((n > 0).sum()) == 61 and grid[n > 0, 0].min() == pytest.approx(0.4)
    assert n.max() == 39  # of 800: 4.9 %, at (0.5, +-0.2, +-0.8)
    corners = np.asarray(clamped(jnp.array([[0.48, 0, 0], [0.5, 0, 0], [0.5, 0, 0.8]], jnp.float32)))
    np.testing.assert_array_equal(corners, [0, 10, 29])  # 0 %, 1.3 %, 3.6 %
