"""Shared pytest fixtures: run a test in float32 and float64 without enabling x64 globally."""

from __future__ import annotations

import jax
import numpy as np
import pytest


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def float_dtype(request):
    """The test's float dtype; x64 is on only inside float64 tests (jax.enable_x64 context)."""
    with jax.enable_x64(request.param == np.float64):
        yield request.param


def pytest_configure(config):
    """A persistent XLA compilation cache for the test session: the training tests compile the same
    PPO step twice (a run and its resume), and a re-run of the suite compiles nothing it has seen."""
    cache = config.rootpath / ".pytest_cache" / "jax_compilation"
    cache.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
