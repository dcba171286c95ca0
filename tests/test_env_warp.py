"""The environments on MJX's Warp implementation (env.impl="warp"), against MuJoCo C on the same
model: a control step from the env's reset, with a nominal and with a randomized model per world;
the feet's ground contact (their height over the plane; contact sensors on the stones) against
MuJoCo C's contact list; the buffers Warp is given, counted by
hand; a batch larger than they were sized for refused in one line."""

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.env_model import warp_buffers
from quadson_mjx.randomize import RANDOMIZED_FIELDS
from quadson_mjx.wrappers import wrap_for_evaluation

WORLDS = 2  # stepped
MAX_WORLDS = 8  # what the env's buffers hold
# The constraint solver runs ITERATIONS iterations here (training: 1, which does not converge, so
# the two implementations' orders of operation would show, not their physics): one control step (5
# physics steps) against MuJoCo C from the same state and targets within these (C runs float64,
# MJX float32).
ITERATIONS = 20
JOINT_TOL_RAD, BASE_TOL_M = 0.005, 5e-4


def _cfg(*overrides):
    cfg = env_config(terrain="flat", base_terrain_contact=False)
    return apply_overrides(
        cfg, ["impl=warp", f"warp_max_worlds={MAX_WORLDS}", f"solver_iterations={ITERATIONS}", *overrides]
    )


@pytest.fixture(scope="session")
def warp_env():
    return LocomotionEnv(_cfg())


@pytest.fixture(scope="session")
def warp_step(warp_env):
    """(reset state, stepped state, action) of WORLDS worlds, jitted and vmapped as in training."""
    env = warp_env
    s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), WORLDS))
    action = 0.5 * jax.random.normal(jax.random.PRNGKey(1), (WORLDS, env.action_size))
    s1 = jax.jit(jax.vmap(env.step))(s0, action)
    return s0, s1


def _c_step(m: mujoco.MjModel, s0, s1, w: int) -> mujoco.MjData:
    """MuJoCo C through the control step of world w: the env's substeps, the previous targets during
    its latency, then the new ones."""
    d = mujoco.MjData(m)
    d.qpos[:] = np.asarray(s0.pipeline_state.qpos[w], np.float64)
    d.qvel[:] = np.asarray(s0.pipeline_state.qvel[w], np.float64)
    latency = int(s0.info["latency_steps"][w])
    n_sub = round(0.02 / m.opt.timestep)
    for i in range(n_sub):
        src = s0.info["last_ctrl"] if i < latency else s1.pipeline_state.ctrl
        d.ctrl[:] = np.asarray(src[w], np.float64)
        mujoco.mj_step(m, d)
    return d


def _feet_touching(m: mujoco.MjModel, d: mujoco.MjData, feet: np.ndarray) -> np.ndarray:
    """(4,) bool: MuJoCo C's contact list has the foot geom with a negative distance."""
    out = np.zeros(len(feet), bool)
    for c in d.contact[: d.ncon]:
        for k, g in enumerate(feet):
            if g in (c.geom1, c.geom2) and c.dist < 0:
                out[k] = True
    return out


def test_a_control_step_under_warp_matches_mujoco_c(warp_env, warp_step):
    s0, s1 = warp_step
    m = warp_env.mj_model
    assert np.all(np.isfinite(np.asarray(s1.pipeline_state.qpos)))
    moved = np.abs(np.asarray(s1.pipeline_state.qpos - s0.pipeline_state.qpos)).max()
    assert moved > 0.01  # the targets moved the legs: the comparison is not of two robots at rest
    for w in range(WORLDS):
        d = _c_step(m, s0, s1, w)
        q = np.asarray(s1.pipeline_state.qpos[w], np.float64)
        assert np.abs(q[:3] - d.qpos[:3]).max() < BASE_TOL_M
        assert np.abs(q[7:] - d.qpos[7:]).max() < JOINT_TOL_RAD


@pytest.fixture(scope="session")
def warp_env_rough():
    return LocomotionEnv(_cfg("terrain=rough"))


