"""The Quadson MJCF (models/quadson/) against its constants, the JAX five-bar kinematics and MuJoCo C.

References are independent of the model: `fivebar.leg_fk` / `leg_points` (seed 000 Algorithm 1 in
JAX), the published inverse kinematics vectors of robots.md (copied below), hand arithmetic, and
MuJoCo C for the one MJX step. Exactly one MJX compilation (module fixture).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from quadson_mjx import mjcf
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar
from quadson_mjx.robots.quadson import model as qmodel

CTRL_DT = 0.02


@pytest.fixture(scope="module")
def m() -> mujoco.MjModel:
    return qmodel.load_model("flat")


@pytest.fixture(scope="module")
def ids(m) -> qmodel.ModelIds:
    return qmodel.model_ids(m)


def _home_data(m) -> mujoco.MjData:
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, C.HOME_KEYFRAME))
    mujoco.mj_forward(m, d)
    return d


def _warnings(d) -> int:
    return int(sum(w.number for w in d.warning))


def _foot_in_shoulder(d, ids, leg: int) -> np.ndarray:
    """Foot site of leg `leg` in its shoulder frame [m], from the base pose and SHOULDER_POS/ROT."""
    base_R = d.xmat[ids.base_body].reshape(3, 3)
    foot_body = base_R.T @ (d.site_xpos[ids.foot_site[leg]] - d.xpos[ids.base_body])
    return C.SHOULDER_ROT[leg].T @ (foot_body - C.SHOULDER_POS[leg])


# --- files, names, constants ----------------------------------------------------------------------


def test_committed_files_equal_generator_output():
    for name, content in qmodel.model_files().items():
        assert (qmodel.MODEL_DIR / name).read_bytes() == content, (
            f"{name}: run python -m quadson_mjx.robots.quadson.model"
        )


def test_every_constant_name_exists_and_layout(m, ids):
    # 7 free-joint coordinates + 4 legs x (3 motors + 2 passive hinges); velocities one fewer.
    assert (m.nq, m.nv, m.nu, m.neq) == (7 + 4 * 5, 6 + 4 * 5, 12, 4)
    assert m.eq_type.tolist() == [mujoco.mjtEq.mjEQ_CONNECT] * 4
    for name in C.MOTOR_JOINTS + C.PASSIVE_JOINTS:
        assert m.joint(name).type == mujoco.mjtJoint.mjJNT_HINGE
    for name in C.ACTUATORS:
        assert m.actuator(name).trntype == mujoco.mjtTrn.mjTRN_JOINT
    assert len(set(ids.motor_qposadr.tolist() + ids.passive_qposadr.tolist())) == 20
    # actuator i drives the joint of the same name (LEGS x MOTORS order)
    np.testing.assert_array_equal(m.actuator_trnid[ids.motor_actuator, 0], ids.motor_joint)
    for sensor in ("imu_quat", "imu_gyro", "imu_acc", "imu_vel", *[f"{f}_touch" for f in C.FEET]):
        assert sensor in ids.sensor_adr
    assert m.nsensordata == 4 + 3 + 3 + 3 + 12 + 12 + 4


def test_unknown_scene_raises():
    with pytest.raises(ValueError, match="unknown scene"):
        qmodel.load_model("moon")


def test_actuator_gains_and_ranges_equal_constants(m, ids):
    a, j = ids.motor_actuator, ids.motor_joint
    np.testing.assert_allclose(m.actuator_gainprm[a, 0], C.MOTOR_KP)
    np.testing.assert_allclose(m.actuator_biasprm[a, :3], np.tile([0.0, -C.MOTOR_KP, -C.MOTOR_KD], (12, 1)))
    np.testing.assert_allclose(
        m.actuator_forcerange[a], np.tile([-C.MOTOR_EFFORT_LIMIT, C.MOTOR_EFFORT_LIMIT], (12, 1))
    )
    ranges = np.tile(C.MOTOR_RANGES, (4, 1))
    np.testing.assert_allclose(m.actuator_ctrlrange[a], ranges)
    np.testing.assert_allclose(m.jnt_range[j], ranges)
    assert m.actuator_forcelimited[a].all() and m.actuator_ctrllimited[a].all() and m.jnt_limited[j].all()
    np.testing.assert_allclose(m.dof_armature[ids.motor_dofadr], C.MOTOR_ARMATURE)
    np.testing.assert_allclose(m.dof_damping[ids.motor_dofadr], C.MOTOR_DAMPING)
    np.testing.assert_allclose(m.dof_armature[ids.passive_dofadr], C.PASSIVE_ARMATURE)
    # hand values of the motor model: 60 / (2 pi 200) * 10 A * 8 * 0.9 = 3.4377 N m;
    # 25e-6 * 64 = 1.6e-3 kg m^2; kp = 1.6e-3 (40 pi)^2 = 25.266; kd = 2 * 1.6e-3 * 40 pi = 0.40212
    assert C.MOTOR_EFFORT_LIMIT == pytest.approx(3.4377, abs=1e-4)
    assert C.MOTOR_KP == pytest.approx(25.266, abs=1e-3)
    assert C.MOTOR_KD == pytest.approx(0.40212, abs=1e-5)


def test_masses_equal_constants(m, ids):
    assert m.body_subtreemass[ids.base_body] == pytest.approx(3.28)  # 1.5 + 4 (0.3 + 0.145)
    assert m.body(C.ROOT_BODY).mass[0] == pytest.approx(C.BASE_MASS)
    for leg in C.LEGS:
        assert m.body(f"{leg}_hip").mass[0] == pytest.approx(C.HIP_MASS)
        for link, mass in C.LINK_MASSES.items():
            assert m.body(f"{leg}_{link}").mass[0] == pytest.approx(mass)


def test_centre_of_mass_at_home_on_the_support_centre(m, ids):
    """The assumed CoM placement (constants.BASE_COM_X): at `home` the whole robot's CoM lies over the
    centre of the four feet, which is +2.5 cm by hand from the gait table: front feet at
    15.3 - (-4 + 12 / 2) = 13.3 cm, rear feet at -15.3 + (13 - 12 / 2) = -8.3 cm, mean 2.5 cm."""
    assert C.SUPPORT_CENTRE_X == pytest.approx(0.025, abs=1e-12)
    d = _home_data(m)
    feet_x = d.site_xpos[ids.foot_site, 0]
    np.testing.assert_allclose(feet_x, [0.133, 0.133, -0.083, -0.083], atol=1e-9)
    # MuJoCo's subtree CoM of the compiled model: 0.024999 m; BASE_COM_X = 0.05 is rounded from
    # (3.28 x 0.025 - 0.0070) / 1.5, so it sits within 0.1 mm of the support centre.
    assert d.subtree_com[ids.base_body, 0] == pytest.approx(np.mean(feet_x), abs=1e-4)
    assert d.subtree_com[ids.base_body, 1] == pytest.approx(0.0, abs=1e-12)


def test_contacts_only_feet_and_base_against_ground(m):
    colliding = [m.geom(i).name for i in range(m.ngeom) if m.geom_contype[i] or m.geom_conaffinity[i]]
    assert sorted(colliding) == sorted(["floor", "base_collision", *[f"{f}_collision" for f in C.FEET]])
    robot = [i for i in range(m.ngeom) if m.geom(i).name != "floor"]
    assert not any(m.geom_contype[i] for i in robot)  # robot geoms never collide with each other


# --- kinematics -----------------------------------------------------------------------------------


def test_planar_ik_reproduces_published_vectors():
    # robots.md: inverse (t0 = 0) of (-4, -20) cm -> (2.8406, 1.7611); (13, -20) cm -> (1.6217, 0.5686)
    for xy, t15 in [((-0.04, -0.20), (2.8406, 1.7611)), ((0.13, -0.20), (1.6217, 0.5686))]:
        got = qmodel._solve_planar_ik(np.array(xy), C.INITIAL_MOTOR_ANGLES[1:])
        np.testing.assert_allclose(got, t15, atol=1e-4)


def test_home_pose_closed_and_feet_on_floor(m, ids):
    d = _home_data(m)
    assert qmodel.closure_residual(m, d).max() < 1e-6
    # feet at trot stance midpoint: front x = -4 + 12/2 = 2 cm, rear x = 13 - 6 = 7 cm, 20 cm down
    expect = np.array([[0.02, -0.20, 0.0]] * 2 + [[0.07, -0.20, 0.0]] * 2)
    for leg in range(4):
        np.testing.assert_allclose(_foot_in_shoulder(d, ids, leg), expect[leg], atol=1e-9)
    np.testing.assert_allclose(d.site_xpos[ids.foot_site, 2], C.FOOT_RADIUS, atol=1e-9)  # spheres touch z = 0
    np.testing.assert_allclose(qmodel.home_ctrl(m), qmodel.home_qpos(m)[ids.motor_qposadr])
    assert qmodel.home_qpos(m).shape == (m.nq,) and qmodel.home_ctrl(m).shape == (m.nu,)


def _workspace_angles(n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) motor angles inside MOTOR_RANGES where the five-bar closes comfortably (p2-p4 no
    longer than 0.95 (L2 + L4)) and the toe-in guard holds."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1], size=(20 * n, 3))
    p2 = C.L1 * np.stack([np.cos(a[:, 1]), -np.sin(a[:, 1])], -1)
    p4 = np.array([C.L0, 0.0]) + C.L5 * np.stack([np.cos(a[:, 2]), -np.sin(a[:, 2])], -1)
    ok = (np.linalg.norm(p4 - p2, axis=-1) < 0.95 * (C.L2 + C.L4)) & (a[:, 2] - a[:, 1] <= C.TOE_IN_MAX)
    return a[ok][:n]


def test_mujoco_foot_equals_leg_fk_over_workspace(m, ids):
    angles = _workspace_angles(64)
    pts = fivebar.leg_points(jnp.asarray(angles))
    fk = np.asarray(fivebar.leg_fk(jnp.asarray(angles)))
    d = mujoco.MjData(m)
    d.qpos[:] = qmodel.home_qpos(m)
    for k in range(len(angles)):
        for leg in range(4):
            q = [angles[k, 0], angles[k, 1], pts.knee2[k], angles[k, 2], pts.knee4[k]]
            adr = [
                *ids.motor_qposadr[3 * leg : 3 * leg + 2],
                ids.passive_qposadr[2 * leg],
                ids.motor_qposadr[3 * leg + 2],
                ids.passive_qposadr[2 * leg + 1],
            ]
            d.qpos[adr] = q
        mujoco.mj_kinematics(m, d)
        # float32 leg_points -> ~1e-7 m; the closure holds in MuJoCo's tree with JAX's knee angles
        assert qmodel.closure_residual(m, d).max() < 1e-5
        for leg in range(4):
            np.testing.assert_allclose(_foot_in_shoulder(d, ids, leg), fk[k], atol=1e-5)


@pytest.fixture(scope="module")
def pinned():
    """The flat scene with the base welded to the world 0.5 m up (free joint removed)."""
    spec = mujoco.MjSpec.from_file(str(qmodel.scene_path("flat")))
    spec.delete(spec.joint("root"))
    spec.delete(spec.key(C.HOME_KEYFRAME))  # its qpos has the free joint's 7 coordinates
    spec.body(C.ROOT_BODY).pos = [0.0, 0.0, 0.5]
    return spec.compile()


def test_servos_settle_chain_on_kinematic_solution(pinned, m):
    """Dynamic check: position servos drive the pinned legs to new targets under gravity; the passive
    hinges must settle where fivebar.leg_points puts them for the motor angles actually reached."""
    home_qpos, home = qmodel.home_qpos(m)[7:], qmodel.home_ctrl(m)  # no free joint in `pinned`
    m = pinned
    ids = qmodel.model_ids(m)
    d = mujoco.MjData(m)
    d.qpos[:] = home_qpos
    rng = np.random.default_rng(1)
    for trial in range(3):
        d.ctrl[:] = home + rng.uniform(-0.25, 0.25, 12) * (trial > 0)
        for _ in range(int(1.0 / m.opt.timestep)):
            mujoco.mj_step(m, d)
        motors = d.qpos[ids.motor_qposadr].reshape(4, 3)
        pts = fivebar.leg_points(jnp.asarray(motors))
        knees = d.qpos[ids.passive_qposadr].reshape(4, 2)
        # measured 3.5e-7 rad (float32 leg_points); a wrong assembly branch or a sagging loop is >1e-2
        np.testing.assert_allclose(knees[:, 0], np.asarray(pts.knee2), atol=1e-5)
        np.testing.assert_allclose(knees[:, 1], np.asarray(pts.knee4), atol=1e-5)
        fk = np.asarray(fivebar.leg_fk(jnp.asarray(motors)))
        mujoco.mj_kinematics(m, d)
        for leg in range(4):
            np.testing.assert_allclose(_foot_in_shoulder(d, ids, leg), fk[leg], atol=1e-5)
        assert np.abs(d.qvel).max() < 1e-6  # settled
        assert _warnings(d) == 0


# --- dynamics -------------------------------------------------------------------------------------


def _run(m, d, seconds: float, noise: float = 0.0, seed: int = 0) -> float:
    """Steps with home ctrl + N(0, noise) per 0.02 s control step; returns the max closure residual."""
    rng = np.random.default_rng(seed)
    home = qmodel.home_ctrl(m)
    n_sub = int(round(CTRL_DT / m.opt.timestep))
    res = 0.0
    for _ in range(int(round(seconds / CTRL_DT))):
        d.ctrl[:] = home + noise * rng.standard_normal(m.nu)
        for _ in range(n_sub):
            mujoco.mj_step(m, d)
            res = max(res, float(qmodel.closure_residual(m, d).max()))
    return res


def test_free_standing_two_seconds(m, ids):
    d = _home_data(m)
    res = _run(m, d, 2.0)
    assert _warnings(d) == 0
    # nominal: shoulders 0.20 m above the feet + 0.015 m foot radius; servos sag ~5 mm under 3.3 kg
    assert abs(d.qpos[ids.root_qposadr + 2] - qmodel.HOME_BASE_HEIGHT) < 0.01
    assert res < 1e-3


def test_noisy_control_one_second(m):
    d = _home_data(m)
    res = _run(m, d, 1.0, noise=0.1, seed=2)
    assert _warnings(d) == 0
    assert np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
    assert res < 2e-3


@pytest.mark.parametrize("scene", sorted(qmodel.SCENES))
def test_every_scene_steps_without_warnings(scene):
    m = qmodel.load_model(scene)
    d = _home_data(m)
    _run(m, d, 0.5, noise=0.1, seed=3)
    assert _warnings(d) == 0
    assert np.isfinite(d.qpos).all()


def test_rough_heights_seeded_and_shallow():
    h = mjcf.stone_field_heights()
    np.testing.assert_array_equal(h, mjcf.stone_field_heights())
    m = qmodel.load_model("rough")
    relief = m.hfield_data.max() * m.hfield_size[0, 2]
    assert relief == pytest.approx(C.ROUGH_MAX_HEIGHT)
    assert 0.2 < (h > 0).mean() < 0.9  # stones cover part of the ground
    nrow, ncol = h.shape
    assert h[nrow // 2, ncol // 2] == 0  # the robot starts on level ground


# --- MJX ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def converged():
    """The flat model with the solver run to convergence, so that MJX and C are compared on the
    model rather than on where one truncated Newton iteration happens to stop (the committed
    1 iteration leaves ~0.05 rad/s between the two after one step)."""
    m = qmodel.load_model("flat")
    m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance = 50, 50, 1e-10
    return m


@pytest.fixture(scope="module")
def mjx_step(converged):
    mx = mjx.put_model(converged, impl="jax")
    return mx, jax.jit(mjx.step)


def test_mjx_step_matches_mujoco_c(converged, ids, mjx_step):
    """One MJX step equals one MuJoCo C step from the same state at rest: home pose, feet in contact,
    the closure loaded, targets 0.1 rad off home. At rest because MuJoCo C 4.0 adds the
    velocity-product term (dJ/dt qvel) to the connect rows' reference acceleration and MJX 3.17 does
    not: from a moving state they differ by design (~0.4 m/s^2 on the closure rows at ~1 rad/s)."""
    m = converged
    mx, step = mjx_step
    d = _home_data(m)
    for _ in range(50):  # settle 0.2 s: at the keyframe the feet touch at distance 0, which float32
        mujoco.mj_step(m, d)  # MJX may read as a hair above the floor (no contact)
    d.qvel[:] = 0.0
    d.ctrl[:] = qmodel.home_ctrl(m) + 0.1 * np.sin(np.arange(m.nu))
    mujoco.mj_forward(m, d)
    assert d.ncon == 4  # four feet, loaded
    res_c = qmodel.closure_residual(m, d)
    dx = step(mx, mjx.put_data(m, d, impl="jax"))
    mujoco.mj_step(m, d)
    # float32 MJX vs float64 C, both with the solver converged: measured 2e-7 (rad or m) of position,
    # 2e-5 rad/s of velocity and 1e-4 N of foot force (of 20 N) after one 4 ms step. Tolerances are
    # 5-10x that; a model difference (armature, gain, contact, sensor) shows as 1e-3 or more.
    np.testing.assert_allclose(np.asarray(dx.qpos), d.qpos, atol=1e-6)
    np.testing.assert_allclose(np.asarray(dx.qvel), d.qvel, atol=2e-4)
    np.testing.assert_allclose(np.asarray(dx.sensordata), d.sensordata, atol=1e-3)
    # mjx.step leaves site_xpos of the start state: the JAX residual must equal C's (float32: 1e-7 m)
    res_jax = np.asarray(qmodel.closure_residual_mjx(dx.site_xpos, ids))
    assert res_jax.shape == (4,) and res_jax.dtype == np.float32
    np.testing.assert_allclose(res_jax, res_c, atol=1e-7)
