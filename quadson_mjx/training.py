"""Brax PPO training of foot-offset policies: configs, checkpoints, MCAP metrics, resume.

`train(env_cfg, ppo_cfg, run_dir)` calls `brax.training.agents.ppo.train` (not a fork of it) and
writes one run directory:

    run_dir/config.json              resolved env + ppo configs, versions
    run_dir/train.mcap               every evaluation's metrics (/train/metrics), events (/train/log),
                                     configs and versions as metadata, the MJCF as an attachment
    run_dir/checkpoints/step_*.msgpack  (normaliser, policy, value) params at every evaluation
    run_dir/checkpoints/state_*.npz     brax's whole TrainingState (+ Adam's moments, step count)
    run_dir/checkpoints/env_state_*.npz the environments' states, when stopped by a signal
    run_dir/checkpoints/latest       name of the newest checkpoint

Checkpoints are written atomically (temp file + rename), so a killed run never leaves a half file
behind as its newest. `--resume RUN_DIR` restores the whole training state and continues the run
as if it had not stopped (see `train`); the previous log is kept beside the new one, which starts
with its readable contents. SIGINT and SIGTERM stop a run at the next safe point (see `train`).

Several local GPUs: brax splits environments and batches over them; `compat.brax_multi_device`
compiles brax's per-device functions as one sharded jit (ppo.multi_device, ppo.max_devices).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import jax
import ml_collections
import numpy as np

from quadson_mjx.config import to_json

CHECKPOINT_DIR = "checkpoints"


def ppo_config(preset: str = "gpu") -> ml_collections.ConfigDict:
    """PPO hyperparameters. Presets: "gpu" (the real job on one GPU), "cpu" (a small run that
    finishes in minutes on a CPU and still learns), "test" (a few iterations, for tests)."""
    base = {
        "num_timesteps": 80_000_000,
        # An evaluation (and checkpoint) every 16M steps: each one runs 128 episodes of 938 sequential
        # steps, 2.74 s on one H100, while 16M training steps take 21.5 s (748k steps/s); with 11,
        # the 10 after the first spent 27 s of a 248 s main job (benchmarks/results_time_to_policy_h100_evals6.json)
        "num_evals": 6,
        "num_envs": 8192,
        "num_eval_envs": 128,
        "episode_length": 0,  # 0: the env config's episode length (18.75 s)
        "unroll_length": 20,
        # 8 minibatches of 1024 envs x 20 steps: the same 163,840 samples per update as 32 x 256,
        # in 4x fewer, larger gradient steps (the small MLPs leave a GPU idle between kernels;
        # measured on one H100: 594k env steps/s against 460k), with twice the learning rate.
        "batch_size": 1024,
        "num_minibatches": 8,
        "num_updates_per_batch": 4,
        "learning_rate": 6e-4,
        "entropy_cost": 1e-2,
        "discounting": 0.97,
        "gae_lambda": 0.95,
        "clipping_epsilon": 0.2,
        "max_grad_norm": 1.0,
        "reward_scaling": 1.0,
        "normalize_observations": True,
        "policy_hidden": (128, 128, 128, 128),
        "value_hidden": (256, 256, 256, 256, 256),
        # "tanh_normal": brax's default (tanh-squashed Gaussian, mean and scale from the MLP with
        # random weights, so the untrained policy already pushes every foot off the gait).
        # "gait_normal": a Gaussian whose mean layer starts at zero, so the untrained policy is the
        # gait itself, with a learned state-independent std starting at init_noise_std (used only
        # here). Either way the env clips actions to [-1, 1].
        "policy_distribution": "tanh_normal",
        "init_noise_std": 0.3,
        # Local GPUs to train on (0: all). Several: brax splits the envs and the batch evenly and
        # all-reduces gradients. "sharded_jit" compiles brax's per-device functions as one jit over
        # the devices (compat.pmap_as_sharded_jit; jax's own pmap crashes XLA on jax 0.11.2 with
        # two GPUs); "pmap" keeps jax's pmap (and is always used across several hosts).
        "max_devices": 0,
        "multi_device": "sharded_jit",
        # Evaluations (the logged eval/* metrics) run the policy's mean action, as deployment does;
        # False samples from the policy as in training (brax's default).
        "deterministic_eval": True,
        "seed": 0,
    }
    presets = {
        "gpu": {},
        "cpu": {
            # 2 min 40 s on 2 cores (measured). Starts from the gait (gait_normal, small exploration
            # noise): random initial offsets make the robot fall, and learning not to fall from
            # there takes more samples than a CPU gives in minutes (README: Results).
            "policy_distribution": "gait_normal",
            "init_noise_std": 0.1,
            "num_timesteps": 600_000,
            "num_evals": 6,
            "num_envs": 128,
            "num_eval_envs": 32,
            "episode_length": 250,
            "batch_size": 128,
            "num_minibatches": 8,
            "learning_rate": 3e-4,
            "policy_hidden": (64, 64),
            "value_hidden": (128, 128),
        },
        "test": {
            "num_timesteps": 2 * 4 * 8 * 2,
            "num_evals": 2,
            "num_envs": 4,
            "num_eval_envs": 2,
            "episode_length": 10,
            "unroll_length": 8,
            "batch_size": 4,
            "num_minibatches": 2,
            "num_updates_per_batch": 1,
            "policy_hidden": (8,),
            "value_hidden": (8,),
        },
    }
    if preset not in presets:
        raise ValueError(f"unknown ppo preset {preset!r}; choose from {sorted(presets)}")
    cfg = ml_collections.ConfigDict({**base, **presets[preset], "preset": preset})
    cfg.lock()
    return cfg


def local_devices_to_use(cfg) -> int:
    """This process's devices brax trains on: all local ones, or ppo.max_devices of them."""
    n = jax.local_device_count()
    return min(n, cfg.max_devices) if cfg.max_devices else n


