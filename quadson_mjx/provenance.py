"""Run provenance: the versions of Python, jax, brax, MuJoCo and numpy, the devices and the git revision,
saved beside every checkpoint and inside every MCAP file. Imports nothing of the project."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

import jax
import numpy as np


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
