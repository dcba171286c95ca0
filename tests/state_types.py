"""A state whose leaf types change on its first step makes every jitted function that takes it
compile twice: brax's evaluation does (its first call gets the reset state, the next ones its own
output), 36-43 s again on one NVIDIA H200 for the tiled ground's evaluation before this check.
jax.eval_shape traces without compiling, so the check costs no XLA compilation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.wrappers.training import EvalWrapper


def leaf_types(tree) -> dict:
    """{path: (shape, dtype, weak_type)} of every leaf of an abstract (eval_shape) pytree."""
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): (v.shape, v.dtype, v.weak_type) for path, v in flat}


def assert_step_keeps_state_types(reset, step, reset_arg, action_size: int, batch: tuple = ()):
    """reset(reset_arg) -> state and step(state, action) -> state keep every leaf's shape, dtype
    and weak type. reset_arg: an abstract (jax.ShapeDtypeStruct) or concrete argument; batch:
    the action's leading shape."""
    before = jax.eval_shape(reset, reset_arg)
    action = jax.ShapeDtypeStruct((*batch, action_size), jnp.float32)
    after = jax.eval_shape(step, before, action)
    a, b = leaf_types(before), leaf_types(after)
    assert a.keys() == b.keys(), sorted(set(a) ^ set(b))
    changed = {k: (a[k], b[k]) for k in a if a[k] != b[k]}
    assert not changed, f"leaves whose type the step changes (reset -> step): {changed}"


def assert_evaluation_compiles_once(wrapped, action_size: int, batch: int) -> None:
    """brax's evaluation of `wrapped` (an env in its training wrappers, `batch` environments):
    its step keeps the reset state's leaf types (assert_step_keeps_state_types)."""
    evaluated = EvalWrapper(wrapped)
    keys = jax.ShapeDtypeStruct((batch, 2), jnp.uint32)
    assert_step_keeps_state_types(evaluated.reset, evaluated.step, keys, action_size, (batch,))
