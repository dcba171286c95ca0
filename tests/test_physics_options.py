"""The environment's physics options (env_config keys base_terrain_contact, joint_limits, cone, solver,
solver_iterations, jacobian, impl): the constraint rows MJX allocates, counted by hand, the solver and mass-matrix
storage the model gets, and errors that name a bad value."""

import mujoco
import pytest
from mujoco import mjx

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config


def _rows(**overrides) -> int:
    cfg = apply_overrides(env_config(), [f"{k}={v}" for k, v in overrides.items()])
    env = LocomotionEnv(cfg)
    return int(mjx.make_data(env.sys)._impl.efc_J.shape[0]), env


# By hand: 4 five-bar closures x 3 connect rows = 12; 12 limited motor joints x 1 = 12; a condim-3
# contact has 4 rows in a pyramidal cone and 3 in an elliptic one; each foot sphere meets the plane
# in 1 contact, the base box in 4.
@pytest.mark.parametrize(
    ("overrides", "rows"),
    [
        ({}, 12 + 12 + 4 * 4 + 4 * 4),
        ({"base_terrain_contact": False}, 12 + 12 + 4 * 4),
        ({"base_terrain_contact": False, "joint_limits": False}, 12 + 4 * 4),
        ({"base_terrain_contact": False, "joint_limits": False, "cone": "elliptic"}, 12 + 4 * 3),
    ],
)
def test_constraint_rows_of_each_physics_option(overrides, rows):
    n, env = _rows(**overrides)
    assert n == rows
    disabled = bool(env.mj_model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_LIMIT)
    assert disabled == (overrides.get("joint_limits") is False)


@pytest.mark.parametrize(
    ("solver", "jacobian", "mj_solver", "sparse"),
    [
        ("newton", "auto", mujoco.mjtSolver.mjSOL_NEWTON, False),  # auto: dense below 60 dofs
        ("cg", "dense", mujoco.mjtSolver.mjSOL_CG, False),
        ("newton", "sparse", mujoco.mjtSolver.mjSOL_NEWTON, True),
    ],
)
def test_solver_and_jacobian_reach_the_mjx_model(solver, jacobian, mj_solver, sparse):
    _, env = _rows(solver=solver, jacobian=jacobian)
    assert env.mj_model.opt.solver == mj_solver and env.sys.opt.solver == mj_solver
    nv = env.mj_model.nv
    # MJX keeps the mass matrix as nv x nv when dense, as MuJoCo's nM sparse entries when sparse
    m = mjx.make_data(env.sys)._impl.M
    assert m.shape == ((env.mj_model.nM,) if sparse else (nv, nv))


@pytest.mark.parametrize(
    ("key", "value"), [("cone", "round"), ("impl", "cuda"), ("solver", "pgs"), ("jacobian", "banded")]
)
def test_bad_physics_option_names_the_key(key, value):
    cfg = apply_overrides(env_config(), [f"{key}={value}"])
    with pytest.raises(ValueError, match=f"env.{key}"):
        LocomotionEnv(cfg)


def test_solver_iterations_reach_the_mjx_model_and_old_runs_keep_one():
    from quadson_mjx.env_config import with_added_keys

    _, env = _rows(solver_iterations=4)
    assert env.mj_model.opt.iterations == 4 and env.sys.opt.iterations == 4
    assert env.mj_model.opt.ls_iterations == 5  # the model's line search, whatever the iterations
    old = env_config().to_dict()
    del old["solver_iterations"]  # a run saved before the key: the model's one iteration
    assert with_added_keys(old).solver_iterations == 1
    for bad in (0, 101):
        with pytest.raises(ValueError, match="env.solver_iterations"):
            LocomotionEnv(apply_overrides(env_config(), [f"solver_iterations={bad}"]))
    with pytest.raises(ValueError, match="solver_iterations"):
        apply_overrides(env_config(), ["solver_iterations=2.5"])


def test_sim_dt_reaches_the_mjx_model_and_a_control_step_stays_ctrl_dt():
    import jax
    import jax.numpy as jnp

    from quadson_mjx.env_config import with_added_keys

    _, env = _rows(sim_dt=0.002)
    assert env.mj_model.opt.timestep == 0.002 and float(env.sys.opt.timestep) == pytest.approx(0.002)
    assert env._n_substeps == 10  # 20 ms control step / 2 ms
    s = env.step(env.reset(jax.random.PRNGKey(0)), jnp.zeros(env.action_size))
    assert float(s.pipeline_state.time) == pytest.approx(0.02, abs=1e-6)
    _, default = _rows()
    assert default.mj_model.opt.timestep == 0.004 and default._n_substeps == 5  # 0: the model's
    old = env_config().to_dict()
    del old["sim_dt"]
    assert with_added_keys(old).sim_dt == 0.0
