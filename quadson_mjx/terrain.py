"""Ground height under a point, in JAX: the rough scene's height field as MuJoCo builds its surface.

MuJoCo triangulates every height-field cell (c, r) .. (c + 1, r + 1) along the diagonal from its
corner (c, r) to (c + 1, r + 1) and casts rays (`mj_ray`) and collides against those triangles; the
height here is the same piecewise-linear surface (bilinear interpolation over a cell differs from
it by up to 10 mm on the stone field, measured against `mujoco.mj_rayHfield`). Heights are
`hfield_data * size_z` above the floor geom's origin; rows run along y, columns along x.

Off the field there is no ground at all: `on_field` says where the field is, and the height there is
the nearest border cell's (clamped, finite).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

FLOOR_GEOM = "floor"


class Heightfield(NamedTuple):
    """heights: (nrow, ncol) [m] above `origin`; half_size: (2,) x, y half extents [m];
    origin: (3,) world position of the field's centre [m] (the floor geom's pos)."""

    heights: jnp.ndarray
    half_size: jnp.ndarray
    origin: jnp.ndarray


def heightfield(mj_model: mujoco.MjModel) -> Heightfield | None:
    """The floor's height field, or None when the floor is a plane (ground at the plane's z)."""
    geom = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, FLOOR_GEOM)
    if geom < 0:
        raise ValueError(f"the model has no geom named {FLOOR_GEOM!r}")
    if mj_model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_HFIELD:
        return None
    if not np.allclose(mj_model.geom_quat[geom], (1, 0, 0, 0)):
        raise ValueError("the height field geom must not be rotated")
    h = int(mj_model.geom_dataid[geom])
    nrow, ncol = int(mj_model.hfield_nrow[h]), int(mj_model.hfield_ncol[h])
    adr = int(mj_model.hfield_adr[h])
    size = mj_model.hfield_size[h]
    data = np.asarray(mj_model.hfield_data[adr : adr + nrow * ncol]).reshape(nrow, ncol)
    # converted on the host: jnp.asarray would compile a device program for each (measured on CPU)
    return Heightfield(
        heights=jax.device_put(np.asarray(data * size[2], np.float32)),
        half_size=jax.device_put(np.asarray(size[:2], np.float32)),
        origin=jax.device_put(np.asarray(mj_model.geom_pos[geom], np.float32)),
    )


def ground_height(field: Heightfield | None, xy: jnp.ndarray) -> jnp.ndarray:
    """xy: (..., 2) world x, y [m] -> (...,) ground height z [m]; 0 for the flat scene (its plane is
    at z = 0). Off the field the nearest border height (see `on_field`)."""
    xy = jnp.asarray(xy)
    if field is None:
        return jnp.zeros(xy.shape[:-1], xy.dtype)
    nrow, ncol = field.heights.shape
    local = xy - field.origin[:2]
    # grid coordinates: u along columns (x), v along rows (y), cell size 2 * half / (n - 1)
    u = (local[..., 0] + field.half_size[0]) * ((ncol - 1) / (2.0 * field.half_size[0]))
    v = (local[..., 1] + field.half_size[1]) * ((nrow - 1) / (2.0 * field.half_size[1]))
    u = jnp.clip(u, 0.0, ncol - 1.0)
    v = jnp.clip(v, 0.0, nrow - 1.0)
    c = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, ncol - 2)
    r = jnp.clip(jnp.floor(v).astype(jnp.int32), 0, nrow - 2)
    h = field.heights
    return field.origin[2] + cell_height(h[r, c], h[r, c + 1], h[r + 1, c], h[r + 1, c + 1], u - c, v - r)


def cell_height(h00, h10, h01, h11, fu, fv):
    """The surface's height at (fu, fv) in [0, 1]^2 of the cell whose corners (c, r), (c + 1, r),
    (c, r + 1), (c + 1, r + 1) are at h00, h10, h01, h11: on MuJoCo's two triangles, split along
    the diagonal from (c, r) to (c + 1, r + 1)."""
    lower = h00 + fu * (h10 - h00) + fv * (h11 - h10)  # triangle (c,r) (c+1,r) (c+1,r+1): fu >= fv
    upper = h00 + fv * (h01 - h00) + fu * (h11 - h01)  # triangle (c,r) (c+1,r+1) (c,r+1): fv > fu
    return jnp.where(fu >= fv, lower, upper)


def on_field(field: Heightfield | None, xy: jnp.ndarray, margin_m: float = 0.0) -> jnp.ndarray:
    """xy (..., 2) [m] -> (...,) bool: at least margin_m inside the field's edges (always True on
    the flat scene, whose plane is infinite)."""
    xy = jnp.asarray(xy)
    if field is None:
        return jnp.ones(xy.shape[:-1], bool)
    local = jnp.abs(xy - field.origin[:2])
    return jnp.all(local <= field.half_size - margin_m, axis=-1)


def scan_offsets(points: int, spacing_m: float) -> np.ndarray:
    """(points**2, 2) x, y offsets [m] of a square grid, spacing_m apart, centred on 0; x-major
    (the first `points` rows share the most backward x)."""
    side = (np.arange(points) - (points - 1) / 2.0) * spacing_m
    x, y = np.meshgrid(side, side, indexing="ij")
    return np.stack([x.ravel(), y.ravel()], axis=-1)


def turned(xy: jnp.ndarray, yaw, offsets: jnp.ndarray) -> jnp.ndarray:
    """World x, y [m] of offsets (n, 2+) in the heading frame of a robot at xy (2,) with heading yaw
    [rad] (only their x, y are read) -> (n, 2)."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return xy + jnp.stack([c * offsets[:, 0] - s * offsets[:, 1], s * offsets[:, 0] + c * offsets[:, 1]], -1)


def ground_scan(
    field: Heightfield | None, xy: jnp.ndarray, yaw, offsets: jnp.ndarray, under=None
) -> jnp.ndarray:
    """The ground around a robot: xy (2,) world [m], yaw [rad], offsets (n, 2) in its heading frame
    (scan_offsets) -> (n,) ground height at each offset minus the ground under xy [m]. under: that
    ground [m] where the caller has it (else queried here)."""
    under = ground_height(field, xy) if under is None else under
    return ground_height(field, turned(xy, yaw, offsets)) - under
