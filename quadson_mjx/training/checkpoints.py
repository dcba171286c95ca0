"""Files under run_dir/checkpoints: parameter checkpoints (msgpack, the `latest` pointer), brax's
whole training state and the environments' states (npz), all written atomically (temp file + rename),
each with a SHA-256 checksum beside it (NAME.sha256, `sha256sum -c` reads it) that every load checks.

`load_checkpoint` (resume, export, rollout, the deploy export all go through it) verifies the checksum,
refuses a damaged file naming it, and refuses non-finite parameters; `verify_checkpoint` checks one
file alone. Checkpoints written before checksums existed load with a one-time notice.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

import jax
import numpy as np

from quadson_mjx.training.guards import non_finite
from quadson_mjx.training.networks import params_template

CHECKPOINT_DIR = "checkpoints"
CHECKSUM_SUFFIX = ".sha256"


class CheckpointDamaged(ValueError):
    """A checkpoint or state file whose bytes differ from its checksum (or that cannot be read)."""


def checksum_path(path: Path) -> Path:
    path = Path(path)
    return path.with_name(path.name + CHECKSUM_SUFFIX)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def checkpoint_sha256(path: Path) -> str:
    """The SHA-256 (hex) of a checkpoint file's bytes, as its checksum file records it."""
    return _sha256(Path(path))


def _replace(tmp: Path, path: Path) -> None:
    """Renames `tmp` over `path` after its bytes reach the disk, and writes the checksum file first:
    a crash leaves either the old pair, or a new checksum beside the old file (reported as damaged,
    never loaded), or the new pair."""
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    side_tmp = checksum_path(tmp)
    side_tmp.write_text(f"{_sha256(tmp)}  {path.name}\n")
    os.replace(side_tmp, checksum_path(path))
    os.replace(tmp, path)


_unverified_notice_given = False


def verify_checkpoint(path: Path) -> bool:
    """Checks `path` against its checksum file. -> True when they agree; False for a file written
    before checksums existed or copied without NAME.sha256 (a notice on stderr, once per process). Raises
    FileNotFoundError for a missing file and CheckpointDamaged naming the file when they differ."""
    global _unverified_notice_given
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    side = checksum_path(path)
    if not side.exists():
        if not _unverified_notice_given:
            _unverified_notice_given = True
            print(
                f"notice: {path} has no checksum file {side.name} (written before checksums "
                "existed, or copied without it); loaded unverified",
                file=sys.stderr,
            )
        return False
    expected = side.read_text().split()[:1]
    actual = _sha256(path)
    if expected != [actual]:
        raise CheckpointDamaged(
            f"{path} is damaged: its SHA-256 is {actual[:12]}..., its checksum file {side.name} says "
            f"{(expected or ['nothing'])[0][:12]}..."
        )
    return True


def save_checkpoint(run_dir: Path, step: int, params) -> Path:
    """Writes (normaliser, policy, value) `params` as checkpoints/step_STEP.msgpack with its checksum
    and points `latest` at it. Raises ValueError, writing nothing, when a parameter is not finite."""
    import flax.serialization

    params = jax.device_get(params)
    bad = non_finite(params)
    if bad:
        raise ValueError(f"refusing to write a checkpoint at step {step}: non-finite parameters in {bad[:3]}")
    ckpt_dir = Path(run_dir) / CHECKPOINT_DIR
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:012d}.msgpack"
    tmp = ckpt_dir / (name + ".tmp")
    tmp.write_bytes(flax.serialization.to_bytes(params))
    _replace(tmp, ckpt_dir / name)
    latest_tmp = ckpt_dir / "latest.tmp"
    latest_tmp.write_text(name)
    os.replace(latest_tmp, ckpt_dir / "latest")
    return ckpt_dir / name


def _step_of(path: Path) -> int:
    return int(path.stem.split("_")[1])


def list_checkpoints(run_dir: Path) -> list[tuple[Path, int]]:
    """-> [(path, env step)] of every parameter checkpoint in the run, oldest first."""
    found = []
    for path in (Path(run_dir) / CHECKPOINT_DIR).glob("step_*.msgpack"):
        try:
            found.append((path, _step_of(path)))
        except (IndexError, ValueError):
            continue  # not a name this module writes
    return sorted(found, key=lambda p: p[1])


