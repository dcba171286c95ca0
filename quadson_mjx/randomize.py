"""Domain randomization as a pure function `(model, rng) -> (model, in_axes)` (seed 000 future work:
friction, masses, motor strength; latency and sensor noise live in the environment's step).

Used by brax's DomainRandomizationVmapWrapper: `rng` is a batch of keys (num_envs, 2), the returned
model has a leading batch axis on exactly the randomized fields, and in_axes marks those fields 0.
"""

from __future__ import annotations

import jax
from mujoco import mjx

# the sliding friction of the models' contact geoms and floors (models/*/*.xml; seed 000's 0.8):
# randomization.friction sets every geom's friction, so a range that leaves the model as it is
# holds this value, not 1.0
NOMINAL_FRICTION = 0.8
# each randomization range at the value that leaves the model unchanged
NOMINAL_RANGES = {
    "friction": (NOMINAL_FRICTION, NOMINAL_FRICTION),
    "mass_scale": (1.0, 1.0),
    "motor_strength": (1.0, 1.0),
    "latency_s": (0.0, 0.0),
    "base_com_shift_m": (0.0, 0.0),
}


def nominal_range_overrides(keep: tuple[str, ...] = ()) -> list[str]:
    """env config overrides ("randomization.mass_scale=1.0,1.0", ..., no "env." prefix) that pin
    every randomization range but those named in `keep` at NOMINAL_RANGES: with randomize=true an
    episode then draws its sensor errors (and the kept ranges) on the nominal model."""
    unknown = set(keep) - set(NOMINAL_RANGES)
    if unknown:
        raise ValueError(f"no randomization range {sorted(unknown)}; choose from {sorted(NOMINAL_RANGES)}")
    return [f"randomization.{k}={lo},{hi}" for k, (lo, hi) in NOMINAL_RANGES.items() if k not in keep]


def randomize(model: mjx.Model, rng: jax.Array, ranges, base_body: int = 1) -> tuple[mjx.Model, mjx.Model]:
    """model: mjx.Model; rng: (B, 2) keys; ranges: the env config's `randomization` block.

    Per environment: sliding friction of every geom set to U(friction), every body mass scaled by one
    factor U(mass_scale) per body (inertia scaled with it), every servo's kp (gain and bias) and force
    range scaled by one factor U(motor_strength) per motor, the base's centre of mass moved along body
    x by U(base_com_shift_m) (the model's +5 cm CoM is an assumption, models/quadson/README.md).
    """

    @jax.vmap
    def one(key):
        k_f, k_m, k_s, k_c = jax.random.split(key, 4)
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
        shift = jax.random.uniform(
            k_c, (), minval=ranges.base_com_shift_m[0], maxval=ranges.base_com_shift_m[1]
        )
        body_ipos = model.body_ipos.at[base_body, 0].add(shift)
        return geom_friction, body_mass, body_inertia, gain, bias, force, body_ipos

    geom_friction, body_mass, body_inertia, gain, bias, force, body_ipos = one(rng)
    fields = {
        "geom_friction": geom_friction,
        "body_mass": body_mass,
        "body_inertia": body_inertia,
        "actuator_gainprm": gain,
        "actuator_biasprm": bias,
        "actuator_forcerange": force,
        "body_ipos": body_ipos,
    }
    batched = model.tree_replace(fields)
    in_axes = jax.tree.map(lambda _: None, model)
    in_axes = in_axes.tree_replace({k: 0 for k in fields})
    return batched, in_axes


def randomization_fn(ranges, base_body: int):
    """The `randomization_fn(model, rng)` that brax PPO expects, bound to the config's ranges."""

    def fn(model, rng):
        return randomize(model, rng, ranges, base_body)

    return fn