def _require(cfg, key: str, ok, what: str, kind=(int, float)) -> None:
    v = cfg[key]
    if isinstance(v, bool) or not isinstance(v, kind) or not math.isfinite(v) or not ok(v):
        raise ValueError(f"ppo.{key} must be {what}, got {v!r}")


def check_ppo_config(cfg) -> None:
    """Raises ValueError naming the key for a value brax would reject late or misread silently:
    non-finite or out-of-range numbers, sizes that do not split over the devices, unknown names."""
    if cfg.policy_distribution not in POLICY_DISTRIBUTIONS:
        raise ValueError(
            f"ppo.policy_distribution is {cfg.policy_distribution!r}; choose from {list(POLICY_DISTRIBUTIONS)}"
        )
    if cfg.multi_device not in ("sharded_jit", "pmap"):
        raise ValueError(f"ppo.multi_device is {cfg.multi_device!r}; choose 'sharded_jit' or 'pmap'")
    for key in (
        "num_timesteps",
        "num_envs",
        "num_eval_envs",
        "unroll_length",
        "batch_size",
        "num_minibatches",
        "num_updates_per_batch",
        "num_evals",
    ):
        _require(cfg, key, lambda v: v >= 1, "an integer >= 1", int)
    positive = lambda v: v > 0  # noqa: E731
    _require(cfg, "episode_length", lambda v: v >= 0, "an integer >= 0 (0: the env's episode length)", int)
    _require(cfg, "max_devices", lambda v: v >= 0, "an integer >= 0 (0: all)", int)
    _require(cfg, "seed", lambda v: 0 <= v < 2**31, "an integer in [0, 2^31)", int)
    _require(cfg, "learning_rate", positive, "a finite number > 0")
    _require(cfg, "entropy_cost", lambda v: v >= 0, "a finite number >= 0")
    _require(cfg, "discounting", lambda v: 0 < v <= 1, "in (0, 1]")
    _require(cfg, "gae_lambda", lambda v: 0 <= v <= 1, "in [0, 1]")
    _require(cfg, "clipping_epsilon", positive, "a finite number > 0")
    _require(cfg, "max_grad_norm", positive, "a finite number > 0 (the gradient clipping norm)")
    _require(cfg, "reward_scaling", positive, "a finite number > 0")
    _require(cfg, "init_noise_std", positive, "a finite number > 0")
    devices = local_devices_to_use(cfg) * jax.process_count()
    for key in ("num_envs", "batch_size"):
        if cfg[key] % devices:
            raise ValueError(f"ppo.{key}={cfg[key]} does not split evenly over {devices} devices")
    if (cfg.batch_size * cfg.num_minibatches) % cfg.num_envs:
        raise ValueError(
            f"ppo.batch_size * ppo.num_minibatches = {cfg.batch_size * cfg.num_minibatches} must be a multiple "
            f"of ppo.num_envs = {cfg.num_envs} (brax collects whole unrolls of every env)"
        )


# --- networks and checkpoints -----------------------------------------------------------------------


POLICY_DISTRIBUTIONS = ("tanh_normal", "gait_normal")


