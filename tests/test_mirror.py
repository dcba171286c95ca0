"""Quadson's mirror symmetry (quadson_mjx.robots.quadson.mirror) against MuJoCo C: the mirrored
qpos puts every geom at the mirror image of its partner's place, the model's dynamics commute with
the reflection, and the get-up observation of a mirrored state is the mirrored observation."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from quadson_mjx import deploy_robots, obs_spec
from quadson_mjx.config import to_json
from quadson_mjx.deploy_observation import ObservationBuilder
from quadson_mjx.env_config import env_config
from quadson_mjx.robots import get_robot
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import mirror as M

REFLECT = np.array([1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def model():
    m = get_robot("quadson").load_model("flat")
    hinges = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in hinges]
    bodies = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody)]
    swap = {"FL_": "FR_", "FR_": "FL_", "RL_": "RR_", "RR_": "RL_"}
    partner = {}  # every robot geom -> the same geom of the partner leg's body (the base's: itself)
    for b in range(1, m.nbody):
        name = bodies[b]
        pb = bodies.index(swap[name[:3]] + name[3:]) if name[:3] in swap else b
        assert m.body_geomnum[pb] == m.body_geomnum[b]
        for i in range(m.body_geomnum[b]):
            partner[m.body_geomadr[b] + i] = m.body_geomadr[pb] + i
    assert len(partner) == sum(m.geom_bodyid > 0)
    return m, names, m.jnt_qposadr[hinges], partner


def _random_qpos(m, rng):
    q = m.qpos0.copy()
    q[:3] = rng.uniform(-0.3, 0.3, 3) + [0.0, 0.0, 0.5]
    quat = rng.normal(size=4)
    q[3:7] = quat / np.linalg.norm(quat)
    q[7:] = rng.uniform(-1.5, 1.5, m.nq - 7)
    return q


def test_mirrored_qpos_places_every_geom_at_its_partners_mirror_image(model):
    m, names, adr, partner = model
    d, e = mujoco.MjData(m), mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(20):
        d.qpos[:] = _random_qpos(m, rng)
        e.qpos[:] = M.mirror_qpos(d.qpos, names, adr)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_kinematics(m, e)
        for g, p in partner.items():
            np.testing.assert_allclose(e.geom_xpos[p], d.geom_xpos[g] * REFLECT, atol=1e-12)
        np.testing.assert_allclose(M.mirror_qpos(e.qpos, names, adr), d.qpos, atol=0)  # an involution


def test_motor_and_qpos_maps_agree(model):
    m, names, adr, _ = model
    motor_adr = np.array([adr[names.index(n)] for n in C.MOTOR_JOINTS])
    q = _random_qpos(m, np.random.default_rng(1))
    np.testing.assert_array_equal(M.mirror_qpos(q, names, adr)[motor_adr], M.mirror_motors(q[motor_adr]))
    a = np.random.default_rng(2).uniform(-1, 1, (5, 12))
    np.testing.assert_array_equal(M.mirror_motors(M.mirror_motors(a)), a)


def test_dynamics_commute_with_the_reflection(model):
    """A drop onto the ground with the motors driven: the mirrored start under mirrored commands
    stays the mirror image, the base within 1e-6 m after 0.3 s (contacts included)."""
    m, names, adr, _ = model
    act_joint = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.actuator_trnid[a, 0]) for a in range(m.nu)]
    ctrl_order = np.array([act_joint.index(n) for n in C.MOTOR_JOINTS])
    d, e = mujoco.MjData(m), mujoco.MjData(m)
    k = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    mujoco.mj_resetDataKeyframe(m, d, k)
    d.qpos[2] += 0.05
    d.qpos[3:7] = [np.cos(0.2), 0.12, 0.08, 0.05]
    d.qpos[3:7] /= np.linalg.norm(d.qpos[3:7])
    d.qvel[3:6] = [0.4, -0.3, 0.2]
    e.qpos[:] = M.mirror_qpos(d.qpos, names, adr)
    e.qvel[:3] = d.qvel[:3] * REFLECT
    e.qvel[3:6] = d.qvel[3:6] * -REFLECT  # body-frame angular velocity: an axial vector
    rng = np.random.default_rng(3)
    targets = m.key_ctrl[k][ctrl_order] + rng.uniform(-0.2, 0.2, 12)
    d.ctrl[ctrl_order] = targets
    e.ctrl[ctrl_order] = M.mirror_motors(targets)
    touched = False
    for _ in range(int(0.3 / m.opt.timestep)):
        mujoco.mj_step(m, d)
        mujoco.mj_step(m, e)
        touched |= d.ncon > 0
    assert touched
    np.testing.assert_allclose(e.qpos[:3], d.qpos[:3] * REFLECT, atol=1e-6)
    np.testing.assert_allclose(M.mirror_qpos(e.qpos, names, adr), d.qpos, atol=1e-5)


def test_mirrored_observation_is_the_observation_of_the_mirrored_state():
    """gravity from the IMU quaternion, the gyro, the encoders and the last action of a state and of
    its mirror image, through the robot's own observation builder."""
    kin = deploy_robots.quadson(json.loads(to_json(env_config())))
    spec = obs_spec.getup_observation(kin.motor_names)
    rng = np.random.default_rng(4)
    for _ in range(10):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        gyro, motors, last = rng.normal(size=3), rng.uniform(-1, 2, 12), rng.uniform(-1, 1, 12)
        obs = []
        for q, w, mot, a in (
            (quat, gyro, motors, last),
            (quat * [1, -1, 1, -1], gyro * -REFLECT, M.mirror_motors(motors), M.mirror_motors(last)),
        ):
            b = ObservationBuilder(spec, kin, 12)
            b.observe(q, w, mot, np.zeros(3), None, 0.0, 0.02)
            b.commit(a)  # the last action of the tick before
            obs.append(b.observe(q, w, mot, np.zeros(3), None, 0.0, 0.02))
        np.testing.assert_allclose(obs[1], M.mirror_getup_observation(obs[0]), atol=1e-6)
    with pytest.raises(ValueError, match="30 values"):
        M.mirror_getup_observation(np.zeros(29))