def latest_checkpoint(run_dir: Path) -> tuple[Path, int]:
    """-> (path, env step) of the newest checkpoint: the one `latest` names, or, when `latest` is
    missing or names a file that is gone, the checkpoint of the highest step. Raises
    FileNotFoundError when the run has none."""
    ckpt_dir = Path(run_dir) / CHECKPOINT_DIR
    pointer = ckpt_dir / "latest"
    if pointer.exists():
        path = ckpt_dir / pointer.read_text().strip()
        if path.is_file() and path.name.startswith("step_"):
            return path, _step_of(path)
    found = list_checkpoints(run_dir)
    if not found:
        raise FileNotFoundError(f"no checkpoint in {run_dir}: {ckpt_dir} holds no step_*.msgpack")
    return found[-1]


def newest_good_checkpoint(run_dir: Path, skipped: list[str] | None = None) -> tuple[Path, int]:
    """-> (path, env step) of the newest checkpoint whose checksum holds (or that has none: older
    runs). Each damaged one passed over is described in `skipped`. FileNotFoundError if none is good."""
    for path, step in reversed(list_checkpoints(run_dir)):
        try:
            verify_checkpoint(path)
        except (CheckpointDamaged, OSError) as e:
            if skipped is not None:
                skipped.append(str(e))
            continue
        return path, step
    raise FileNotFoundError(f"no intact checkpoint in {run_dir}")


def load_checkpoint(path: Path, obs_size: int, action_size: int, ppo_cfg):
    """Restores (normaliser, policy, value) params after checking the file's checksum. Raises
    FileNotFoundError for a missing file, CheckpointDamaged (a ValueError) naming a damaged one,
    ValueError for one that does not match the run's networks or holds non-finite parameters."""
    import flax.serialization

    path = Path(path)
    verify_checkpoint(path)
    template = params_template(obs_size, action_size, ppo_cfg)
    try:
        params = flax.serialization.from_bytes(template, path.read_bytes())
    except Exception as e:  # msgpack and flax raise several types for a damaged file
        raise ValueError(f"checkpoint {path} is corrupt or does not match the run's networks: {e}") from e
    bad = non_finite(params)
    if bad:
        raise ValueError(f"checkpoint {path} holds non-finite parameters ({bad[:3]}): not usable")
    return params


def _save_npz(path: Path, leaves: list[np.ndarray], step: int) -> None:
    """Arrays to `path` atomically (temp file + rename) with a checksum, and the env step they belong to."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.savez(f, step=np.int64(step), **{f"leaf_{i:05d}": leaf for i, leaf in enumerate(leaves)})
    _replace(tmp, path)


# what each kind of state file holds, and what resuming without it does
_NPZ_KINDS = {
    "training": (
        "training state",
        "move it away to resume with the parameters only (the optimiser's moments restart)",
    ),
    "env": (
        "environment state",
        "move it away to resume with the environments restarting from the run's initial states",
    ),
}


def _load_npz(path: Path, step: int, kind: str = "training") -> list[np.ndarray]:
    """The arrays of a state file written by _save_npz, checked against its checksum and step.
    kind: "training" (state_*.npz) or "env" (env_state_*.npz), for the message of a damaged file."""
    what, advice = _NPZ_KINDS[kind]
    try:
        verify_checkpoint(path)
        with np.load(path, allow_pickle=False) as data:
            if int(data["step"]) != step:
                raise ValueError(f"it holds step {int(data['step'])}, not {step}")
            names = sorted(k for k in data.files if k.startswith("leaf_"))
            return [data[k] for k in names]
    except Exception as e:  # zipfile, numpy and our own checks raise several types
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(
            f"{what} {path} is corrupt or does not belong to its checkpoint ({reason}); {advice}"
        ) from e


def training_state_path(run_dir: Path, step: int) -> Path:
    """brax's whole TrainingState (params, normaliser, Adam's moments, step count) at `step`,
    written at every evaluation next to the parameter checkpoint."""
    return Path(run_dir) / CHECKPOINT_DIR / f"state_{step:012d}.npz"


def env_state_path(run_dir: Path, step: int) -> Path:
    """The batched environment states at `step`, written when a run stops on a signal or Ctrl-C
    (about 57 kB per environment: 0.47 GB for the gpu preset's 8192, so not at every evaluation)."""
    return Path(run_dir) / CHECKPOINT_DIR / f"env_state_{step:012d}.npz"