@pytest.mark.parametrize("terrain", ["flat", "rough"])
def test_the_feet_contact_agrees_with_mujoco_c_contact_list(warp_env, warp_env_rough, terrain):
    """Random base positions, heights and tilts over the ground, some feet down and some up: the
    env's foot_contact under Warp after a forward pass (flat: the feet's height over the plane;
    stones: the feet's contact sensors) against MuJoCo C's contact list on the same model."""
    env = warp_env if terrain == "flat" else warp_env_rough
    m = env.mj_model
    sensors_on = not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_SENSOR
    assert sensors_on == (terrain == "rough")  # the plane needs no sensor
    rng = np.random.default_rng(3)
    n = MAX_WORLDS
    qpos = np.tile(m.key_qpos[0], (n, 1))
    if terrain == "rough":  # anywhere on the stones' central metre, the base over the ground there
        qpos[:, :2] = rng.uniform(-0.5, 0.5, (n, 2))
        qpos[:, 2] += np.asarray(env.ground_height(jnp.asarray(qpos[:, :2], jnp.float32)))
    qpos[:, 2] += rng.uniform(-0.02, 0.02, n)
    tilt = rng.uniform(-0.15, 0.15, (n, 2))
    for i in range(n):
        mujoco.mju_euler2Quat(qpos[i, 3:7], np.array([tilt[i, 0], tilt[i, 1], 0.0]), "xyz")
    data = jax.vmap(lambda q: env._start(q, jax.random.PRNGKey(0)).pipeline_state)(
        jnp.asarray(qpos, jnp.float32)
    )
    data = jax.jit(jax.vmap(mjx.forward, in_axes=(None, 0)))(env.sys, data)
    got = np.asarray(jax.vmap(env.foot_contact)(data))
    feet = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in env.robot.foot_geoms()])
    d = mujoco.MjData(m)
    want = []
    for q in qpos:
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        want.append(_feet_touching(m, d, feet))
    want = np.array(want)
    assert want.any() and not want.all()  # both kinds of foot are in the sample
    np.testing.assert_array_equal(got, want)


def test_a_randomized_model_per_world_under_warp_matches_mujoco_c():
    """Domain randomization (friction, masses, motor strength, base centre of mass per world) under
    Warp's batching of model fields: each world's step against MuJoCo C on that world's model."""
    cfg = _cfg("randomize=True")
    env = LocomotionEnv(cfg)
    wrapped = wrap_for_evaluation(env, cfg, WORLDS, seed=5, steps=1)
    s0 = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), WORLDS))
    action = 0.5 * jax.random.normal(jax.random.PRNGKey(1), (WORLDS, env.action_size))
    s1 = jax.jit(wrapped.step)(s0, action)
    dr = wrapped.env.env  # the DomainRandomizationVmapWrapper, holding each world's model
    fields = RANDOMIZED_FIELDS
    masses = np.asarray(dr._sys_v.body_mass)
    assert np.abs(masses[0] - masses[1]).max() > 1e-4  # the worlds' models differ
    for w in range(WORLDS):
        m = copy.deepcopy(env.mj_model)
        for f in fields:
            getattr(m, f)[:] = np.asarray(getattr(dr._sys_v, f)[w], np.float64)
        d = _c_step(m, s0, s1, w)
        q = np.asarray(s1.pipeline_state.qpos[w], np.float64)
        assert np.abs(q[:3] - d.qpos[:3]).max() < BASE_TOL_M
        assert np.abs(q[7:] - d.qpos[7:]).max() < JOINT_TOL_RAD


# By hand (as tests/test_physics_options.py): per world, each foot sphere meets the plane in 1
# contact and the base box in up to 4; rows: 4 five-bar closures x 3 = 12, 12 limited motor joints,
# 4 rows per pyramidal condim-3 contact.
@pytest.mark.parametrize(
    ("base_contact", "contacts", "rows"),
    [(False, 4, 12 + 12 + 4 * 4), (True, 4 + 4, 12 + 12 + 8 * 4)],
)
def test_warp_buffers_counted_by_hand(base_contact, contacts, rows):
    from quadson_mjx.env_model import training_model
    from quadson_mjx.robots import get_robot

    cfg = apply_overrides(env_config(base_terrain_contact=base_contact), ["impl=warp"])
    m = training_model(get_robot("quadson"), cfg)
    assert warp_buffers(m, 1000) == (contacts * 1000, rows)
    # on the plane no contact sensor (the feet's height tells their contact), sensors off as under JAX
    assert mujoco.mjtSensor.mjSENS_CONTACT not in m.sensor_type
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_SENSOR


