"""How many contacts MJX makes between a sphere (a foot) and a height field: the env key
`hfield_foot_contacts`.

MJX's JAX collider for a sphere on a height field tests the sphere against the prisms of the grid
cells under it and keeps up to four of their contact points (a contact manifold), so each foot on
the stone field or the tiles carries four contacts and 16 constraint rows instead of one contact
and four rows on a plane. `deepest_sphere_contact` keeps only the deepest of those points, with
its own normal, as a sphere on a plane has. On one NVIDIA H200 at 32768 worlds it steps the stone
field 1.23x faster (benchmarks/physics_vs_go1.py, docs/benchmarks.md).

MJX looks its colliders up in one table by geom types, when a model's data is made and when a
step is traced, and the table is the process's. `sphere_contacts(n)` swaps the entry for the
length of a `with` block and restores what was there; the environment makes its data and traces
its physics steps inside it, so two environments with different settings live in one process.
A data made under one setting and stepped under the other fails at trace time on its contact
arrays' shapes, never silently. Only MJX's JAX implementation is covered (Warp has its own
colliders).
"""

from __future__ import annotations

import contextlib

import jax.numpy as jnp
from mujoco.mjx._src import collision_convex, collision_driver
from mujoco.mjx._src import math as mjx_math
from mujoco.mjx._src.types import GeomType

# The values of env.hfield_foot_contacts: MJX's own collider, and the deepest point alone.
CHOICES = (4, 1)
_PAIR = (GeomType.HFIELD, GeomType.SPHERE)
_MJX_OWN = collision_driver._COLLISION_FUNC[_PAIR]


@collision_convex.collider(ncon=1)
def deepest_sphere_contact(h, s, subgrid_size):
    """The deepest of the contacts of MJX's height-field/sphere collision (distance, position and
    frame in the world frame), before MJX's selection of up to four."""
    dist, pos, n = collision_convex._hfield_collision(
        collision_convex._sphere_convex, h, s, jnp.max(s.size), subgrid_size
    )
    i = jnp.argmin(dist)
    return dist[i], h.mat @ pos[i] + h.pos, mjx_math.make_frame(h.mat @ n[i])


@contextlib.contextmanager
def sphere_contacts(n: int):
    """Within the block MJX collides spheres with height fields into n contacts (CHOICES: 4, its
    own collider; 1, the deepest point); the table entry found on entry is restored on exit."""
    if n not in CHOICES:
        raise ValueError(f"hfield_foot_contacts must be one of {CHOICES}, got {n!r}")
    table = collision_driver._COLLISION_FUNC
    before = table[_PAIR]
    table[_PAIR] = _MJX_OWN if n == 4 else deepest_sphere_contact
    try:
        yield
    finally:
        table[_PAIR] = before
