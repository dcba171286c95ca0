"""Compatibility shims for the pinned toolchain (brax 0.14.2 on jax >= 0.10). Each one says what it
works around, measured, and the upstream issue where one exists, so it can be deleted once fixed:

* `patch_brax`: `jax.device_put_replicated`, removed from jax, still called by brax PPO.
* `brax_multi_device`: brax's `jax.pmap` as one sharded `jit` (jax's pmap crashes XLA on two GPUs).
* `brax_evaluator_compiles_once`: brax's evaluator compiled twice per run.
"""

from __future__ import annotations

import contextlib

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

# brax PPO's pmap axis name (brax.training.agents.ppo.train._PMAP_AXIS_NAME). Arrays placed for
# pmap must carry a sharding over a mesh axis of this name: jax's pmap gives its outputs exactly
# that, and an input placed any other way makes the first training epoch compile twice.
PMAP_AXIS = "i"


def _device_put_replicated(x, devices):
    """Drop-in for the removed `jax.device_put_replicated` (JAX's pmap migration guide).

    Stacks every leaf of the pytree `x` once per device, giving a leading axis of len(devices), and
    places shard i on devices[i] through a NamedSharding over a 1-D mesh: exactly the layout that
    `jax.pmap` expects of its inputs. When `devices` are the first local ones (what brax passes),
    the result also goes through a pmapped identity, so it carries exactly the sharding of a pmap
    output: brax hands the same parameters to its evaluator before and after training, and any
    other sharding compiles the evaluation twice (measured: about 12 s of a 228 s run on one H200).
    """
    devices = list(devices)
    sharding = NamedSharding(Mesh(np.array(devices), (PMAP_AXIS,)), PartitionSpec(PMAP_AXIS))

    def put(leaf):
        stacked = np.broadcast_to(np.asarray(leaf), (len(devices), *np.shape(leaf)))
        return jax.device_put(stacked, sharding)

    out = jax.tree.map(put, x)
    if devices == jax.local_devices()[: len(devices)]:
        out = jax.pmap(lambda t: t, axis_name=PMAP_AXIS)(out)
    return out


def patch_brax() -> bool:
    """Make brax PPO run on jax >= 0.10, which removed `jax.device_put_replicated`.

    brax 0.14.2's `ppo.train` still calls it (google/brax issue #671). The replacement is installed
    only when the attribute is missing, so a jax that still has it is left alone. Returns True when
    the shim was installed.
    """
    if hasattr(jax, "device_put_replicated"):  # jax < 0.10 still has it (hasattr is False on the
        return False  # deprecation AttributeError that newer jax raises)
    jax.device_put_replicated = _device_put_replicated
    return True


def pmap_as_sharded_jit(fun, axis_name=None, *, in_axes=0, out_axes=0, donate_argnums=(), **kwargs):
    """`jax.pmap` rebuilt as `jit(vmap(fun, axis_name))` over a NamedSharding of the mapped axis.

    Same contract as pmap for what brax PPO uses: every argument and result carries a leading
    axis of one entry per device, and collectives on `axis_name` (pmean, psum, pmin, pmax) reduce
    across it; under vmap they are reductions over that axis, which XLA's SPMD partitioner turns
    into cross-device all-reduces. The mapped axis is sharded over the first n local devices, n
    being its length, as pmap does when `devices` is not given, over a mesh axis named PMAP_AXIS
    (so `_device_put_replicated`'s arrays enter without a copy or a second compilation).

    Why: on jax 0.11.2 with CUDA (the GPU image this project measured on), XLA segfaults while
    compiling brax's `pmap(env.reset)` across two GPUs; jax's pmap is built on shard_map since
    0.8, and the same reset compiled as one jit over a NamedSharding runs. Single-process only:
    across hosts brax needs jax's own pmap (collectives that span processes).
    """
    unsupported = {k: v for k, v in kwargs.items() if v not in (None, (), 0)}
    unsupported.update({k: v for k, v in (("in_axes", in_axes), ("out_axes", out_axes)) if v != 0})
    if unsupported:
        raise NotImplementedError(f"pmap_as_sharded_jit does not support {sorted(unsupported)}")
    mapped = jax.vmap(fun, in_axes=in_axes, out_axes=out_axes, axis_name=axis_name)
    compiled = {}

    def call(*args):
        leaves = jax.tree.leaves(args)
        n = int(np.shape(leaves[0])[0])
        if n not in compiled:
            devices = jax.local_devices()[:n]
            if len(devices) < n:
                raise ValueError(f"mapped axis of size {n} but only {len(devices)} local devices")
            sharding = NamedSharding(Mesh(np.array(devices), (PMAP_AXIS,)), PartitionSpec(PMAP_AXIS))
            compiled[n] = jax.jit(
                mapped, in_shardings=sharding, out_shardings=sharding, donate_argnums=donate_argnums
            )
        return compiled[n](*args)

    return call


@contextlib.contextmanager
def brax_multi_device(devices_to_use: int):
    """While active, brax's `jax.pmap` calls build `pmap_as_sharded_jit` instead, when brax will
    use more than one local device and this is the only process (see pmap_as_sharded_jit). On one
    device, or across hosts, jax's pmap is left in place. Yields True when replaced.
    """
    if devices_to_use < 2 or jax.process_count() > 1:
        yield False
        return
    original = jax.pmap
    jax.pmap = pmap_as_sharded_jit
    try:
        yield True
    finally:
        jax.pmap = original


@contextlib.contextmanager
def brax_evaluator_compiles_once():
    """While active, brax's `acting.Evaluator` commits its inputs to the first local device.

    brax 0.14.2's evaluator donates and reuses its env state. The first evaluation gets a fresh,
    uncommitted state and the parameters as device_put_replicated left them; later ones get its own
    output and the training epoch's parameters, which carry other shardings on jax >= 0.8, so
    the evaluation compiled a second time (measured: 14.5 s of a 230 s run on one H200, and about
    as long on a CPU). Placing both on one device every time gives one compilation.
    """
    from brax.training import acting

    original = acting.Evaluator

    class Evaluator(original):
        def run_evaluation(self, policy_params, training_metrics, aggregate_episodes=True):
            device = jax.local_devices()[0]
            self._eval_state_to_donate = jax.device_put(self._eval_state_to_donate, device)
            return super().run_evaluation(
                jax.device_put(policy_params, device), training_metrics, aggregate_episodes
            )

    acting.Evaluator = Evaluator
    try:
        yield
    finally:
        acting.Evaluator = original