def make_networks(obs_size: int, action_size: int, ppo_cfg):
    """brax's PPO networks for `ppo_cfg.policy_distribution` (see ppo_config)."""
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import networks as ppo_networks

    kind = ppo_cfg.policy_distribution
    if kind not in POLICY_DISTRIBUTIONS:
        raise ValueError(f"ppo.policy_distribution is {kind!r}; choose from {list(POLICY_DISTRIBUTIONS)}")
    extra = {}
    if kind == "gait_normal":
        extra = {
            "distribution_type": "normal",
            "noise_std_type": "log",  # std = exp(param): stays positive whatever the update
            "init_noise_std": float(ppo_cfg.init_noise_std),
            "mean_kernel_init_fn": jax.nn.initializers.constant,
            "mean_kernel_init_kwargs": {"value": 0.0},
        }
    normalize = running_statistics.normalize if ppo_cfg.normalize_observations else (lambda x, y: x)
    return ppo_networks.make_ppo_networks(
        obs_size,
        action_size,
        preprocess_observations_fn=normalize,
        policy_hidden_layer_sizes=tuple(ppo_cfg.policy_hidden),
        value_hidden_layer_sizes=tuple(ppo_cfg.value_hidden),
        **extra,
    )


def params_template(obs_size: int, action_size: int, ppo_cfg):
    """Freshly initialised (normaliser, policy, value) params: the structure a checkpoint restores into."""
    from brax.training.acme import running_statistics, specs

    nets = make_networks(obs_size, action_size, ppo_cfg)
    key_p, key_v = jax.random.split(jax.random.PRNGKey(0))
    normalizer = running_statistics.init_state(specs.Array((obs_size,), np.dtype("float32")))
    return (normalizer, nets.policy_network.init(key_p), nets.value_network.init(key_v))


def save_checkpoint(run_dir: Path, step: int, params) -> Path:
    import flax.serialization

    ckpt_dir = Path(run_dir) / CHECKPOINT_DIR
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:012d}.msgpack"
    data = flax.serialization.to_bytes(jax.device_get(params))
    tmp = ckpt_dir / (name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, ckpt_dir / name)
    latest_tmp = ckpt_dir / "latest.tmp"
    latest_tmp.write_text(name)
    os.replace(latest_tmp, ckpt_dir / "latest")
    return ckpt_dir / name


def latest_checkpoint(run_dir: Path) -> tuple[Path, int]:
    """-> (path, env step) of the newest checkpoint; raises FileNotFoundError naming what is missing."""
    ckpt_dir = Path(run_dir) / CHECKPOINT_DIR
    pointer = ckpt_dir / "latest"
    if not pointer.exists():
        raise FileNotFoundError(f"no checkpoint in {run_dir}: {pointer} does not exist")
    path = ckpt_dir / pointer.read_text().strip()
    if not path.exists():
        raise FileNotFoundError(f"{pointer} names {path.name}, which does not exist")
    return path, int(path.stem.split("_")[1])


