"""Domain randomization as a pure function `(model, rng) -> (model, in_axes)` (seed 000 future work:
friction, masses, motor strength; latency and sensor noise live in the environment's step).

Used by brax's DomainRandomizationVmapWrapper: `rng` is a batch of keys (num_envs, 2), the returned
model has a leading batch axis on exactly the randomized fields, and in_axes marks those fields 0.
"""

from __future__ import annotations

import jax
from mujoco import mjx


def randomize(model: mjx.Model, rng: jax.Array, ranges) -> tuple[mjx.Model, mjx.Model]:
    """model: mjx.Model; rng: (B, 2) keys; ranges: the env config's `randomization` block.

    Per environment: sliding friction of every geom set to U(friction), every body mass scaled by one
    factor U(mass_scale) per body (inertia scaled with it), every servo's kp (gain and bias) and force
    range scaled by one factor U(motor_strength) per motor.
    """

    @jax.vmap
    def one(key):
        k_f, k_m, k_s = jax.random.split(key, 3)
        friction = jax.random.uniform(k_f, (), minval=ranges.friction[0], maxval=ranges.friction[1])
        geom_friction = model.geom_friction.at[:, 0].set(friction)
        scale = jax.random.uniform(
            k_m, (model.nbody,), minval=ranges.mass_scale[0], maxval=ranges.mass_scale[1]
        )
        body_mass = model.body_mass * scale
        body_inertia = model.body_inertia * scale[:, None]
        strength = jax.random.uniform(
            k_s, (model.nu,), minval=ranges.motor_strength[0], maxval=ranges.motor_strength[1]
        )
        gain = model.actuator_gainprm.at[:, 0].multiply(strength)
        bias = model.actuator_biasprm.at[:, 1].multiply(strength)
        force = model.actuator_forcerange * strength[:, None]
        return geom_friction, body_mass, body_inertia, gain, bias, force

    geom_friction, body_mass, body_inertia, gain, bias, force = one(rng)
    fields = {
        "geom_friction": geom_friction,
        "body_mass": body_mass,
        "body_inertia": body_inertia,
        "actuator_gainprm": gain,
        "actuator_biasprm": bias,
        "actuator_forcerange": force,
    }
    batched = model.tree_replace(fields)
    in_axes = jax.tree.map(lambda _: None, model)
    in_axes = in_axes.tree_replace({k: 0 for k in fields})
    return batched, in_axes


def randomization_fn(ranges):
    """The `randomization_fn(model, rng)` that brax PPO expects, bound to the config's ranges."""

    def fn(model, rng):
        return randomize(model, rng, ranges)

    return fn
