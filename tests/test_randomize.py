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


def test_draws_follow_the_documented_formula_in_one_program():
    """Each environment's fields, recomputed in numpy from the same keys split as documented (friction,
    masses, motors, centre of mass), equal the jitted draws exactly; a new batch size compiles one
    program (op by op it was about 24)."""
    env = LocomotionEnv(env_config(randomize=True))
    r, sys, base = env.config.randomization, env.sys, env.base_body
    rng = jax.random.split(jax.random.PRNGKey(7), 5)
    compiled = []

    def on_compile(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(on_compile)
    try:
        model, _ = randomize(sys, rng, r, base)
    finally:
        from jax._src import monitoring

        monitoring.unregister_event_duration_listener(on_compile)
    assert len(compiled) == 1, compiled
    for b in range(5):
        k_f, k_m, k_s, k_c = jax.random.split(rng[b], 4)
        friction = float(jax.random.uniform(k_f, (), minval=r.friction[0], maxval=r.friction[1]))
        scale = np.asarray(
            jax.random.uniform(k_m, (sys.nbody,), minval=r.mass_scale[0], maxval=r.mass_scale[1])
        )
        strength = np.asarray(
            jax.random.uniform(k_s, (sys.nu,), minval=r.motor_strength[0], maxval=r.motor_strength[1])
        )
        shift = float(jax.random.uniform(k_c, (), minval=r.base_com_shift_m[0], maxval=r.base_com_shift_m[1]))
        want = {
            "geom_friction": np.concatenate(
                [np.full((sys.ngeom, 1), friction, np.float32), np.asarray(sys.geom_friction)[:, 1:]], axis=1
            ),
            "body_mass": np.asarray(sys.body_mass) * scale,
            "body_inertia": np.asarray(sys.body_inertia) * scale[:, None],
            "actuator_forcerange": np.asarray(sys.actuator_forcerange) * strength[:, None],
        }
        gain, bias, ipos = (
            np.array(sys.actuator_gainprm),
            np.array(sys.actuator_biasprm),
            np.array(sys.body_ipos),
        )
        gain[:, 0] *= strength
        bias[:, 1] *= strength
        ipos[base, 0] += np.float32(shift)
        want.update(actuator_gainprm=gain, actuator_biasprm=bias, body_ipos=ipos)
        for field, value in want.items():
            np.testing.assert_array_equal(np.asarray(getattr(model, field))[b], value, err_msg=field)
