"""Run provenance: the versions of Python, jax, brax, MuJoCo and numpy, the devices, jax's default
float32 matmul precision and the git revision, saved beside every checkpoint and inside every MCAP
file. Imports nothing of the project."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

import jax
import numpy as np


def versions(source: Path | None = None) -> dict[str, str]:
    """The versions of this process's libraries and devices, and of the source tree `source` (default:
    this package's folder): git_revision, its HEAD (or "unknown"), and git_tree, "clean" when no
    tracked file differs from HEAD, "modified" when one does (a run from edited code, or a copy of
    a checkout whose .git is not the tree's own), "unknown" outside git."""
    import brax
    import mujoco

    out = {"python": platform.python_version(), "jax": jax.__version__, "brax": brax.__version__}
    out["mujoco"] = mujoco.__version__
    out["numpy"] = np.__version__
    out["devices"] = ", ".join(d.device_kind for d in jax.devices())
    # "default" lets an NVIDIA GPU since Ampere multiply float32 matrices in TF32, MJX's physics
    # included; JAX_DEFAULT_MATMUL_PRECISION=highest keeps them float32, as on the CPU
    out["matmul_precision"] = str(jax.config.jax_default_matmul_precision or "default")
    out["git_revision"], out["git_tree"] = "unknown", "unknown"
    cwd = Path(__file__).parent if source is None else source

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=cwd, timeout=10)

    try:
        rev = git("rev-parse", "HEAD")
        if rev.returncode == 0 and rev.stdout.strip():
            out["git_revision"] = rev.stdout.strip()
            status = git("status", "--porcelain", "--untracked-files=no")
            if status.returncode == 0:
                out["git_tree"] = "modified" if status.stdout.strip() else "clean"
    except (OSError, subprocess.SubprocessError):
        pass
    return out
