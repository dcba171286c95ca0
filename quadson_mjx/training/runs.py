"""A run directory as a whole: its configs (config.json, keys added since filled in), whether a new
run may start in it, where a resume starts, the resumed run's log, and its trained policy."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
from pathlib import Path

import ml_collections

from quadson_mjx.config import apply_overrides
from quadson_mjx.errors import UsageError
from quadson_mjx.training.checkpoints import (
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    verify_checkpoint,
)
from quadson_mjx.training.networks import make_networks
from quadson_mjx.training.presets import PPO_KEYS_ADDED, PRESETS, check_ppo_config, epoch_steps, ppo_config

LOCK_NAME = ".lock"  # run_dir/.lock: flock'ed by the process training in the directory, holds its pid


class RunDirInUse(UsageError):
    """Another process (a trainer or a resume) holds the run directory's lock."""


def load_run_config(
    run_dir: Path, for_evaluation: bool = False
) -> tuple[ml_collections.ConfigDict, ml_collections.ConfigDict]:
    """-> (env_cfg, ppo_cfg) of a run directory, with keys added since the run filled in
    (PPO_KEYS_ADDED, env_config.ENV_KEYS_ADDED). A damaged or incomplete config.json, a key this version does
    not know, a missing key, a value of the wrong type or out of range is a ValueError naming the
    file and the key. for_evaluation: env_cfg on MJX's JAX implementation even for a run trained on
    Warp (env.impl="warp"), so that every evaluation and export steps the same physics code and
    model (no Warp contact sensors, buffers or warp-lang), at any batch size."""
    from quadson_mjx.config import conform
    from quadson_mjx.env_config import check_env_config, env_config, with_added_keys

    path = Path(run_dir) / "config.json"
    if not path.exists():
        raise FileNotFoundError(f"{run_dir} is not a run directory: {path} does not exist")
    copy = "a copy of both configs is in the run's train.mcap (metadata env_config and ppo_config)"
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise ValueError(f"{path} is not valid JSON ({e}): the file is damaged; {copy}") from None
    if (
        not isinstance(data, dict)
        or not isinstance(data.get("env"), dict)
        or not isinstance(data.get("ppo"), dict)
    ):
        raise ValueError(f"{path} lacks its 'env' or 'ppo' section: the file is incomplete; {copy}")
    ppo = {**PPO_KEYS_ADDED, **data["ppo"]}
    preset = ppo.get("preset", "gpu")
    if not isinstance(preset, str) or preset not in PRESETS:
        raise ValueError(f"{path}: config key 'ppo.preset' is {preset!r}; expected gpu, cpu or test")
    try:
        env = with_added_keys(data["env"]).to_dict()
        env_cfg = conform(env, env_config(), "env.", str(path))
        ppo_cfg = conform(ppo, ppo_config(preset), "ppo.", str(path))
        check_env_config(env_cfg)
        check_ppo_config(ppo_cfg)
    except (ValueError, TypeError, AttributeError, KeyError) as e:  # any shape a hand edit leaves
        text = str(e) if isinstance(e, ValueError) else f"damaged or hand-edited ({type(e).__name__}: {e})"
        raise ValueError(text if text.startswith(str(path)) else f"{path}: {text}") from None
    if for_evaluation and env_cfg.impl != "jax":
        env_cfg = apply_overrides(env_cfg, ["impl=jax"])
    return env_cfg, ppo_cfg


def check_writable_dir(run_dir: Path) -> None:
    """Raises UsageError now, before a run starts, when `run_dir` could not be created or written:
    a path component that is a file, or a read-only folder."""
    run_dir = Path(run_dir)
    probe = run_dir
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise UsageError(
            f"run directory {run_dir}: {probe} is a file, not a folder; choose another --run-dir"
        )
    if not os.access(probe, os.W_OK | os.X_OK):
        raise UsageError(
            f"run directory {run_dir}: {probe} is not writable (read-only?); choose a writable --run-dir"
        )


def lock_holder(run_dir: Path) -> int | None:
    """-> the pid of the process holding `run_dir`'s lock (0 if it has not written its pid yet), or
    None when no process holds it."""
    path = Path(run_dir) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            text = os.pread(fd, 32, 0).decode(errors="replace").strip()
            return int(text) if text.isdigit() else 0
        return None
    finally:
        os.close(fd)


def _in_use(run_dir: Path, pid: int) -> RunDirInUse:
    who = f"process {pid}" if pid else "another process"
    return RunDirInUse(
        f"run directory {run_dir} is in use by {who} (a trainer or --resume holds {Path(run_dir) / LOCK_NAME}); "
        "wait for it to end, or choose another --run-dir"
    )


@contextlib.contextmanager
def run_dir_lock(run_dir: Path):
    """Holds an exclusive lock on `run_dir` (flock on run_dir/.lock, which holds this pid) while
    active: one trainer or resume at a time. Raises RunDirInUse naming the holder's pid. The kernel
    releases the lock when the process ends, however it ends; the file stays (empty) behind."""
    path = Path(run_dir) / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise
        raise _in_use(run_dir, lock_holder(run_dir) or 0) from None
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)


