"""Compatibility shims for the pinned toolchain (brax 0.14.2 on jax >= 0.10). Each one says what it
works around, measured, and the upstream issue where one exists, so it can be deleted once fixed:

* `patch_brax`: `jax.device_put_replicated`, removed from jax, still called by brax PPO.
* `brax_multi_device`: brax's `jax.pmap` as one sharded `jit` (jax's pmap crashes XLA on two GPUs).
* `brax_evaluator_compiles_once`: brax's evaluator compiled twice per run.
* `brax_training_state`: brax PPO's whole training state (optimiser moments, step count, RNG,
  environment states) saved and restored at evaluations; brax's own checkpoints keep only the
  parameters, so a resumed run restarts Adam's moments (google/brax issue #655).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.metadata
import re
from collections.abc import Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

# The versions these shims are tested with (pyproject.toml pins the same): brax exactly, jax from
# JAX_LOWEST up to, not including, JAX_BELOW (0.10.2 on the CPU, 0.11.2 on the GPU machines). The
# shims reach into brax PPO's internals, so another version gets an ImportError, not a wrong patch.
BRAX_TESTED = "0.14.2"
JAX_LOWEST = "0.10.2"
JAX_BELOW = "0.12"
TESTED_WITH = f"brax {BRAX_TESTED} and jax {JAX_LOWEST}-0.11.x"


def _release(version: str) -> tuple[int, ...]:
    """ "0.11.2" -> (0, 11, 2); the leading release numbers only ("0.5.0rc1" -> (0, 5, 0))."""
    return tuple(int(n) for n in re.findall(r"\d+", re.match(r"[\d.]*", version).group().strip(".")))


def check_versions(brax_version: str | None = None, jax_version: str | None = None) -> None:
    """Raises ImportError in one line unless brax and jax (default: the installed ones) are the
    tested versions above."""
    brax_version = brax_version or importlib.metadata.version("brax")
    jax_version = jax_version or jax.__version__
    jax_ok = _release(JAX_LOWEST) <= _release(jax_version) < _release(JAX_BELOW)
    if _release(brax_version) != _release(BRAX_TESTED) or not jax_ok:
        raise ImportError(
            f"quadson_mjx.compat is tested with {TESTED_WITH}; found brax {brax_version} and jax "
            f"{jax_version}: install the pinned versions (pip install -e .)"
        )


check_versions()

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


def brax_epoch_keys(seed: int, epoch: int, devices: int, process_id: int = 0) -> jax.Array:
    """The PRNG keys brax 0.14.2's `ppo.train(seed=seed)` passes to its training epoch number
    `epoch` (0-based), (devices, 2) uint32: its key derivation, step by step, so that a resumed
    run can continue the key sequence where the interrupted one stopped.
    (tests/test_training.py checks these against the keys brax passes.)"""
    _, local_key = jax.random.split(jax.random.PRNGKey(seed))
    local_key = jax.random.fold_in(local_key, process_id)
    local_key, _, _ = jax.random.split(local_key, 3)
    for _ in range(epoch + 1):
        epoch_key, local_key = jax.random.split(local_key)
    return jax.random.split(epoch_key, devices)


@dataclasses.dataclass
class BraxTrainingState:
    """What `brax_training_state` saw and what it restores (see there).

    first_epoch: global index of the first training epoch of this session (0: a fresh run).
    restore_training_state: leaves of brax's TrainingState (one device's copy) to start from.
    restore_env_state: leaves of the batched environment state to start from (optional).
    epoch_keys: epoch -> keys, used from first_epoch on when first_epoch > 0.
    checkpoint: called before every training epoch and evaluation (a place to stop at).
    """

    first_epoch: int = 0
    restore_training_state: list | None = None
    restore_env_state: list | None = None
    epoch_keys: Callable[[int], jax.Array] | None = None
    checkpoint: Callable[[], None] = lambda: None
    epochs_done: int = 0
    keys_seen: list = dataclasses.field(default_factory=list)
    latest: tuple | None = None  # (training_state, env_state) after the last epoch, until the next

    def training_state_leaves(self) -> list[np.ndarray]:
        """One device's copy of the TrainingState after the last epoch, as numpy leaves."""
        return [np.asarray(leaf[0]) for leaf in jax.tree.leaves(self.latest[0])]

    def env_state_leaves(self) -> list[np.ndarray]:
        """The whole batched environment state after the last epoch (every device), numpy leaves."""
        return [np.asarray(leaf) for leaf in jax.tree.leaves(self.latest[1])]

    def _wrap(self, epoch_fn):
        def call(training_state, env_state, keys):
            self.checkpoint()
            self.latest = None  # drop references to buffers that this call donates
            if self.epochs_done == 0:
                if self.restore_training_state is not None:
                    training_state = _replace_leaves(training_state, self.restore_training_state, True)
                if self.restore_env_state is not None:
                    env_state = _replace_leaves(env_state, self.restore_env_state, False)
            if self.first_epoch > 0:
                keys = self.epoch_keys(self.first_epoch + self.epochs_done)
            self.keys_seen.append(np.asarray(keys))
            out = epoch_fn(training_state, env_state, keys)
            self.epochs_done += 1
            self.latest = (out[0], out[1])
            return out

        return call


