"""Compatibility shims for the pinned toolchain. Each one names the upstream issue it works around,
so it can be deleted once the upstream fix is released.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def _device_put_replicated(x, devices):
    """Drop-in for the removed `jax.device_put_replicated` (JAX's pmap migration guide).

    Stacks every leaf of the pytree `x` once per device, giving a leading axis of len(devices), and
    places shard i on devices[i] through a NamedSharding over a 1-D mesh: exactly the layout that
    `jax.pmap` expects of its inputs.
    """
    devices = list(devices)
    sharding = NamedSharding(Mesh(np.array(devices), ("devices",)), PartitionSpec("devices"))

    def put(leaf):
        stacked = np.broadcast_to(np.asarray(leaf), (len(devices), *np.shape(leaf)))
        return jax.device_put(stacked, sharding)

    return jax.tree.map(put, x)


def patch_brax() -> bool:
    """Make brax PPO run on jax >= 0.10, which removed `jax.device_put_replicated`.

    brax 0.14.2's `ppo.train` still calls it (google/brax issue #671). The replacement is installed
    only when the attribute is missing, so a jax that still has it is left alone. Returns True when
    the shim was installed.
    """
    if hasattr(jax, "device_put_replicated"):  # jax < 0.10 still has it (hasattr is False on the
        return False  # deprecation AttributeError that newer jax raises)
    jax.device_put_replicated = _device_put_replicated
    return True