def test_index_layout_is_the_getup_observations():
    names = obs_spec.getup_observation(C.MOTOR_JOINTS).names
    assert names[:6] == ("gravity.x", "gravity.y", "gravity.z", "gyro.x", "gyro.y", "gyro.z")
    assert names[6:18] == tuple(f"motor_pos.{n}" for n in C.MOTOR_JOINTS)
    assert names[18:] == tuple(f"last_action.a{i}" for i in range(12))
    assert C.MOTOR_JOINTS[0::3] == tuple(f"{leg}_motor0_joint" for leg in C.LEGS)


class _Recorder:
    """A get-up policy that records what it sees and answers a fixed action."""

    obs_size, action_size = 30, 12

    def __init__(self, action):
        self.action, self.seen = np.asarray(action, np.float32), []

    def __call__(self, obs):
        self.seen.append(np.array(obs))
        return self.action


def test_getup_policy_mirrors_an_attempt_decided_on_its_first_tick():
    """mirror_to "left": an attempt whose first tick has the right side lower (roll +40 deg: the
    body's y axis tips down) sees the mirrored observation and sends the mirrored action, for the
    whole attempt even after the tilt changes side; the next attempt decides afresh."""
    from quadson_mjx.deploy_supervisor import GetupPolicy, getup_targets

    kin = deploy_robots.quadson(json.loads(to_json(env_config())))
    action = np.linspace(-0.8, 0.9, 12)
    rec = _Recorder(action)
    gp = GetupPolicy(rec, kin, 0.02, mirror_to="left")
    roll = lambda deg: np.array([np.cos(np.radians(deg) / 2), np.sin(np.radians(deg) / 2), 0.0, 0.0])  # noqa: E731
    motors = np.asarray(kin.home_motor) + np.linspace(-0.1, 0.1, 12)
    gp.reset()
    targets, sent, obs = gp.act(roll(40.0), np.array([0.3, 0.1, -0.2]), motors)
    assert obs[1] < 0 and gp.mirrored  # gravity's body y: the right side is lower
    np.testing.assert_allclose(rec.seen[-1], M.mirror_getup_observation(obs), atol=1e-7)
    np.testing.assert_allclose(sent, M.mirror_motors(action), atol=1e-7)
    np.testing.assert_allclose(targets, kin.clamp(getup_targets(M.mirror_motors(action), kin.home_motor)))
    _, _, obs2 = gp.act(roll(-40.0), np.zeros(3), motors)  # the other side, same attempt
    assert obs2[1] > 0 and gp.mirrored
    np.testing.assert_allclose(rec.seen[-1][18:], action, atol=1e-7)  # its own last action, unmirrored
    gp.reset()
    _, sent, obs3 = gp.act(roll(-40.0), np.zeros(3), motors)
    assert not gp.mirrored and np.allclose(sent, action) and np.allclose(rec.seen[-1], obs3)
    with pytest.raises(ValueError, match="mirror_to"):
        GetupPolicy(rec, kin, 0.02, mirror_to="up")


