"""Compatibility shims for the pinned toolchain (brax 0.14.2 on jax >= 0.10). Each one says what it
works around, measured, and the upstream issue where one exists, so it can be deleted once fixed:

* `patch_brax`: `jax.device_put_replicated`, removed from jax, still called by brax PPO.
* `brax_multi_device`: brax's `jax.pmap` as one sharded `jit` (jax's pmap crashes XLA on two GPUs),
  over one mesh of every process's devices when several processes train (jax.distributed).
* `brax_multi_process`: the randomness of a multi-process run made that of one process with as many
  devices (brax draws it per process), so a run does not depend on how its devices are spread.
* `mjx_local_device`: MJX's `put_model` places the model on jax.devices()[0], in a multi-process
  run a device of process 0 only.
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
import time
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
    axis of one entry per local device, and collectives on `axis_name` (pmean, psum, pmin, pmax)
    reduce across it; under vmap they are reductions over that axis, which XLA's SPMD partitioner
    turns into cross-device all-reduces. The mapped axis is sharded over the first n local devices,
    n being its length, as pmap does when `devices` is not given, over a mesh axis named PMAP_AXIS
    (so `_device_put_replicated`'s arrays enter without a copy or a second compilation).

    Several processes (jax.distributed): as jax's pmap, each process passes and gets back its own
    devices' entries, and the collectives span every process's devices. The call assembles the
    processes' local arrays into global ones over one mesh of the first n devices of every process
    (`_global_mesh`; no copy: the same device buffers), runs the jit there (every process must
    call it, as with pmap) and hands each process its own devices' entries back.

    Why: on jax 0.11.2 with CUDA (the GPU image this project measured on), XLA segfaults while
    compiling brax's `pmap(env.reset)` across two GPUs; jax's pmap is built on shard_map since
    0.8, and the same reset compiled as one jit over a NamedSharding runs.
    """
    unsupported = {k: v for k, v in kwargs.items() if v not in (None, (), 0)}
    unsupported.update({k: v for k, v in (("in_axes", in_axes), ("out_axes", out_axes)) if v != 0})
    if unsupported:
        raise NotImplementedError(f"pmap_as_sharded_jit does not support {sorted(unsupported)}")
    mapped = jax.vmap(fun, in_axes=in_axes, out_axes=out_axes, axis_name=axis_name)
    compiled, executables = {}, {}

    def call(*args):
        leaves = jax.tree.leaves(args)
        n = int(np.shape(leaves[0])[0])
        if n not in compiled:
            devices = jax.local_devices()[:n]
            if len(devices) < n:
                raise ValueError(f"mapped axis of size {n} but only {len(devices)} local devices")
            local = NamedSharding(Mesh(np.array(devices), (PMAP_AXIS,)), PartitionSpec(PMAP_AXIS))
            sharding = local
            if jax.process_count() > 1:
                sharding = NamedSharding(_global_mesh(n), PartitionSpec(PMAP_AXIS))
            jitted = jax.jit(
                mapped, in_shardings=sharding, out_shardings=sharding, donate_argnums=donate_argnums
            )
            compiled[n] = (jitted, local, sharding)
        jitted, local, sharding = compiled[n]
        if sharding is local:
            return jitted(*args)
        to_global = lambda x: _process_local_to_global(x, local, sharding)  # noqa: E731
        args = jax.tree.map(to_global, args)
        # compiled ahead, then run once every process has compiled (see processes_meet)
        key = (n, jax.tree.structure(args), tuple((x.shape, x.dtype) for x in jax.tree.leaves(args)))
        if key not in executables:
            executables[key] = jitted.lower(*args).compile()
        processes_meet()
        out = executables[key](*args)
        return jax.tree.map(lambda x: _global_to_process_local(x, local), out)

    return call


# How long a process waits at processes_meet for the others (process 0 evaluates while the others
# wait; a dead process ends the run sooner, through jax.distributed's heartbeats).
MEET_TIMEOUT_S = 3600
_meetings = [0]
_KEYS = "quadson_mjx"


class ProcessesStopped(KeyboardInterrupt):
    """Another process of a multi-process run stopped (a signal, an error): this one stops too, at
    the meeting where it learns of it (see processes_meet), as on a signal of its own."""


