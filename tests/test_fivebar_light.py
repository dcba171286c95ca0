"""The light five-bar model (env.fivebar_model=light) against the full one, in MuJoCo C, and mjx.step
against mj_step on it. Numbers measured by benchmarks/fivebar_light_vs_full.py
(benchmarks/results/fivebar_light_vs_full_cpu.log)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from quadson_mjx.cli.gait import open_loop_targets
from quadson_mjx.env_config import check_env_config, env_config, with_added_keys
from quadson_mjx.env_model import training_model
from quadson_mjx.robots import get_robot
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import light_check as L
from quadson_mjx.robots.quadson import model as M

FOOT_TOL_M = 1e-3  # the bar for the light model's feet
CTRL_DT = 0.02


@pytest.fixture(scope="module")
def targets():
    return open_loop_targets("trot", 1.0, CTRL_DT)  # 50 control steps: ramp from home into the trot


def test_light_model_has_one_dof_and_two_equality_rows_fewer_per_leg_same_mass_and_com():
    full, light = L.model_sizes("full"), L.model_sizes("light")
    # per leg: knee4 gone (nv - 1), a 1-row tendon equality instead of a 3-row connect
    assert full["nv"] - light["nv"] == C.NUM_LEGS
    assert (full["equality_rows"], light["equality_rows"]) == (3 * C.NUM_LEGS, C.NUM_LEGS)
    assert full["nefc"] - light["nefc"] == 2 * C.NUM_LEGS  # same contacts at home
    assert light["mass_kg"] == pytest.approx(C.TOTAL_MASS, abs=1e-12)
    np.testing.assert_allclose(light["com_m"], full["com_m"], atol=1e-12)


def test_light_home_keyframe_is_closed_and_ids_resolve():
    m = M.load_model("flat", "light")
    d = mujoco.MjData(m)
    d.qpos[:] = M.home_qpos(m)
    mujoco.mj_kinematics(m, d)
    ids = M.model_ids(m)
    assert ids.closure_length_m == C.L4 and ids.passive_qposadr.shape == (C.NUM_LEGS,)
    # the p3 - p4 distance is L4 (hand geometry of the five-bar), so the gap is ~0
    assert M.closure_residual(m, d).max() < 1e-9
    assert m.tendon_invweight0.min() > 1.0  # qpos0 not the degenerate straight leg (model._knee2_ref)


def test_hanging_feet_follow_the_full_model_within_1mm(targets):
    r = L.compare(targets, 5, CTRL_DT, hang=True)
    assert r["light"]["foot_max_m"] < FOOT_TOL_M  # measured 0.18 mm over 5 s
    assert max(r["closure_max_full_m"], r["closure_max_light_m"]) < 1e-3
    assert r["warnings"] == 0


def test_walking_feet_agree_for_the_first_steps(targets):
    n = round(0.2 / CTRL_DT)  # 0.2 s: measured 0.19 mm; the feet part by 1 mm at 0.28 s
    r = L.compare(targets[:n], 5, CTRL_DT)
    assert r["light"]["foot_max_m"] < FOOT_TOL_M
    assert r["floor"]["foot_max_m"] < 1e-5  # measured 2.7e-7 m
    assert r["closure_max_light_m"] < 1e-3 and r["warnings"] == 0


def test_walking_one_control_step_from_the_full_models_states(targets):
    # over the first 1 s, converged solver: measured feet RMS 0.16 mm (max 1.3 mm at a touch-down),
    # normal forces RMS 0.66 N
    e = L.one_step_errors(targets, 5, iterations=50)
    assert e["foot_rms_m"] < 0.5 * FOOT_TOL_M and e["foot_max_m"] < 3 * FOOT_TOL_M
    assert e["force_rms_n"] < 2.0


def test_mjx_step_equals_mj_step_on_the_light_model():
    r = L.mjx_vs_c("light", n_steps=3)
    # float64, converged solver: the same equations; measured 1e-14
    assert r["qpos_max"] < 1e-9 and r["qvel_max"] < 1e-7
    assert r["closure_max_mjx_m"] == pytest.approx(r["closure_max_c_m"], abs=1e-9)


def test_fivebar_model_config_key():
    cfg = env_config()
    assert cfg.fivebar_model == "full"  # the default stays the full model
    old = cfg.to_dict()
    del old["fivebar_model"]
    assert with_added_keys(old).fivebar_model == "full"
    light = env_config().copy_and_resolve_references()
    light.fivebar_model = "light"
    check_env_config(light)
    assert training_model(get_robot("quadson"), light).nv == L.model_sizes("light")["nv"]
    cfg = env_config(robot="caramel").copy_and_resolve_references()
    cfg.fivebar_model = "light"
    with pytest.raises(ValueError, match="fivebar_model"):
        check_env_config(cfg)
    with pytest.raises(ValueError, match="five-bar model"):
        M.load_model("flat", "lite")
