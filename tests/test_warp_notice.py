"""mujoco.mjx prints "Failed to import warp" at import when warp-lang is missing; the project shows it
only to a user who asks for the warp backend (quadson_mjx.warp_notice)."""

import subprocess
import sys

import pytest


def _imports_quietly(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    )


def test_importing_the_environment_prints_nothing():
    res = _imports_quietly("import quadson_mjx.env, brax.envs, mujoco.mjx")
    assert "warp" not in res.stdout + res.stderr


def test_the_notice_is_kept_and_given_to_who_asks_for_warp():
    """Without warp-lang (its import blocked in a fresh interpreter), asking for the warp backend
    is one ValueError that names it, from the model and from the environment."""
    code = (
        "import sys; sys.modules['warp'] = None\n"
        "from quadson_mjx import warp_notice\n"
        "import mujoco.mjx\n"
        "from quadson_mjx.env_model import put_model, check_env_impl\n"
        "from quadson_mjx.env import LocomotionEnv\n"
        "from quadson_mjx.config import apply_overrides\n"
        "from quadson_mjx.env_config import env_config\n"
        "assert warp_notice.MODULE in sys.modules\n"
        "for call in (lambda: put_model(None, 'warp'), lambda: LocomotionEnv(apply_overrides(env_config(), ['impl=warp']))):\n"
        "    try:\n"
        "        call()\n"
        "    except ValueError as e:\n"
        "        print(e)\n"
    )
    res = _imports_quietly(code)
    lines = res.stdout.strip().splitlines()
    assert len(lines) == 2
    for line in lines:
        assert line.startswith("env.impl='warp' needs warp-lang") and line.endswith("or use env.impl=jax")


def test_the_hook_leaves_other_imports_alone():
    res = _imports_quietly(
        "import quadson_mjx, json, sys; print(sum(type(f).__name__ == '_Finder' for f in sys.meta_path))"
    )
    assert res.stdout.strip() == "1"


def test_an_unknown_implementation_is_one_error():
    from quadson_mjx.env_model import check_env_impl

    with pytest.raises(ValueError, match=r"^env.impl is 'cuda'; choose from \['jax', 'warp'\]$"):
        check_env_impl("cuda")