def processes_meet() -> None:
    """Waits until every process of a multi-process run has got here, through the key-value store
    of jax.distributed's coordination service (not a collective); raises ProcessesStopped when
    another process has stopped instead (processes_stop). Called before each computation across
    processes, so that none waits in a collective for a process that will not come:
    on the CPU, gloo gives up on a collective whose peers arrive more than about 30 s apart
    ("Gloo context initialization failed: Connect timeout", measured while process 0 compiled its
    first evaluation, which the others do not run, and when the processes' compilations of the
    training epoch took 17 s and 36 s, on a loaded 2-core machine); and a process stopped on a
    signal at its safe point left the others in the next collective until jax.distributed's
    shutdown barrier gave up (300 s)."""
    from jax._src import distributed

    client = distributed.global_state.client
    _meetings[0] += 1
    here = f"{_KEYS}/meet/{_meetings[0]}"
    client.key_value_set(f"{here}/{jax.process_index()}", "1")
    deadline = time.monotonic() + MEET_TIMEOUT_S
    while True:
        stopped = client.key_value_dir_get(f"{_KEYS}/stop")
        if stopped:
            key, why = stopped[0]
            raise ProcessesStopped(
                f"process {key.rsplit('/', 1)[-1]} of {jax.process_count()} stopped: {why}"
            )
        if len(client.key_value_dir_get(here)) == jax.process_count():
            return
        if time.monotonic() > deadline:
            raise TimeoutError(f"the other processes did not arrive within {MEET_TIMEOUT_S} s")
        time.sleep(0.005)


def processes_stop(reason: str) -> None:
    """Tells the other processes of a multi-process run that this one stops (they stop at their
    next processes_meet). A no-op in one process or once the coordination service is gone."""
    if jax.process_count() == 1:
        return
    from jax._src import distributed

    with contextlib.suppress(Exception):
        distributed.global_state.client.key_value_set(f"{_KEYS}/stop/{jax.process_index()}", reason[:300])


def _global_mesh(n: int) -> Mesh:
    """One 1-D mesh (axis PMAP_AXIS) over the first n devices of every process, process by process:
    the global device order in which brax numbers its per-device environments and keys."""
    by_process: dict[int, list] = {}
    for d in sorted(jax.devices(), key=lambda d: (d.process_index, d.id)):
        by_process.setdefault(d.process_index, []).append(d)
    if any(len(ds) < n for ds in by_process.values()):
        raise ValueError(f"mapped axis of size {n} but a process has fewer local devices")
    return Mesh(np.array([d for p in sorted(by_process) for d in by_process[p][:n]]), (PMAP_AXIS,))


def _process_local_to_global(x, local: NamedSharding, sharding: NamedSharding) -> jax.Array:
    """This process's (n, ...) entries -> the global (n * processes, ...) array over `sharding`,
    built from the same device buffers (a global array from an earlier call passes unchanged)."""
    if isinstance(x, jax.Array) and x.sharding == sharding:
        return x
    if not (isinstance(x, jax.Array) and x.sharding == local):
        x = jax.device_put(x, local)
    shape = (x.shape[0] * jax.process_count(), *x.shape[1:])
    return jax.make_array_from_single_device_arrays(shape, sharding, [s.data for s in x.addressable_shards])


def _global_to_process_local(x: jax.Array, local: NamedSharding) -> jax.Array:
    """A global array over the mesh -> this process's (n, ...) entries, the same device buffers,
    placed as jax's pmap places its outputs."""
    shards = [s.data for s in x.addressable_shards]
    shape = (len(shards) * shards[0].shape[0], *x.shape[1:])
    return jax.make_array_from_single_device_arrays(shape, local, shards)


@contextlib.contextmanager
def brax_multi_device(devices_to_use: int):
    """While active, brax's `jax.pmap` calls build `pmap_as_sharded_jit` instead, when brax will
    use more than one local device or several processes train (see pmap_as_sharded_jit). On one
    device of one process jax's pmap is left in place. Yields True when replaced.
    """
    if devices_to_use < 2 and jax.process_count() == 1:
        yield False
        return
    original = jax.pmap
    jax.pmap = pmap_as_sharded_jit
    try:
        yield True
    finally:
        jax.pmap = original


def brax_reset_keys(seed: int, num_envs: int, devices: int) -> jax.Array:
    """The keys brax 0.14.2's `ppo.train(seed=seed, num_envs=num_envs)` resets its environments
    with in one process training on `devices` devices, (devices, num_envs // devices, 2) uint32."""
    _, local_key = jax.random.split(jax.random.PRNGKey(seed))
    _, key_env, _ = jax.random.split(jax.random.fold_in(local_key, 0), 3)
    return jax.random.split(key_env, num_envs).reshape(devices, -1, 2)


def brax_env_key(seed: int) -> jax.Array:
    """The key brax 0.14.2's `ppo.train(seed=seed)` in one process draws the training
    environments' domain randomization from (its `key_env`)."""
    _, local_key = jax.random.split(jax.random.PRNGKey(seed))
    return jax.random.split(jax.random.fold_in(local_key, 0), 3)[1]


def process_rows(x, devices: int):
    """This process's rows of a per-device array of every process's devices (leading axis
    devices * process_count, process by process, as `_global_mesh` orders them)."""
    p = jax.process_index()
    return x[p * devices : (p + 1) * devices]


