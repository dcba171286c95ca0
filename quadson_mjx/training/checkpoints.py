"""Files under run_dir/checkpoints: parameter checkpoints (msgpack, the `latest` pointer), brax's
whole training state and the environments' states (npz), all written atomically (temp file + rename)."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np

from quadson_mjx.training.networks import params_template

CHECKPOINT_DIR = "checkpoints"


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