def _replace_leaves(tree, leaves, replicated: bool):
    """`tree` with its leaves replaced by numpy `leaves`, placed like the leaves they replace.

    replicated: each new leaf is one device's copy, stacked over the leading device axis;
    otherwise it holds every device's part and is reshaped to the replaced leaf's shape (so a run
    resumed on another number of devices splits the same environments differently).
    """
    old, treedef = jax.tree.flatten(tree)
    if len(old) != len(leaves):
        raise ValueError(f"saved state has {len(leaves)} arrays, this run's has {len(old)}")
    new = []
    for i, (o, n) in enumerate(zip(old, leaves, strict=True)):
        n = np.asarray(n)
        shape_ok = n.shape == o.shape[1:] if replicated else n.size == o.size
        if not shape_ok or n.dtype != o.dtype:
            raise ValueError(
                f"saved state array {i} is {n.dtype}{list(n.shape)}, this run's is {o.dtype}{list(o.shape)}"
            )
        n = np.broadcast_to(n, o.shape) if replicated else n.reshape(o.shape)
        new.append(jax.device_put(n, o.sharding))
    return jax.tree.unflatten(treedef, new)


@contextlib.contextmanager
def brax_training_state(state: BraxTrainingState, eval_offset: int = 0):
    """While active, brax PPO's training epoch and evaluator are wrapped so that the whole training
    state can be saved at an evaluation and restored on resume, without forking `ppo.train`:

    * brax builds its epoch with `jax.pmap(training_epoch, ...)`; that one call gets a wrapper
      that records the epoch's output (TrainingState: params, normaliser, Adam's moments, env step
      count; and the batched environment states), replaces the first epoch's inputs by the saved
      ones, and hands out the keys of the right global epoch (`brax_epoch_keys`);
    * `acting.Evaluator` starts `eval_offset` evaluations into its key sequence, so the resumed
      run's evaluations draw the same keys as the uninterrupted run's.

    Save `state.training_state_leaves()` (and `env_state_leaves()`) from brax's
    `policy_params_fn` or after an interruption: between two epochs `state.latest` is alive.
    Nest inside `brax_multi_device` (this wraps whatever `jax.pmap` is at entry).
    """
    from brax.training import acting

    original_pmap, original_evaluator = jax.pmap, acting.Evaluator

    def pmap(fun, *args, **kwargs):
        compiled = original_pmap(fun, *args, **kwargs)
        return state._wrap(compiled) if getattr(fun, "__name__", "") == "training_epoch" else compiled

    class Evaluator(original_evaluator):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            for _ in range(eval_offset):  # run_evaluation splits its key once per evaluation
                self._key, _ = jax.random.split(self._key)

        def run_evaluation(self, *args, **kwargs):
            state.checkpoint()
            return super().run_evaluation(*args, **kwargs)

    jax.pmap, acting.Evaluator = pmap, Evaluator
    try:
        yield state
    finally:
        jax.pmap, acting.Evaluator = original_pmap, original_evaluator
