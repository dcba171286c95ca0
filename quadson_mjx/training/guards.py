"""What stops a training run early with one line instead of a wasted run or a traceback: a run that
diverged (a non-finite loss, gradient or parameter at an evaluation), a batch of environments that
cannot fit in memory (estimated before compiling; XLA's resource-exhausted error after), a physics
implementation the environments cannot run on here (env.impl="warp" without warp-lang, or a batch
larger than Warp's buffers were sized for)."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import env_model
from quadson_mjx.errors import UsageError


class TrainingDiverged(UsageError):
    """A loss, gradient (Adam's moments) or parameter became NaN or infinite: the run stopped at the
    evaluation that saw it, without writing that checkpoint."""


class OutOfMemory(UsageError):
    """The run's batch of environments does not fit the device's memory."""


def non_finite(tree) -> list[str]:
    """Key paths of the floating-point leaves of `tree` holding a NaN or an infinity."""
    bad = []
    for keypath, leaf in jax.tree_util.tree_leaves_with_path(tree):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
            bad.append(jax.tree_util.keystr(keypath))
    return bad


def non_finite_metrics(metrics: dict) -> list[str]:
    """Names of the losses (training/*loss*) and the evaluation reward in brax's `metrics` that are
    not finite."""
    keys = [k for k in metrics if k.startswith("training/") and "loss" in k]
    keys += [k for k in ("eval/episode_reward",) if k in metrics]
    return [k for k in keys if not np.all(np.isfinite(np.asarray(metrics[k], dtype=np.float64)))]


def diverged(where: str, what: list[str], last_good: str) -> TrainingDiverged:
    return TrainingDiverged(
        f"training diverged at {where}: non-finite {', '.join(what[:3])}{' ...' if len(what) > 3 else ''}; "
        f"stopped without writing that checkpoint (the last finite one: {last_good}); "
        "lower --ppo.learning_rate or raise --ppo.max_grad_norm's clipping"
    )


def check_backend(env_cfg, ppo_cfg=None, devices: int = 1) -> None:
    """Raises UsageError when env.impl names an MJX implementation the environments cannot run on
    here (warp without warp-lang) or that steps the task wrongly (env_model.check_warp_ground),
    or, given ppo_cfg, when a batch of the run (ppo.num_envs over `devices`, ppo.num_eval_envs) is
    more worlds than Warp's contact buffer is sized for (env.warp_max_worlds)."""
    try:
        env_model.check_env_impl(env_cfg.impl)
        env_model.check_warp_ground(env_cfg)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if env_cfg.impl != "warp" or ppo_cfg is None:
        return
    batch = max(-(-ppo_cfg.num_envs // devices), ppo_cfg.num_eval_envs)
    if batch > env_cfg.warp_max_worlds:
        raise UsageError(
            f"env.warp_max_worlds={env_cfg.warp_max_worlds} is fewer worlds than the run steps in one "
            f"batch ({batch}: ppo.num_envs over {devices} device(s), or ppo.num_eval_envs); "
            f"set --env.warp_max_worlds={batch}"
        )


def memory_bytes(devices: int) -> tuple[int, str]:
    """-> (bytes, what) of memory the run's arrays may use: the devices' allocator limit on a GPU,
    the machine's physical memory on the CPU backend."""
    stats = jax.local_devices()[0].memory_stats() or {}
    if stats.get("bytes_limit"):
        kind = jax.local_devices()[0].device_kind
        return int(stats["bytes_limit"]) * devices, f"{devices} x {kind}"
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"), "this machine's RAM"


def check_memory(env, num_envs: int, devices: int) -> None:
    """Raises OutOfMemory before anything compiles when `num_envs` environment states alone (sized
    from the environment's reset, unbatched, with jax.eval_shape: no compilation) need more than the
    memory available; brax holds them at least twice (the state and its update), and the unrolls,
    networks and the randomized models come on top, so this is a lower bound: a run that passes can
    still run out (the resource-exhausted error is then caught, see `is_out_of_memory`)."""
    one, two = (state_bytes(env, n) for n in (1, 2))
    per_env, shared = two - one, 2 * one - two  # shared: held once per batch (Warp's contact buffer)
    need = 2 * (per_env * num_envs + shared)
    have, what = memory_bytes(devices)
    if need > have:
        raise OutOfMemory(
            f"ppo.num_envs={num_envs:,} needs at least {need / 1e9:.1f} GB for the environments' states "
            f"({per_env / 1e3:.1f} kB each, twice) and {what} has {have / 1e9:.1f} GB; "
            f"lower --ppo.num_envs (and --ppo.batch_size with it)"
        )


def state_bytes(env, n: int) -> int:
    """Bytes of the states of a batch of n environments (vmapped reset, jax.eval_shape: nothing
    compiles)."""
    keys = jax.ShapeDtypeStruct((n, 2), jnp.uint32)
    shapes = jax.eval_shape(jax.vmap(env.reset), keys)
    return sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(shapes))


def is_out_of_memory(exc: BaseException) -> bool:
    """True for XLA's resource-exhausted error (jax raises it as JaxRuntimeError / XlaRuntimeError)
    and Python's MemoryError."""
    text = str(exc)
    return isinstance(exc, MemoryError) or "RESOURCE_EXHAUSTED" in text or "Out of memory" in text


def out_of_memory(ppo_cfg, exc: BaseException) -> OutOfMemory:
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
    return OutOfMemory(
        f"out of memory with ppo.num_envs={ppo_cfg.num_envs:,}, ppo.batch_size={ppo_cfg.batch_size:,} "
        f"({first}); lower --ppo.num_envs and --ppo.batch_size, or --ppo.num_eval_envs"
    )
