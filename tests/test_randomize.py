"""Domain randomization: batched fields in range, in_axes on exactly those fields, and the randomized
model steps in MJX under vmap."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.randomize import nominal_range_overrides, randomization_fn, randomize
from quadson_mjx.wrappers import wrap_for_training


def test_randomized_fields_ranges_and_axes():
    env = LocomotionEnv(env_config(randomize=True))
    r = env.config.randomization
    model, in_axes = randomize(env.sys, jax.random.split(jax.random.PRNGKey(0), 64), r, env.base_body)
    f = np.asarray(model.geom_friction[:, :, 0])
    assert f.shape == (64, env.sys.ngeom) and f.min() >= r.friction[0] and f.max() <= r.friction[1]
    assert np.all(f == f[:, :1])  # one friction per environment for every geom
    nonzero = np.asarray(env.sys.body_mass) > 0  # the world body has no mass
    scale = np.asarray(model.body_mass)[:, nonzero] / np.asarray(env.sys.body_mass)[None, nonzero]
    assert scale.min() >= r.mass_scale[0] - 1e-6 and scale.max() <= r.mass_scale[1] + 1e-6
    kp = np.asarray(model.actuator_gainprm[:, :, 0]) / np.asarray(env.sys.actuator_gainprm[:, 0])[None]
    bias = np.asarray(model.actuator_biasprm[:, :, 1]) / np.asarray(env.sys.actuator_biasprm[:, 1])[None]
    np.testing.assert_allclose(kp, bias, rtol=1e-6)  # a position servo stays a servo: kp and -kp scaled alike
    assert kp.min() >= r.motor_strength[0] - 1e-6 and kp.max() <= r.motor_strength[1] + 1e-6
    shift = np.asarray(model.body_ipos[:, env.base_body, 0]) - float(env.sys.body_ipos[env.base_body, 0])
    assert shift.min() >= r.base_com_shift_m[0] - 1e-6 and shift.max() <= r.base_com_shift_m[1] + 1e-6
    assert in_axes.geom_friction == 0 and in_axes.body_ipos == 0 and in_axes.body_pos is None
    assert in_axes.opt is None or jax.tree.leaves(in_axes.opt) == []


def test_training_wrappers_step_randomized_models():
    # brax's DomainRandomizationVmapWrapper swaps each environment's model in; two environments with
    # different friction/mass/servo strength step to finite, different states from the same start.
    env = LocomotionEnv(env_config(randomize=True))
    w = wrap_for_training(
        env,
        10,
        randomization_fn=functools.partial(
            randomization_fn(env.config.randomization, env.base_body),
            rng=jax.random.split(jax.random.PRNGKey(1), 2),
        ),
    )
    state = jax.jit(w.reset)(jnp.stack([jax.random.PRNGKey(0)] * 2))
    step = jax.jit(w.step)
    for _ in range(5):
        state = step(state, jnp.zeros((2, 12)))
    q = np.asarray(state.pipeline_state.qpos)
    assert np.all(np.isfinite(q)) and not np.allclose(q[0], q[1])


@pytest.mark.parametrize("robot", ["quadson", "caramel"])
def test_nominal_ranges_leave_the_model_as_its_mjcf_has_it(robot):
    """The pinned ranges ("the sensor errors only" rows of the results scripts) draw the model as
    the MJCF defines it: every contact geom's friction (the MJCF's 0.8), masses, servo gains and
    force ranges, the base's centre of mass; not the 1.0 friction MuJoCo defaults to."""
    from quadson_mjx.config import apply_overrides

    cfg = apply_overrides(env_config(randomize=True, robot=robot), nominal_range_overrides())
    env = LocomotionEnv(cfg)
    mj = env._mj_model  # the MJCF as compiled by MuJoCo C
    model, _ = randomize(
        env.sys, jax.random.split(jax.random.PRNGKey(1), 4), cfg.randomization, env.base_body
    )
    contact = (mj.geom_contype > 0) | (mj.geom_conaffinity > 0)
    assert contact.any()
    for b in range(4):
        np.testing.assert_allclose(
            np.asarray(model.geom_friction[b, contact, 0]), mj.geom_friction[contact, 0], rtol=1e-6
        )
        np.testing.assert_allclose(np.asarray(model.body_mass[b]), mj.body_mass, rtol=1e-6)
        np.testing.assert_allclose(
            np.asarray(model.actuator_gainprm[b, :, 0]), mj.actuator_gainprm[:, 0], rtol=1e-6
        )
        np.testing.assert_allclose(
            np.asarray(model.actuator_forcerange[b]), mj.actuator_forcerange, rtol=1e-6
        )
        np.testing.assert_allclose(np.asarray(model.body_ipos[b]), mj.body_ipos, atol=1e-7)
    assert cfg.randomization.latency_s == (0.0, 0.0)


def test_nominal_range_overrides_keep_the_named_range():
    kept = nominal_range_overrides(keep=("friction",))
    assert not any(o.startswith("randomization.friction=") for o in kept) and len(kept) == 4
    with pytest.raises(ValueError, match="no randomization range"):
        nominal_range_overrides(keep=("fricton",))