def test_warp_on_the_stones_has_the_feet_contact_sensors_only():
    from quadson_mjx.env_model import training_model
    from quadson_mjx.robots import get_robot

    m = training_model(get_robot("quadson"), apply_overrides(env_config(terrain="rough"), ["impl=warp"]))
    # the model's only sensors: one contact sensor per foot, against the floor
    assert m.nsensor == 4 and set(m.sensor_type.tolist()) == {int(mujoco.mjtSensor.mjSENS_CONTACT)}
    assert not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_SENSOR


def test_a_batch_larger_than_the_buffers_is_refused_in_one_line(warp_env):
    wrapped = wrap_for_evaluation(warp_env, warp_env.config, MAX_WORLDS + 1, seed=0, steps=1)
    with pytest.raises(ValueError, match=r"^9 worlds in one batch, but env.warp_max_worlds is 8 .*>= 9$"):
        wrapped.reset(jax.random.split(jax.random.PRNGKey(0), MAX_WORLDS + 1))


def test_the_getup_task_under_warp_follows_the_jax_implementation():
    """The get-up task (every leg geom touches the ground, motor torque limits set per physics step
    from the joint speeds): the same drops at reset, and one control step from them within
    1 mm (base) and 0.03 rad (joints) of MJX's JAX implementation, solver at ITERATIONS iterations
    (measured: 0.06 mm and 17 mrad; a robot lying on its links has many contacts)."""
    from quadson_mjx import tasks
    from quadson_mjx.envs import make_env

    out = {}
    for impl in ("jax", "warp"):
        cfg = apply_overrides(
            tasks.make_task_config("QuadsonGetupFlat"),
            [
                f"impl={impl}",
                f"warp_max_worlds={WORLDS}",
                f"solver_iterations={ITERATIONS}",
                "randomize=false",
            ],
        )
        env = make_env(cfg)
        s0 = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), WORLDS))
        action = 0.5 * jax.random.normal(jax.random.PRNGKey(1), (WORLDS, env.action_size))
        s1 = jax.jit(jax.vmap(env.step))(s0, action)
        out[impl] = np.asarray(s0.pipeline_state.qpos), np.asarray(s1.pipeline_state.qpos)
    np.testing.assert_array_equal(out["warp"][0], out["jax"][0])
    (_, q_jax), (_, q_warp) = out["jax"], out["warp"]
    assert np.all(np.isfinite(q_warp))
    assert np.abs(q_warp[:, :3] - q_jax[:, :3]).max() < 1e-3
    assert np.abs(q_warp[:, 7:] - q_jax[:, 7:]).max() < 0.03


def test_the_getup_task_on_the_stones_is_refused_under_warp():
    """Worlds turn non-finite there under Warp (benchmarks/warp_getup_ground.py): GetupEnv refuses
    the config; on flat ground, and under JAX on the stones, the check lets it through."""
    from quadson_mjx import tasks
    from quadson_mjx.env_model import check_warp_ground
    from quadson_mjx.getup_env import GetupEnv

    cfg = apply_overrides(tasks.make_task_config("QuadsonGetupRough"), ["impl=warp"])
    with pytest.raises(ValueError, match=r"^env.impl=warp cannot run the get-up task on env.terrain=rough"):
        GetupEnv(cfg)
    check_warp_ground(apply_overrides(tasks.make_task_config("QuadsonGetupFlat"), ["impl=warp"]))
    check_warp_ground(apply_overrides(tasks.make_task_config("QuadsonGetupRough"), ["impl=jax"]))
