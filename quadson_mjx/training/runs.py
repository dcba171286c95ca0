"""A run directory as a whole: its configs (config.json, keys added since filled in), whether a new
run may start in it, where a resume starts, the resumed run's log, and its trained policy."""

from __future__ import annotations

import json
import os
from pathlib import Path

import ml_collections

from quadson_mjx.training.checkpoints import latest_checkpoint, load_checkpoint
from quadson_mjx.training.networks import make_networks
from quadson_mjx.training.presets import PPO_KEYS_ADDED, check_ppo_config, epoch_steps, ppo_config


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


def check_new_run_dir(run_dir: Path) -> None:
    """Raises FileExistsError when `run_dir` holds anything: a new run never writes over one."""
    run_dir = Path(run_dir)
    if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
        raise FileExistsError(
            f"run directory {run_dir} is not empty; continue it with --resume {run_dir}, or choose another --run-dir"
        )


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
