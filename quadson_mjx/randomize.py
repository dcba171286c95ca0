"""Domain randomization as a pure function `(model, rng) -> (model, in_axes)` (seed 000 future work:
friction, masses, motor strength; latency and sensor noise live in the environment's step).

Used by brax's DomainRandomizationVmapWrapper: `rng` is a batch of keys (num_envs, 2), the returned
model has a leading batch axis on exactly the randomized fields, and in_axes marks those fields 0.
"""

from __future__ import annotations

import functools

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

    The draws are one jitted program (brax calls this eagerly, once for the training environments and
    once for the evaluator's: op by op, that was about 45 small programs to compile).
    """
    bounds = tuple(
        (float(lo), float(hi))
        for lo, hi in (ranges.friction, ranges.mass_scale, ranges.motor_strength, ranges.base_com_shift_m)
    )
    fields = _draw({k: getattr(model, k) for k in RANDOMIZED_FIELDS}, rng, bounds, int(base_body))
    batched = model.tree_replace(fields)
    in_axes = jax.tree.map(lambda _: None, model)
    in_axes = in_axes.tree_replace({k: 0 for k in fields})
    return batched, in_axes


# the mjx.Model fields that randomize() batches (in_axes 0)
RANDOMIZED_FIELDS = (
    "geom_friction",
    "body_mass",
    "body_inertia",
    "actuator_gainprm",
    "actuator_biasprm",
    "actuator_forcerange",
    "body_ipos",
)


@functools.partial(jax.jit, static_argnums=(2, 3))
def _draw(nominal: dict, rng: jax.Array, bounds: tuple, base_body: int) -> dict:
    """nominal: RANDOMIZED_FIELDS of the model; rng: (B, 2) keys; bounds: (lo, hi) of friction,
    mass_scale, motor_strength, base_com_shift_m -> the fields with a leading batch axis B."""
    (f_lo, f_hi), (m_lo, m_hi), (s_lo, s_hi), (c_lo, c_hi) = bounds

    def one(key):
        k_f, k_m, k_s, k_c = jax.random.split(key, 4)
        friction = jax.random.uniform(k_f, (), minval=f_lo, maxval=f_hi)
        scale = jax.random.uniform(k_m, nominal["body_mass"].shape, minval=m_lo, maxval=m_hi)
        strength = jax.random.uniform(k_s, nominal["actuator_gainprm"].shape[:1], minval=s_lo, maxval=s_hi)
        shift = jax.random.uniform(k_c, (), minval=c_lo, maxval=c_hi)
        return {
            "geom_friction": nominal["geom_friction"].at[:, 0].set(friction),
            "body_mass": nominal["body_mass"] * scale,
            "body_inertia": nominal["body_inertia"] * scale[:, None],
            "actuator_gainprm": nominal["actuator_gainprm"].at[:, 0].multiply(strength),
            "actuator_biasprm": nominal["actuator_biasprm"].at[:, 1].multiply(strength),
            "actuator_forcerange": nominal["actuator_forcerange"] * strength[:, None],
            "body_ipos": nominal["body_ipos"].at[base_body, 0].add(shift),
        }

    return jax.vmap(one)(rng)


def randomization_fn(ranges, base_body: int):
    """The `randomization_fn(model, rng)` that brax PPO expects, bound to the config's ranges."""

    def fn(model, rng):
        return randomize(model, rng, ranges, base_body)

    return fn
