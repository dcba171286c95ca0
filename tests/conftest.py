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