def test_a_policy_trained_on_one_side_runs_on_that_side():
    """A get-up file whose env config says getup.mirror_to "left" runs mirrored to the left by
    default (mirror.TRAINED) and refuses to run on both sides or the right; a file trained on both
    sides runs as asked; the command lines' words parse to those values."""
    from quadson_mjx.deploy_supervisor import GetupPolicy

    kin = deploy_robots.quadson(json.loads(to_json(env_config())))
    left = _Recorder(np.zeros(12))
    left.meta = {"env_config": {"getup": {"mirror_to": "left"}}}
    assert GetupPolicy(left, kin, 0.02).mirror_to == "left"
    assert GetupPolicy(left, kin, 0.02, mirror_to="left").mirror_to == "left"
    for other in (None, "right"):
        with pytest.raises(ValueError, match="trained mirrored to the left"):
            GetupPolicy(left, kin, 0.02, mirror_to=other)
    both = _Recorder(np.zeros(12))
    both.meta = {"env_config": {"getup": {"mirror_to": "none"}}}
    assert GetupPolicy(both, kin, 0.02).mirror_to is None
    assert GetupPolicy(both, kin, 0.02, mirror_to="right").mirror_to == "right"
    assert GetupPolicy(_Recorder(np.zeros(12)), kin, 0.02).mirror_to is None  # no meta: both sides
    assert M.trained_mirror_to(env_config(task="getup")) is None  # the ConfigDict of a run
    assert [M.parse_mirror_to(w) for w in ("trained", "none", "left", "right")] == [
        M.TRAINED,
        None,
        "left",
        "right",
    ]
    with pytest.raises(ValueError, match="--mirror-to up: choose from trained, none, left, right"):
        M.parse_mirror_to("up")


def test_evaluation_mirrors_the_chosen_rows_in_jax():
    """getup_eval.mirrored_policy under jit: rows whose first gravity y is below 0 (mirror_to
    "left") give the policy the mirrored actor observation and return its mirrored action; the
    critic's input and the other rows pass unchanged."""
    import jax
    import jax.numpy as jnp

    from quadson_mjx.getup_eval import mirrored_policy

    rng = np.random.default_rng(5)
    state = jnp.asarray(rng.normal(size=(4, 30)), jnp.float32)
    priv = jnp.asarray(rng.normal(size=(4, 7)), jnp.float32)

    def policy(obs, key):
        return jnp.arange(1.0, 13.0) * obs["state"][:, 1:2], obs["privileged_state"]  # not symmetric

    choose = M.wants_mirror(state[:, 1], "left")
    np.testing.assert_array_equal(np.asarray(choose), np.asarray(state[:, 1]) < 0)
    action, critic_saw = jax.jit(mirrored_policy(policy, choose))(
        {"state": state, "privileged_state": priv}, None
    )
    s, a, c = np.asarray(state), np.asarray(action), np.asarray(choose)
    assert 0 < c.sum() < 4
    for i in range(4):
        ramp = np.arange(1.0, 13.0)
        want = M.mirror_motors(ramp * -s[i, 1]) if c[i] else ramp * s[i, 1]  # mirrored: gravity y negated
        np.testing.assert_allclose(a[i], want, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(critic_saw), np.asarray(priv))
    np.testing.assert_array_equal(np.asarray(M.wants_mirror(state[:, 1], None)), np.zeros(4, bool))
    with pytest.raises(ValueError, match="mirror_to"):
        M.wants_mirror(0.0, "both")
