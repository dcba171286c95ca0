"""How many contacts MJX makes between a sphere (a foot) and a height field: the env key
`hfield_foot_contacts`.

MJX's JAX collider for a sphere on a height field tests the sphere against the prisms of the grid
cells under it and keeps up to four of their contact points (a contact manifold), so each foot on
the stone field or the tiles carries four contacts and 16 constraint rows instead of one contact
and four rows on a plane. Its prism test also goes wrong beside a cell whose top is above the
sphere's centre (on a slope or at a step): the sphere then meets the prism's side, a face inside
the ground, and MJX reports a contact up to 3 cm deep with a nearly horizontal normal where MuJoCo
C's height-field collision finds the surface (for 2 % of random sphere positions touching the
tiled ground).

`surface_sphere_contact` makes one contact a foot, as on a plane: the nearest point of the surface
(the two triangles of each cell under the sphere, MuJoCo's split), with the distance signed by
whether the centre is above or below the surface. Where the centre is above the surface this is
MuJoCo C's deepest contact (tests/test_hfield_contact.py: within 1e-6 m on the stones and the
tiles); on the CPU it takes a third of the time of MJX's prism tests.

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

from quadson_mjx.terrain import cell_height

# The values of env.hfield_foot_contacts: MJX's own collider, and one contact on the surface.
CHOICES = (4, 1)
_PAIR = (GeomType.HFIELD, GeomType.SPHERE)
_MJX_OWN = collision_driver._COLLISION_FUNC[_PAIR]


def _closest_on_triangles(p, a, b, c):
    """The closest point to p on each triangle (a[i], b[i], c[i]): the projection onto its plane
    where that falls inside it, else the nearest point of its three edges."""
    n = jnp.cross(b - a, c - a)
    nn = jnp.sum(n * n, axis=-1, keepdims=True)
    proj = p - n * jnp.sum((p - a) * n, axis=-1, keepdims=True) / nn
    # inside: the projection is on the inner side of every edge
    inside = jnp.all(
        jnp.stack(
            [jnp.sum(jnp.cross(v1 - v0, proj - v0) * n, axis=-1) >= 0 for v0, v1 in ((a, b), (b, c), (c, a))]
        ),
        axis=0,
    )

    def on_edge(v0, v1):
        e = v1 - v0
        t = jnp.clip(
            jnp.sum((p - v0) * e, axis=-1, keepdims=True) / jnp.sum(e * e, axis=-1, keepdims=True), 0, 1
        )
        return v0 + t * e

    edges = jnp.stack([on_edge(a, b), on_edge(b, c), on_edge(c, a)])  # (3, T, 3)
    k = jnp.argmin(jnp.sum((edges - p) ** 2, axis=-1), axis=0)
    nearest_edge = jnp.take_along_axis(edges, k[None, :, None], axis=0)[0]
    return jnp.where(inside[:, None], proj, nearest_edge)


def nearest_on_surface(h, s, subgrid_size):
    """The sphere's contact with the height field's surface: the nearest point of the triangles
    of the cells under it (MJX's and MuJoCo's split of each cell into two), the distance signed by
    whether the centre is above or below the surface there; position and frame in the world frame.
    Where the centre is above the surface this is MuJoCo C's deepest contact; below it, the
    sphere is pushed out through the surface, not through the side of a prism."""
    c = h.mat.T @ (s.pos - h.pos)
    r = s.size[0]
    dx = 2.0 * h.size[0] / (h.ncol - 1)
    dy = 2.0 * h.size[1] / (h.nrow - 1)
    # the first cell of the subgrid under the sphere, as MJX finds it
    c0 = jnp.clip(jnp.floor((c[0] - r + h.size[0]) / dx), -(h.ncol - 1), h.ncol - 1).astype(int)
    r0 = jnp.clip(jnp.floor((c[1] - r + h.size[1]) / dy), -(h.nrow - 1), h.nrow - 1).astype(int)
    nx, ny = subgrid_size
    ci = jnp.clip(c0 + jnp.arange(nx), 0, h.ncol - 2)  # (nx,)
    ri = jnp.clip(r0 + jnp.arange(ny), 0, h.nrow - 2)  # (ny,)
    ci, ri = jnp.meshgrid(ci, ri, indexing="ij")
    ci, ri = ci.ravel(), ri.ravel()

    def vertex(i, j):
        return jnp.stack([dx * i - h.size[0], dy * j - h.size[1], h.data[i, j] * h.size[2]], axis=-1)

    p00, p10 = vertex(ci, ri), vertex(ci + 1, ri)
    p01, p11 = vertex(ci, ri + 1), vertex(ci + 1, ri + 1)
    a = jnp.concatenate([p00, p00])
    b = jnp.concatenate([p11, p10])
    t = jnp.concatenate([p01, p11])
    q = _closest_on_triangles(c, a, b, t)
    d2 = jnp.sum((c - q) ** 2, axis=-1)
    i = jnp.argmin(d2)
    gap = jnp.sqrt(jnp.maximum(d2[i], 1e-18))
    # above or below: the height of the surface under the centre (the triangle containing it)
    cc = jnp.clip(jnp.floor((c[0] + h.size[0]) / dx), 0, h.ncol - 2).astype(int)
    rc = jnp.clip(jnp.floor((c[1] + h.size[1]) / dy), 0, h.nrow - 2).astype(int)
    u = (c[0] + h.size[0]) / dx - cc
    v = (c[1] + h.size[1]) / dy - rc
    z = cell_height(h.data[cc, rc], h.data[cc + 1, rc], h.data[cc, rc + 1], h.data[cc + 1, rc + 1], u, v)
    sign = jnp.where(c[2] >= z * h.size[2], 1.0, -1.0)
    # the normal from the surface to the sphere; straight up the triangle's face where the centre
    # lies on the surface itself
    face = jnp.cross(b[i] - a[i], t[i] - a[i])
    face = face / jnp.linalg.norm(face)
    n = jnp.where(d2[i] > 1e-18, sign * (c - q[i]) / gap, face)
    dist = sign * gap - r
    pos = q[i] + n * (0.5 * dist)
    return dist, h.mat @ pos + h.pos, mjx_math.make_frame(h.mat @ n)


surface_sphere_contact = collision_convex.collider(ncon=1)(nearest_on_surface)


@contextlib.contextmanager
def sphere_contacts(n: int):
    """Within the block MJX collides spheres with height fields into n contacts (CHOICES: 4, its
    own collider; 1, the nearest point of the surface); the table entry found on entry is
    restored on exit."""
    if n not in CHOICES:
        raise ValueError(f"hfield_foot_contacts must be one of {CHOICES}, got {n!r}")
    table = collision_driver._COLLISION_FUNC
    before = table[_PAIR]
    table[_PAIR] = _MJX_OWN if n == 4 else surface_sphere_contact
    try:
        yield
    finally:
        table[_PAIR] = before
