"""mujoco.mjx prints "Failed to import warp" at import when warp-lang is missing; the project shows it
only to a user who asks for the warp backend (quadson_mjx.warp_notice)."""

import subprocess
import sys

import pytest

from quadson_mjx import warp_notice
from quadson_mjx.env_config import env_config
from quadson_mjx.env_model import put_model


def _imports_quietly(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=300
    )


def test_importing_the_environment_prints_nothing():
    res = _imports_quietly("import quadson_mjx.env, brax.envs, mujoco.mjx")
    assert "warp" not in res.stdout + res.stderr


def test_the_notice_is_kept_and_given_to_who_asks_for_warp():
    try:
        import warp  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("warp-lang is installed here: there is no notice to give")
    import mujoco.mjx  # noqa: F401

    cfg = env_config()
    cfg.impl = "warp"
    with pytest.raises(ValueError, match=r"env.impl='warp' needs warp-lang.*use env.impl=jax"):
        put_model(None, cfg.impl)
    assert warp_notice.MODULE in sys.modules


def test_the_hook_leaves_other_imports_alone():
    res = _imports_quietly(
        "import quadson_mjx, json, sys; print(sum(type(f).__name__ == '_Finder' for f in sys.meta_path))"
    )
    assert res.stdout.strip() == "1"


def test_the_environment_refuses_warp_with_a_clear_error():
    """Its reset and foot contacts use the JAX implementation's data layout (env_model.check_env_impl)."""
    from quadson_mjx.env import LocomotionEnv

    cfg = env_config()
    cfg.impl = "warp"
    with pytest.raises(
        ValueError, match=r"env.impl='warp': the environments run on MJX's JAX implementation only"
    ):
        LocomotionEnv(cfg)