def check_new_run_dir(run_dir: Path) -> None:
    """Raises FileExistsError when `run_dir` holds anything (its lock file aside): a new run never
    writes over one; RunDirInUse when a process holds it; UsageError when it cannot be written."""
    run_dir = Path(run_dir)
    pid = lock_holder(run_dir) if run_dir.is_dir() else None
    if pid is not None:
        raise _in_use(run_dir, pid)
    if run_dir.exists() and (not run_dir.is_dir() or any(p.name != LOCK_NAME for p in run_dir.iterdir())):
        raise FileExistsError(
            f"run directory {run_dir} is not empty; continue it with --resume {run_dir}, or choose another --run-dir"
        )
    check_writable_dir(run_dir)


def resume_point(run_dir: Path, ppo_cfg, notes: list[str] | None = None) -> tuple[int, Path | None]:
    """-> (start step, checkpoint or None) for --resume; ValueError if the run cannot continue. The
    checkpoint is the newest intact one (its checksum holds): the one `latest` names, else (no
    `latest`, or a damaged file) the newest before it; `notes` gets a line for each passed over. A
    run stopped before its first checkpoint (or with only the step-0 one, which a fresh run
    reproduces from the seed) starts from step 0."""
    notes = [] if notes is None else notes
    try:
        ckpt, start = latest_checkpoint(Path(run_dir))
    except FileNotFoundError:
        return 0, None
    if not (Path(run_dir) / "checkpoints" / "latest").exists():
        notes.append(f"{run_dir} has no checkpoints/latest: resuming from its newest checkpoint")
    try:
        verify_checkpoint(ckpt)
    except ValueError as e:
        notes.append(f"{e}; resuming from the newest intact checkpoint before it")
        for path, step in reversed([c for c in list_checkpoints(run_dir) if c[1] < start]):
            try:
                verify_checkpoint(path)
            except ValueError as damaged:
                notes.append(str(damaged))
                continue
            ckpt, start = path, step
            break
        else:
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


def init_point(source: Path) -> tuple[Path, Path, int]:
    """-> (source run directory, checkpoint, its step) for --init-from: `source` is a run directory
    (its newest intact checkpoint) or one of its checkpoint files (checkpoints/step_*.msgpack).
    FileNotFoundError for a missing run or checkpoint, CheckpointDamaged for a damaged file."""
    from quadson_mjx.training.checkpoints import _step_of, newest_good_checkpoint

    source = Path(source)
    if source.is_file():
        if not (source.name.startswith("step_") and source.suffix == ".msgpack"):
            raise ValueError(f"{source} is neither a run directory nor a checkpoints/step_*.msgpack file")
        verify_checkpoint(source)
        return source.parent.parent, source, _step_of(source)
    if not (source / "config.json").exists():
        raise FileNotFoundError(f"{source} is not a run directory (no config.json) nor a checkpoint file")
    ckpt, step = newest_good_checkpoint(source)
    return source, ckpt, step


def source_curriculum_line(source: Path, tiles) -> str | None:
    """For --init-from on the tiled ground: one line with the mean curriculum level per tile type
    of the source run's robots at its last logged evaluation (its train.mcap's curriculum/ metrics)
    and the levels this run starts its robots at (tiles: the new env config's `tiles`); None when
    the source logged no curriculum. A fine-tune whose robots restart far below where the source's
    ended trains on easier ground than it will be asked to walk (docs/results.md, a calibrated IMU)."""
    from quadson_mjx.mcap_check import read_messages

    log = Path(source) / "train.mcap"
    if not log.is_file():
        return None
    ended = {}
    for _, _, m in read_messages(log, topics=("/train/metrics",)):
        levels = {
            k[: -len("_level_mean")]: v
            for k, v in m.get("curriculum", {}).items()
            if k.endswith("_level_mean")
        }
        ended = levels or ended
    if not ended:
        return None
    means = ", ".join(f"{t} {v:.1f}" for t, v in ended.items())
    return (
        f"curriculum: the source's robots ended at mean levels {means}; this run starts its robots at "
        f"levels {tiles.min_init_level}-{tiles.max_init_level} (env.tiles.min_init_level, max_init_level)"
    )


def _free_name(run_dir: Path, stem: str, suffix: str) -> Path:
    n = 1
    while (run_dir / f"{stem}_{n}{suffix}").exists():
        n += 1
    return run_dir / f"{stem}_{n}{suffix}"


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


def load_policy(run_dir: Path, checkpoint: Path | None = None, deterministic: bool = True):
    """-> (policy(obs, key) -> (action, extras), env_cfg, ppo_cfg, params) from a run directory, for
    an evaluation: env_cfg is the run's on MJX's JAX implementation even when it trained on Warp
    (load_run_config's for_evaluation), so every evaluation steps the same physics code and reads
    its per-world contact list (rollouts' foot forces), at any batch size."""
    from brax.training.agents.ppo import networks as ppo_networks

    from quadson_mjx.envs import make_env

    env_cfg, ppo_cfg = load_run_config(run_dir, for_evaluation=True)
    env = make_env(env_cfg)
    path = checkpoint or latest_checkpoint(run_dir)[0]
    params = load_checkpoint(path, env.observation_size, env.action_size, ppo_cfg)
    nets = make_networks(env.observation_size, env.action_size, ppo_cfg)
    policy = ppo_networks.make_inference_fn(nets)(params, deterministic=deterministic)
    return policy, env_cfg, ppo_cfg, params