def _save_npz(path: Path, leaves: list[np.ndarray], step: int) -> None:
    """Arrays to `path` atomically (temp file + rename), with the env step they belong to."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez(f, step=np.int64(step), **{f"leaf_{i:05d}": leaf for i, leaf in enumerate(leaves)})
    os.replace(tmp, path)


def _load_npz(path: Path, step: int) -> list[np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            if int(data["step"]) != step:
                raise ValueError(f"it holds step {int(data['step'])}, not {step}")
            names = sorted(k for k in data.files if k.startswith("leaf_"))
            return [data[k] for k in names]
    except Exception as e:  # zipfile, numpy and our own checks raise several types
        raise ValueError(
            f"training state {path} is corrupt or does not belong to its checkpoint ({e}); "
            f"move it away to resume with the parameters only (the optimiser's moments restart)"
        ) from e


def training_state_path(run_dir: Path, step: int) -> Path:
    """brax's whole TrainingState (params, normaliser, Adam's moments, step count) at `step`,
    written at every evaluation next to the parameter checkpoint."""
    return Path(run_dir) / CHECKPOINT_DIR / f"state_{step:012d}.npz"


def env_state_path(run_dir: Path, step: int) -> Path:
    """The batched environment states at `step`, written when a run stops on a signal or Ctrl-C
    (about 57 kB per environment: 0.47 GB for the gpu preset's 8192, so not at every evaluation)."""
    return Path(run_dir) / CHECKPOINT_DIR / f"env_state_{step:012d}.npz"


def epoch_steps(ppo_cfg) -> tuple[int, int]:
    """-> (environment steps per training epoch, epochs) of brax PPO for `ppo_cfg`: brax splits
    num_timesteps into max(num_evals - 1, 1) epochs of whole training steps, rounding up."""
    per_train_step = ppo_cfg.batch_size * ppo_cfg.unroll_length * ppo_cfg.num_minibatches
    epochs = max(ppo_cfg.num_evals - 1, 1)
    return math.ceil(ppo_cfg.num_timesteps / (epochs * per_train_step)) * per_train_step, epochs


# PPO keys added after runs were already published, with the value that reproduces what those runs
# did: a run directory saved before a key existed is read with it (load_run_config).
PPO_KEYS_ADDED = {
    "policy_distribution": "tanh_normal",
    "init_noise_std": 0.3,
    "max_devices": 0,
    "multi_device": "sharded_jit",
    "deterministic_eval": False,
}


def load_run_config(run_dir: Path) -> tuple[ml_collections.ConfigDict, ml_collections.ConfigDict]:
    """-> (env_cfg, ppo_cfg) of a run directory, with keys added since the run filled in
    (PPO_KEYS_ADDED, env_config.ENV_KEYS_ADDED). A damaged or incomplete config.json, a key this version does
    not know, a missing key, a value of the wrong type or out of range is a ValueError naming the
    file and the key."""
    from quadson_mjx.config import conform
    from quadson_mjx.env_config import check_env_config, env_config, with_added_keys

    path = Path(run_dir) / "config.json"
    if not path.exists():
        raise FileNotFoundError(f"{run_dir} is not a run directory: {path} does not exist")
    copy = "a copy of both configs is in the run's train.mcap (metadata env_config and ppo_config)"
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path} is not valid JSON ({e}): the file is damaged; {copy}") from None
    if (
        not isinstance(data, dict)
        or not isinstance(data.get("env"), dict)
        or not isinstance(data.get("ppo"), dict)
    ):
        raise ValueError(f"{path} lacks its 'env' or 'ppo' section: the file is incomplete; {copy}")
    ppo = {**PPO_KEYS_ADDED, **data["ppo"]}
    preset = ppo.get("preset", "gpu")
    if preset not in ("gpu", "cpu", "test"):
        raise ValueError(f"{path}: config key 'ppo.preset' is {preset!r}; expected gpu, cpu or test")
    env = with_added_keys(data["env"]).to_dict()
    try:
        env_cfg = conform(env, env_config(), "env.", str(path))
        ppo_cfg = conform(ppo, ppo_config(preset), "ppo.", str(path))
        check_env_config(env_cfg)
        check_ppo_config(ppo_cfg)
    except ValueError as e:
        raise ValueError(e if str(e).startswith(str(path)) else f"{path}: {e}") from None
    return env_cfg, ppo_cfg


def load_checkpoint(path: Path, obs_size: int, action_size: int, ppo_cfg):
    """Restores (normaliser, policy, value) params; raises ValueError on a corrupt or mismatched file."""
    import flax.serialization

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    template = params_template(obs_size, action_size, ppo_cfg)
    try:
        return flax.serialization.from_bytes(template, path.read_bytes())
    except Exception as e:  # msgpack and flax raise several types for a damaged file
        raise ValueError(f"checkpoint {path} is corrupt or does not match the run's networks: {e}") from e


def load_policy(run_dir: Path, checkpoint: Path | None = None, deterministic: bool = True):
    """-> (policy(obs, key) -> (action, extras), env_cfg, ppo_cfg, params) from a run directory."""
    from brax.training.agents.ppo import networks as ppo_networks

    from quadson_mjx.env import LocomotionEnv

    env_cfg, ppo_cfg = load_run_config(run_dir)
    env = LocomotionEnv(env_cfg)
    path = checkpoint or latest_checkpoint(run_dir)[0]
    params = load_checkpoint(path, env.observation_size, env.action_size, ppo_cfg)
    nets = make_networks(env.observation_size, env.action_size, ppo_cfg)
    policy = ppo_networks.make_inference_fn(nets)(params, deterministic=deterministic)
    return policy, env_cfg, ppo_cfg, params


def check_new_run_dir(run_dir: Path) -> None:
    """Raises FileExistsError when `run_dir` holds anything: a new run never writes over one."""
    run_dir = Path(run_dir)
    if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
        raise FileExistsError(
            f"run directory {run_dir} is not empty; continue it with --resume {run_dir}, or choose another --run-dir"
        )


# --- run bookkeeping --------------------------------------------------------------------------------


def versions() -> dict[str, str]:
    import brax
    import mujoco

    out = {"python": platform.python_version(), "jax": jax.__version__, "brax": brax.__version__}
    out["mujoco"] = mujoco.__version__
    out["numpy"] = np.__version__
    out["devices"] = ", ".join(d.device_kind for d in jax.devices())
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).parent, timeout=5
        )
        out["git_revision"] = rev.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        out["git_revision"] = "unknown"
    return out


def enable_compilation_cache(path: str | Path) -> Path:
    """Keeps XLA executables in `path` across processes (jax's persistent compilation cache): a
    second run of the same configuration on the same machine loads its programs instead of
    compiling them. Every program is kept, however small: the main job compiles about 90 programs
    of under 0.5 s each, about 6 s together on one H100."""
    path = Path(path).expanduser()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return path


