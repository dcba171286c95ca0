"""The Caramel MJCF (models/caramel/) against its constants, serial.py's kinematics and hand arithmetic.

Independent references: `serial.serial_fk` (DH chain, seed 002 conventions) for MuJoCo's foot sites;
the published IK vectors of the robot (robots.md, copied below) for the home keyframe; the MX-28
datasheet arithmetic written out by hand for the servo gains; the masses summed by hand.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import serial
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.robots.caramel import constants as C
from quadson_mjx.robots.caramel import model as M


@pytest.fixture(scope="module")
def m() -> mujoco.MjModel:
    return M.load_model("flat")


def _warnings(d) -> int:
    return int(sum(w.number for w in d.warning))


def _home_data(m) -> mujoco.MjData:
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, M.home_key(m))
    mujoco.mj_forward(m, d)
    return d


# --- files, names, constants ----------------------------------------------------------------------


def test_committed_files_equal_generator_output():
    for name, content in M.model_files().items():
        path = M.MODEL_DIR / name
        assert path.read_bytes() == content, f"{name}: run python -m quadson_mjx.robots.caramel.model"


def test_names_and_leg_order(m):
    # Quadson's leg order and naming scheme (quadson_mjx.robots.quadson.constants): FL, FR, RL, RR.
    assert C.LEGS == ("FL", "FR", "RL", "RR")
    assert C.JOINT_NAMES[:3] == ("FL_hip_roll_joint", "FL_hip_pitch_joint", "FL_knee_joint")
    assert C.ACTUATORS[-1] == "RR_knee" and C.FEET == ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
    assert m.nu == 12 and m.nq == 7 + 12 and m.nv == 6 + 12
    qadr = M.joint_qposadr(m)
    np.testing.assert_array_equal(qadr, np.arange(7, 19))  # legs in LEGS order, joints in JOINTS order
    # actuator i drives joint i
    np.testing.assert_array_equal(m.actuator_trnid[M.actuator_ids(m), 0], np.arange(1, 13))
    # hips: L = 0.2291 m front-rear, W = 0.140 m left-right (robots.md)
    hips = np.array([m.body_pos[M.name_id(m, mujoco.mjtObj.mjOBJ_BODY, f"{leg}_hip")] for leg in C.LEGS])
    np.testing.assert_allclose(hips[0] - hips[2], [0.2291, 0, 0], atol=1e-12)
    np.testing.assert_allclose(hips[0] - hips[1], [0, 0.140, 0], atol=1e-12)


def test_servo_gains_from_datasheet_by_hand():
    # kp = 2.5 N m x (32 / 8) x (4096 / 2 pi) / 1023 = 6.3724 N m / rad; damping = 2.5 / (55 x 2 pi / 60)
    assert C.SERVO_KP == pytest.approx(2.5 * 4 * 4096 / (2 * math.pi) / 1023, rel=1e-12)
    assert C.SERVO_KP == pytest.approx(6.3724, abs=1e-4)
    assert C.SERVO_DAMPING == pytest.approx(0.43406, abs=1e-5)
    assert C.SERVO_ARMATURE == pytest.approx(8.6e-8 * 193**2, rel=1e-12)


def test_actuators_and_joints_equal_constants(m):
    act = M.actuator_ids(m)
    np.testing.assert_allclose(m.actuator_gainprm[act, 0], C.SERVO_KP, rtol=1e-8)
    np.testing.assert_allclose(m.actuator_biasprm[act, 1], -C.SERVO_KP, rtol=1e-8)
    np.testing.assert_allclose(m.actuator_biasprm[act, 2], -C.SERVO_KV, atol=1e-12)
    np.testing.assert_allclose(
        m.actuator_forcerange[act], [[-C.EFFORT_LIMIT, C.EFFORT_LIMIT]] * 12, rtol=1e-8
    )
    assert m.actuator_forcelimited[act].all() and m.actuator_ctrllimited[act].all()
    limits = np.tile(C.JOINT_LIMITS, (4, 1))
    np.testing.assert_allclose(m.actuator_ctrlrange[act], limits, rtol=1e-8)
    jid = m.actuator_trnid[act, 0]
    np.testing.assert_allclose(m.jnt_range[jid], limits, rtol=1e-8)
    assert m.jnt_limited[jid].all()
    dof = m.jnt_dofadr[jid]
    np.testing.assert_allclose(m.dof_damping[dof], C.SERVO_DAMPING, rtol=1e-8)
    np.testing.assert_allclose(m.dof_armature[dof], C.SERVO_ARMATURE, rtol=1e-8)


def test_total_mass(m):
    # 1.5 + 4 x (0.12 + 0.035 + 0.020) = 2.2 kg (robots.md: about 2.2 kg)
    assert C.TOTAL_MASS == pytest.approx(2.2, abs=1e-12)
    base = M.name_id(m, mujoco.mjtObj.mjOBJ_BODY, C.ROOT_BODY)
    assert m.body_subtreemass[base] == pytest.approx(2.2, abs=1e-9)


def test_home_keyframe_is_the_published_ik():
    # robots.md: right leg (0, -0.048, -0.17) -> commands (0, -0.00174, 0.00347) (rounded to 1e-5)
    cmd = np.asarray(serial.caramel_commands(jnp.asarray(M.home_joint_angles())))
    np.testing.assert_allclose(cmd, np.tile([0.0, -0.00174, 0.00347], (4, 1)), atol=1e-5)


# --- compile and step -----------------------------------------------------------------------------


@pytest.mark.parametrize("scene", ["flat", "rough", "fixed"])
def test_compiles_and_steps_noisy_control_without_warnings(scene):
    m = M.load_model(scene)
    d = _home_data(m)
    rng = np.random.default_rng(0)
    act = M.actuator_ids(m)
    home = m.key_ctrl[M.home_key(m)]
    assert _warnings(d) == 0
    for i in range(round(2.0 / m.opt.timestep)):
        if i % 5 == 0:  # 50 Hz, as the planner
            d.ctrl[act] = home + rng.normal(0.0, 0.1, 12)
        mujoco.mj_step(m, d)
    assert _warnings(d) == 0
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))


# --- kinematics: MuJoCo C's foot sites against serial_fk ------------------------------------------


def test_foot_sites_equal_serial_fk():
    m = M.load_model("fixed")
    d = mujoco.MjData(m)
    qadr = M.joint_qposadr(m)
    lo, hi = C.JOINT_LIMITS[:, 0], C.JOINT_LIMITS[:, 1]
    grid = np.stack(np.meshgrid(*[np.linspace(a, b, 4) for a, b in zip(lo, hi, strict=True)]), -1).reshape(
        -1, 3
    )
    sites = [M.name_id(m, mujoco.mjtObj.mjOBJ_SITE, n) for n in C.FEET]
    base = M.name_id(m, mujoco.mjtObj.mjOBJ_BODY, C.ROOT_BODY)
    with jax.enable_x64(True):
        ref = {
            s: np.asarray(serial.serial_fk(jnp.asarray(grid, jnp.float64), C.LEG, s))
            for s in (serial.LEFT, serial.RIGHT)
        }
    worst = 0.0
    for g, q in enumerate(grid):
        d.qpos[qadr] = np.tile(q, 4)
        mujoco.mj_kinematics(m, d)
        for i in range(4):
            foot_hip = d.site_xpos[sites[i]] - d.xpos[base] - C.HIP_POS[i]  # base at identity orientation
            worst = max(worst, float(np.max(np.abs(foot_hip - ref[C.SIDE[i]][g]))))
    assert worst < 1e-6  # same float64 geometry; a wrong axis or offset is centimetres


# --- standing -------------------------------------------------------------------------------------


def test_home_keyframe_stands(m):
    d = _home_data(m)
    d.ctrl[:] = m.key_ctrl[M.home_key(m)]
    for _ in range(round(2.0 / m.opt.timestep)):
        mujoco.mj_step(m, d)
    hip_height = d.qpos[2] - C.FOOT_RADIUS  # hips lie in the base's z = 0 plane; feet centres r above 0
    # the MX-28 P loop sags under 0.55 kg per leg: about 9 mm at these gains
    assert abs(hip_height - C.STANCE_HEIGHT) < 0.01
    roll, pitch, _ = quat_to_rpy(d.qpos[3:7])
    assert abs(math.degrees(roll)) < 2.0 and abs(math.degrees(pitch)) < 2.0
    assert _warnings(d) == 0
