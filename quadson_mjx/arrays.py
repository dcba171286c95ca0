"""The array namespace of numpy or JAX arrays, for code that serves both (quaternions, observations).

`namespace(*arrays)` is array_api_compat's `array_namespace` for numpy arrays and Python
sequences. JAX arrays and tracers name their namespace themselves (`__array_namespace__`, jax.numpy),
and it is taken from them directly: array_namespace builds a `jnp.empty(0)` the first time it meets
each array type, and under a trace that is a dead constant in the program being traced. The first
program of a process that used it then lowered to another module than the same program traced
later, and missed the persistent compilation cache (measured: a training's evaluation program
compiled twice in one process).
"""

from __future__ import annotations

import numpy as np
from array_api_compat import array_namespace


def namespace(*arrays):
    """The namespace of the arrays (objects with a shape; others are ignored); plain Python
    sequences and no arrays at all count as numpy. Raises TypeError for a mix of namespaces."""
    arrays = [a for a in arrays if hasattr(a, "shape")]
    if not arrays:
        return array_namespace(np.zeros(0))
    if all(hasattr(a, "__array_namespace__") and not isinstance(a, np.ndarray | np.generic) for a in arrays):
        spaces = {a.__array_namespace__() for a in arrays}
        if len(spaces) == 1:
            return spaces.pop()
    return array_namespace(*arrays)  # numpy, and the error for a mix