class XlaCompilations:
    """Counts this process's XLA compilations while active, from jax.monitoring's events: `count`
    (executables jax had to build: a new function or a new shape, dtype or placement of one),
    `seconds` spent building them, and `cache_hits` (those the persistent cache served)."""

    _COMPILE = "/jax/core/compile/backend_compile_duration"
    _HIT = "/jax/compilation_cache/cache_hits"

    def __init__(self):
        self.count = 0
        self.seconds = 0.0
        self.cache_hits = 0
        self.programs: list[tuple[str, float]] = []  # (function name, seconds), in order

    def _on_duration(self, event: str, duration: float, **kwargs) -> None:
        if event == self._COMPILE:
            self.count += 1
            self.seconds += duration
            self.programs.append((str(kwargs.get("fun_name", "?")), float(duration)))

    def summary(self, top: int = 4) -> str:
        """One line: count, total seconds, the slowest programs."""
        slow = sorted(self.programs, key=lambda p: -p[1])[:top]
        names = ", ".join(f"{n} {s:.1f} s" for n, s in slow)
        small = [s for _, s in self.programs if s < 0.5]
        return (
            f"{self.count} XLA compilations, {self.seconds:.1f} s ({self.cache_hits} from the cache): {names}; "
            f"{len(small)} under 0.5 s, {sum(small):.1f} s together"
        )

    def _on_event(self, event: str, **kwargs) -> None:
        if event == self._HIT:
            self.cache_hits += 1

    def __enter__(self):
        jax.monitoring.register_event_duration_secs_listener(self._on_duration)
        jax.monitoring.register_event_listener(self._on_event)
        return self

    def __exit__(self, *exc):
        from jax._src import monitoring  # public registration has no public removal

        monitoring.unregister_event_duration_listener(self._on_duration)
        monitoring.unregister_event_listener(self._on_event)
        return False


@dataclasses.dataclass
class Progress:
    """Terminal progress: one line per evaluation with steps, steps/s, ETA and the latest reward."""

    total_steps: int
    start_step: int = 0
    stream: object = sys.stdout
    t0: float = dataclasses.field(default_factory=time.monotonic)
    last: tuple[float, int] | None = None

    def update(self, step: int, reward: float | None) -> dict[str, float]:
        now = time.monotonic()
        done = step - self.start_step
        if self.last is not None and step > self.last[1]:
            sps = (step - self.last[1]) / max(now - self.last[0], 1e-9)
        else:
            sps = float("nan")
        remaining = max(self.total_steps - step, 0)
        eta = remaining / sps if sps == sps and sps > 0 else float("nan")
        self.last = (now, step)
        width = 30
        filled = int(width * min(step / max(self.total_steps, 1), 1.0))
        bar = "#" * filled + "-" * (width - filled)
        eta_txt = f"{int(eta // 60)}m{int(eta % 60):02d}s" if eta == eta else "--"
        sps_txt = f"{sps:,.0f}" if sps == sps else "--"
        rew_txt = f"{reward:.3f}" if reward is not None else "--"
        print(
            f"[{bar}] {step:,}/{self.total_steps:,} steps | {sps_txt} steps/s | ETA {eta_txt} | "
            f"eval reward {rew_txt} | {now - self.t0:.0f}s",
            file=self.stream,
            flush=True,
        )
        return {"env_steps_per_s": sps, "steps_this_session": float(done)}


class StopRequested(KeyboardInterrupt):
    """SIGINT or SIGTERM asked a training run to stop; raised at the next safe point (see train)."""