@contextlib.contextmanager
def brax_multi_process(seed: int, num_envs: int, devices: int):
    """While active, brax PPO in several processes draws the randomness that one process with
    `devices` * process_count devices draws: brax folds the process index into its environment
    keys (resets, domain randomization), so the same seed and global batch would train on other
    data depending on how the devices are spread over processes. Here every process resets its
    environments with its rows of the single-process reset keys (`brax_reset_keys`) and
    randomizes from the single-process key (`brax_env_key`); the training epochs' keys are
    handed out by `brax_training_state` (BraxTrainingState.epoch_keys, see `process_epoch_keys`).
    Evaluations run on process 0, whose keys are the single process's already. Nest inside
    `brax_multi_device`. A no-op in one process.
    """
    if jax.process_count() == 1:
        yield
        return
    from brax.training.agents.ppo import train as ppo_train

    original_pmap, original_wrap = jax.pmap, ppo_train._maybe_wrap_env
    total = devices * jax.process_count()
    reset_keys = process_rows(brax_reset_keys(seed, num_envs, total), devices)

    def pmap(fun, *args, **kwargs):
        compiled = original_pmap(fun, *args, **kwargs)
        if getattr(fun, "__name__", "") != "reset":
            return compiled
        return lambda keys: compiled(reset_keys if keys.shape == reset_keys.shape else keys)

    def maybe_wrap_env(*args, **kwargs):
        if len(args) >= 7:  # the training env, positional (the eval env passes its key by keyword)
            args = (*args[:6], brax_env_key(seed), *args[7:])
        return original_wrap(*args, **kwargs)

    jax.pmap, ppo_train._maybe_wrap_env = pmap, maybe_wrap_env
    try:
        yield
    finally:
        jax.pmap, ppo_train._maybe_wrap_env = original_pmap, original_wrap


@contextlib.contextmanager
def mjx_local_device():
    """While active, MJX's `put_model` without a `device` places the model on a device of this
    process. mujoco 4.0.0's `mjx._src.io._resolve_device` picks `jax.devices()[0]`, which in a
    multi-process run (jax.distributed) belongs to process 0: on the other processes the model's
    arrays span a device they cannot address, and the first jit over them fails ("Closing over
    jax.Array that spans non-addressable (non process local) devices"). A no-op in one process.
    """
    if jax.process_count() == 1:
        yield
        return
    from mujoco.mjx._src import io

    original = io._resolve_device

    def resolve_device(impl):
        device = original(impl)
        if device.process_index == jax.process_index():
            return device
        return jax.local_devices(backend=device.platform)[0]

    io._resolve_device = resolve_device
    try:
        yield
    finally:
        io._resolve_device = original


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


@contextlib.contextmanager
def brax_without_evaluator():
    """While active, brax's `acting.Evaluator` is a stand-in that builds nothing: for
    `ppo.train(run_evals=False)`, which never evaluates but still constructs its evaluator, and
    brax 0.14.2's evaluator compiles and runs a reset of its environments on construction (5.3 s
    of compilation at a 2 ms step on one H200). An evaluation asked of it raises."""
    from brax.training import acting

    original = acting.Evaluator

    class Evaluator:
        def __init__(self, *args, key=None, **kwargs):
            self._key = key  # brax_training_state's subclass advances it

        def run_evaluation(self, *args, **kwargs):
            raise RuntimeError("brax asked for an evaluation of a run with ppo.run_evals=false")

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


def process_epoch_keys(seed: int, epoch: int, devices: int) -> jax.Array:
    """This process's keys of training epoch `epoch`, (devices, 2): its rows of the keys one
    process with `devices` * process_count devices draws (see brax_multi_process)."""
    return process_rows(brax_epoch_keys(seed, epoch, devices * jax.process_count()), devices)


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
            if self.first_epoch > 0 or jax.process_count() > 1:
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
    resumed on another number of devices splits the same environments differently); in several
    processes, every process's devices' part, of which this process takes its own.
    """
    processes = jax.process_count()
    old, treedef = jax.tree.flatten(tree)
    if len(old) != len(leaves):
        raise ValueError(f"saved state has {len(leaves)} arrays, this run's has {len(old)}")
    new = []
    for i, (o, n) in enumerate(zip(old, leaves, strict=True)):
        n = np.asarray(n)
        shape_ok = n.shape == o.shape[1:] if replicated else n.size == o.size * processes
        if not shape_ok or n.dtype != o.dtype:
            whole = list(o.shape) if replicated or processes == 1 else [processes, *o.shape]
            raise ValueError(
                f"saved state array {i} is {n.dtype}{list(n.shape)}, this run's is {o.dtype}{whole}"
            )
        if replicated:
            n = np.broadcast_to(n, o.shape)
        else:
            n = n.reshape((processes, *o.shape))[jax.process_index()]
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