@dataclasses.dataclass
class _Stop:
    """Signals deferred to a flag that the training loop checks at safe points."""

    signum: int | None = None

    def check(self) -> None:
        if self.signum is not None:
            raise StopRequested(f"stopped by {signal.Signals(self.signum).name}")

    def handler(self, signum, frame):
        if self.signum is not None:  # a second signal: stop now, wherever Python is
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}")
        self.signum = signum
        message = (
            f"\n{signal.Signals(signum).name}: stopping at the next safe point (after the compilation or "
            "training epoch under way; a second signal stops at once)\n"
        )
        with contextlib.suppress(OSError, ValueError):  # an unbuffered write: safe inside a handler
            os.write(sys.stderr.fileno(), message.encode())

    @contextlib.contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():
            yield  # signal handlers can only be set from the main thread
            return
        previous = {s: signal.signal(s, self.handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in previous.items():
                signal.signal(s, h)


def _free_name(run_dir: Path, stem: str, suffix: str) -> Path:
    n = 1
    while (run_dir / f"{stem}_{n}{suffix}").exists():
        n += 1
    return run_dir / f"{stem}_{n}{suffix}"


def resume_point(run_dir: Path, ppo_cfg) -> tuple[int, Path | None]:
    """-> (start step, checkpoint or None) for --resume; ValueError if the run cannot continue. A
    run stopped before its first checkpoint (or with only the step-0 one, which a fresh run
    reproduces from the seed) starts from step 0."""
    try:
        ckpt, start = latest_checkpoint(Path(run_dir))
    except FileNotFoundError:
        return 0, None
    per_epoch, epochs = epoch_steps(ppo_cfg)
    if start % per_epoch:
        raise ValueError(
            f"checkpoint {ckpt.name} is at step {start}, not at the end of a training epoch of {per_epoch} steps "
            "(written by an older resume?): it cannot be resumed exactly"
        )
    if start >= epochs * per_epoch:
        raise ValueError(f"run {run_dir} already trained {start} of {ppo_cfg.num_timesteps} steps")
    return start, (ckpt if start > 0 else None)


def _reopen_log(run_dir: Path, log_path: Path, stream):
    """Moves a resumed run's log aside (never deleted) and starts a new one holding every readable
    message, metadata record and attachment of it. -> (log, kept path, copied messages, damage)."""
    from quadson_mjx.mcap_check import read_contents, recover_messages
    from quadson_mjx.mcap_log import McapLog

    contents = read_contents(log_path)
    old = recover_messages(log_path)
    kept = _free_name(run_dir, "train.before_resume", ".mcap")
    os.replace(log_path, kept)
    log = McapLog(log_path, profile="quadson_mjx.train")
    for topic, log_time, message in old:
        log.log(topic, message, log_time)
    for m in contents.metadata:
        log.metadata(m.name, dict(m.metadata))
    for a in contents.attachments:
        log.attachment(a.name, a.data, a.media_type)
    state = (
        f"{len(contents.damaged)} damaged records: {contents.damaged[0]}" if contents.damaged else "intact"
    )
    print(
        f"resume: kept the previous log as {kept.name} ({state}); copied its {len(old)} readable messages, "
        f"{len(contents.metadata)} metadata records and {len(contents.attachments)} attachments into {log_path.name}",
        file=stream,
    )
    return log, kept, old, contents


def train(
    env_cfg,
    ppo_cfg,
    run_dir: str | Path,
    resume: bool = False,
    progress_stream=sys.stdout,
    on_eval: Callable[[int, dict], None] | None = None,
):
    """Trains with brax PPO and writes the run directory. Returns (make_policy, params, metrics).

    resume=True continues the run in `run_dir` (configs come from it) from its newest checkpoint,
    restoring brax's whole training state: parameters, normaliser, Adam's moments and step count
    (state_*.npz, written at every evaluation), the PRNG keys (derived from the seed and the epoch
    number) and, when the run stopped on a signal or Ctrl-C, the environments' states
    (env_state_*.npz). Then the resumed run's later evaluations and parameters equal those of
    an uninterrupted run (tested on the CPU, bit for bit). After a hard kill (no env_state file)
    the environments restart from the run's initial states, so the curve continues but is not
    identical; a checkpoint without a state file (older versions) restores the parameters and
    normaliser only and the moments restart. A run without a checkpoint starts over from step 0.
    The previous train.mcap is kept as train.before_resume_N.mcap; its readable contents
    (read past damaged records) start the new log.

    SIGINT and SIGTERM (Ctrl-C, a scheduler's preemption) are deferred while training: the run
    stops at the next safe point: before a training epoch or an evaluation, or after saving a
    checkpoint. A signal that arrives during an XLA compilation (tens of seconds on the first epoch
    and evaluation) or a training epoch takes effect when it ends; a second signal stops at once.
    Stopping raises StopRequested (a KeyboardInterrupt) after closing the log and saving the state.
    """
    stop = _Stop()
    with stop.installed():
        return _train(env_cfg, ppo_cfg, Path(run_dir), resume, progress_stream, on_eval, stop)


def _train(env_cfg, ppo_cfg, run_dir: Path, resume: bool, stream, on_eval, stop: _Stop):
    from brax.training.agents.ppo import train as ppo

    from quadson_mjx import compat
    from quadson_mjx.env import LocomotionEnv
    from quadson_mjx.env_config import check_env_config
    from quadson_mjx.mcap_log import McapLog
    from quadson_mjx.randomize import randomization_fn
    from quadson_mjx.wrappers import wrap_for_training

    compat.patch_brax()
    start_step, ckpt = 0, None
    if resume:
        env_cfg, ppo_cfg = load_run_config(run_dir)
        start_step, ckpt = resume_point(run_dir, ppo_cfg)
        if ckpt is None:
            print(
                f"resume: {run_dir} has no checkpoint after step 0: starting from step 0 with its configs",
                file=stream,
            )
    check_env_config(env_cfg)
    check_ppo_config(ppo_cfg)
    if not resume:
        check_new_run_dir(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)

    env = LocomotionEnv(env_cfg)
    eval_env = LocomotionEnv(env_cfg)
    per_epoch, epochs = epoch_steps(ppo_cfg)
    first_epoch = start_step // per_epoch
    state = compat.BraxTrainingState(first_epoch=first_epoch)
    restore, restored = None, "nothing (a fresh start from the seed)"
    if ckpt is not None:
        restore = load_checkpoint(ckpt, env.observation_size, env.action_size, ppo_cfg)
        restored = "parameters and normaliser only (no state file: the optimiser's moments restart)"
        if training_state_path(run_dir, start_step).exists():
            state.restore_training_state = _load_npz(training_state_path(run_dir, start_step), start_step)
            restored = "the whole training state (Adam's moments, step count, keys)"
            if env_state_path(run_dir, start_step).exists():
                state.restore_env_state = _load_npz(env_state_path(run_dir, start_step), start_step)
                restored += " and the environments"
            else:
                restored += "; the environments restart from the run's initial states"
        print(f"resume from step {start_step:,}: restoring {restored}", file=stream)
    devices = local_devices_to_use(ppo_cfg)
    state.epoch_keys = lambda epoch: compat.brax_epoch_keys(ppo_cfg.seed, epoch, devices, jax.process_index())
    vers = versions()
    config_tmp = run_dir / "config.json.tmp"
    config_tmp.write_text(
        json.dumps(
            {"env": json.loads(to_json(env_cfg)), "ppo": json.loads(to_json(ppo_cfg)), "versions": vers},
            indent=2,
        )
    )
    os.replace(config_tmp, run_dir / "config.json")

    log_path = run_dir / "train.mcap"
    old, kept, contents = [], None, None
    if resume and log_path.exists():
        log, kept, old, contents = _reopen_log(run_dir, log_path, stream)
    else:
        log = McapLog(log_path, profile="quadson_mjx.train")
    have_meta = {m.name: dict(m.metadata) for m in contents.metadata} if contents else {}
    for name, data in (
        ("env_config", {"json": to_json(env_cfg)}),
        ("ppo_config", {"json": to_json(ppo_cfg)}),
    ):
        if name not in have_meta:
            log.metadata(name, data)
    if have_meta.get("versions") != {k: str(v) for k, v in vers.items()}:
        log.metadata(
            "versions" if "versions" not in have_meta else f"versions_resume_step_{start_step}", vers
        )
    xml_name = f"{env.robot.name}.xml"
    if not (contents and any(a.name == xml_name for a in contents.attachments)):
        log.attachment(xml_name, env.robot.model_xml_text(env_cfg.terrain).encode(), "application/xml")
    event = {"event": "resume" if resume else "start", "step": start_step}
    if resume:
        event.update(restored=restored, kept_log=kept.name if kept else "", copied_messages=len(old))
        if contents is not None and contents.damaged:
            event["damaged_records"] = "; ".join(contents.damaged)[:2000]
    log.log("/train/log", event, time.time_ns())
    logged_steps = {m["progress"]["step"] for t, _, m in old if t == "/train/metrics" and "progress" in m}

    progress = Progress(total_steps=ppo_cfg.num_timesteps, start_step=start_step, stream=stream)
    compilations = XlaCompilations()
    last_metrics: dict = {}
    # brax counts steps from its TrainingState: restored (global) when the state file was, else
    # from 0 in this session; its calls before the first epoch pass step 0.
    offset = 0 if state.restore_training_state is not None else start_step
    state.checkpoint = stop.check
    saved = {"step": None, "epochs": -1}

    def global_step(step) -> int:
        return start_step if int(step) == 0 else int(step) + offset

    def progress_fn(step, metrics):
        step = global_step(step)
        reward = metrics.get("eval/episode_reward")
        extra = progress.update(step, None if reward is None else float(reward))
        record = {
            **{k: float(v) for k, v in metrics.items()},
            **{f"progress/{k}": v for k, v in extra.items()},
        }
        record["progress/step"] = step
        record["progress/xla_compiles"] = compilations.count
        record["progress/xla_compile_s"] = compilations.seconds
        record["progress/xla_cache_hits"] = compilations.cache_hits
        length = record.get("eval/avg_episode_length")
        if length:  # brax sums per-step metrics over an episode; per-step means are what one reads
            for name in ("forward_speed", "abs_roll", "abs_pitch", "ik_invalid_legs", "nan_reset", "vx_sq_err", "vy_sq_err", "yaw_rate_sq_err", "base_height", "base_below_terrain", "fall", "off_field"):  # fmt: skip
                if f"eval/episode_{name}" in record:
                    record[f"eval/mean_{name}"] = record[f"eval/episode_{name}"] / length
        if step not in logged_steps:  # a resumed run re-evaluates its checkpoint: logged already
            log.log("/train/metrics", _nest(record), time.time_ns())
            logged_steps.add(step)
        last_metrics.clear()
        last_metrics.update(record)
        if on_eval is not None:
            on_eval(step, record)
        stop.check()

    def policy_params_fn(step, make_policy, params):
        step = global_step(step)
        if state.latest is not None:  # after an epoch: the whole training state too
            _save_npz(training_state_path(run_dir, step), state.training_state_leaves(), step)
        elif step > start_step:
            raise RuntimeError(
                "compat.brax_training_state did not find brax's training epoch (brax changed?)"
            )
        if not (state.epochs_done == 0 and ckpt is not None):  # a resumed checkpoint exists already
            save_checkpoint(run_dir, step, params)
        saved.update(step=step, epochs=state.epochs_done)
        stop.check()

    remaining_epochs = epochs - first_epoch
    episode_length = ppo_cfg.episode_length or env.episode_length
    randomize = randomization_fn(env_cfg.randomization, env.base_body) if env_cfg.randomize else None
    multi_device = (
        compat.brax_multi_device(devices)
        if ppo_cfg.multi_device == "sharded_jit"
        else contextlib.nullcontext()
    )
    try:
        with (
            multi_device,
            compat.brax_evaluator_compiles_once(),
            compat.brax_training_state(state, eval_offset=first_epoch if ppo_cfg.num_evals > 1 else 0),
            compilations,
        ):
            stop.check()
            make_policy, params, _ = ppo.train(
                environment=env,
                eval_env=eval_env,
                wrap_env_fn=wrap_for_training,
                randomization_fn=randomize,
                num_timesteps=remaining_epochs * per_epoch,
                num_evals=remaining_epochs + 1 if ppo_cfg.num_evals > 1 else 1,
                num_envs=ppo_cfg.num_envs,
                num_eval_envs=ppo_cfg.num_eval_envs,
                episode_length=episode_length,
                unroll_length=ppo_cfg.unroll_length,
                batch_size=ppo_cfg.batch_size,
                num_minibatches=ppo_cfg.num_minibatches,
                num_updates_per_batch=ppo_cfg.num_updates_per_batch,
                learning_rate=ppo_cfg.learning_rate,
                entropy_cost=ppo_cfg.entropy_cost,
                discounting=ppo_cfg.discounting,
                gae_lambda=ppo_cfg.gae_lambda,
                clipping_epsilon=ppo_cfg.clipping_epsilon,
                max_grad_norm=ppo_cfg.max_grad_norm,
                reward_scaling=ppo_cfg.reward_scaling,
                normalize_observations=ppo_cfg.normalize_observations,
                network_factory=lambda obs, act, preprocess_observations_fn: make_networks(obs, act, ppo_cfg),
                seed=ppo_cfg.seed,
                progress_fn=progress_fn,
                policy_params_fn=policy_params_fn,
                restore_params=restore,
                max_devices_per_host=ppo_cfg.max_devices or None,
                deterministic_eval=ppo_cfg.deterministic_eval,
            )
    except KeyboardInterrupt as e:
        event = {"event": "interrupted", "step": saved["step"] if saved["step"] is not None else start_step}
        if state.latest is not None and saved["epochs"] == state.epochs_done:
            # stopped between epochs: the environments' states make the resume exact
            _save_npz(env_state_path(run_dir, saved["step"]), state.env_state_leaves(), saved["step"])
            event["env_state"] = env_state_path(run_dir, saved["step"]).name
        event["reason"] = str(e) or type(e).__name__
        log.log("/train/log", event, time.time_ns())
        log.close()
        raise
    except BaseException as e:  # any other failure: the log still gets its summary and says why
        event = f"failed: {type(e).__name__}: {e}"[:500]
        log.log("/train/log", {"event": event, "step": start_step}, time.time_ns())
        log.close()
        raise
    print(compilations.summary(), file=stream, flush=True)
    # brax hands the final parameters to policy_params_fn at its last evaluation: already saved.
    final_step = progress.last[1] if progress.last else ppo_cfg.num_timesteps
    log.log("/train/log", {"event": "finished", "step": final_step}, time.time_ns())
    log.close()
    return make_policy, params, last_metrics


def _nest(record: dict) -> dict:
    from quadson_mjx.mcap_log import nest_metrics

    return nest_metrics(record)
