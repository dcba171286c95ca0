"""A MuJoCo model as Foxglove draws it: each drawn geom as a SceneEntity in its body's frame (capsule =
cylinder + 2 spheres, box = cube, sphere, plane = thin cube, height field = triangle list), body frames
and their poses relative to the parent body, and the conversions to Foxglove's messages (MuJoCo writes
quaternions wxyz, Foxglove reads xyzw)."""

from __future__ import annotations

import mujoco
import numpy as np
from foxglove import messages as fm

from quadson_mjx.quat import quat_conj, quat_mul, quat_rotate

FLOOR_HALF_EXTENT_M = 10.0  # an infinite MuJoCo plane is drawn this large
_FLOOR_COLOR = (0.25, 0.35, 0.45, 1.0)


def timestamp(t_ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=int(t_ns // 1_000_000_000), nsec=int(t_ns % 1_000_000_000))


def quaternion_xyzw(q_wxyz) -> fm.Quaternion:
    w, x, y, z = (float(v) for v in q_wxyz)
    return fm.Quaternion(x=x, y=y, z=z, w=w)


def vector3(v) -> fm.Vector3:
    return fm.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def pose(pos, quat_wxyz) -> fm.Pose:
    return fm.Pose(position=vector3(pos), orientation=quaternion_xyzw(quat_wxyz))


def local_transforms(model: mujoco.MjModel, xpos, xquat):
    """World body poses (..., nbody, 3), (..., nbody, 4 wxyz) -> each body's pose in its parent
    body's frame (same shapes); the world body's entry is the identity."""
    parent = model.body_parentid
    conj = quat_conj(np.asarray(xquat[..., parent, :], np.float64))  # float64, whatever the rollout's dtype
    rel_pos = quat_rotate(conj, xpos - xpos[..., parent, :])
    rel_quat = quat_mul(conj, xquat)
    return rel_pos, rel_quat


def body_frames(model: mujoco.MjModel, env: int) -> list[str]:
    """Frame id of every body for environment `env` ("world" for the world body)."""
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in range(model.nbody)]
    return ["world"] + [f"env{env}/{n}" for n in names[1:]]


def _floor_color() -> fm.Color:
    r, g, b, a = _FLOOR_COLOR
    return fm.Color(r=r, g=g, b=b, a=a)


def _color(model, g) -> fm.Color:
    r, gr, b, a = (float(v) for v in model.geom_rgba[g])
    return fm.Color(r=r, g=gr, b=b, a=a)


def drawn_geoms(model) -> list[int]:
    """Geoms to draw: all but exact duplicates of another geom on the same body (a collision box
    that coincides with its visual box would flicker)."""
    seen, out = set(), []
    for g in np.argsort(model.geom_group, kind="stable"):  # visual (group 2) before collision (3)
        key = (
            int(model.geom_bodyid[g]),
            int(model.geom_type[g]),
            tuple(np.round(model.geom_size[g], 9)),
            tuple(np.round(model.geom_pos[g], 9)),
            tuple(np.round(model.geom_quat[g], 9)),
        )
        if key not in seen:
            seen.add(key)
            out.append(int(g))
    return sorted(out)


HFIELD_MAX_VERTICES = 250_000  # a larger height field is drawn from every k-th sample


def hfield_grid(model, g) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples of height field geom g that the scene draws -> (x (ncol,), y (nrow,), z (nrow,
    ncol)) in the geom frame [m]. Fields of more than HFIELD_MAX_VERTICES samples (the tiled
    ground: 1101 x 901) are drawn from every k-th sample in each direction, the last row and column
    kept, so the scene message stays a few MB (the default tiled ground: every 2nd, 4 cm apart; its
    stairs' 15 cm treads still show)."""
    h = int(model.geom_dataid[g])
    nrow, ncol = int(model.hfield_nrow[h]), int(model.hfield_ncol[h])
    rx, ry, top, _ = model.hfield_size[h]
    adr = int(model.hfield_adr[h])
    z = np.asarray(model.hfield_data[adr : adr + nrow * ncol]).reshape(nrow, ncol) * top
    xs = np.linspace(-rx, rx, ncol)
    ys = np.linspace(-ry, ry, nrow)
    k = int(np.ceil(np.sqrt(nrow * ncol / HFIELD_MAX_VERTICES)))
    if k > 1:
        rows = np.unique(np.append(np.arange(0, nrow, k), nrow - 1))
        cols = np.unique(np.append(np.arange(0, ncol, k), ncol - 1))
        z, xs, ys = z[np.ix_(rows, cols)], xs[cols], ys[rows]
    return xs, ys, z


def _hfield_triangles(model, g) -> fm.TriangleListPrimitive:
    """The height field as a triangle list in the geom frame (MuJoCo's vertex layout), from
    hfield_grid's samples."""
    xs, ys, z = hfield_grid(model, g)
    nrow, ncol = z.shape
    points = [
        fm.Point3(x=float(xs[c]), y=float(ys[r]), z=float(z[r, c])) for r in range(nrow) for c in range(ncol)
    ]
    r, c = np.meshgrid(np.arange(nrow - 1), np.arange(ncol - 1), indexing="ij")
    v00 = (r * ncol + c).ravel()
    v01, v10, v11 = v00 + 1, v00 + ncol, v00 + ncol + 1
    idx = np.stack([v00, v01, v11, v00, v11, v10], axis=-1).ravel().tolist()
    return fm.TriangleListPrimitive(
        pose=pose(model.geom_pos[g], model.geom_quat[g]),
        points=points,
        color=_floor_color(),
        indices=idx,
    )


def geom_entity(model, g: int, frame_id: str, entity_id: str) -> fm.SceneEntity | None:
    """A SceneEntity drawing geom g in its body's frame (None for a type not drawn)."""
    T = mujoco.mjtGeom
    gtype, size = int(model.geom_type[g]), model.geom_size[g]
    pos, quat = model.geom_pos[g], model.geom_quat[g]
    kw: dict = {}
    if gtype == T.mjGEOM_CAPSULE or gtype == T.mjGEOM_CYLINDER:
        r, half = float(size[0]), float(size[1])
        kw["cylinders"] = [
            fm.CylinderPrimitive(
                pose=pose(pos, quat),
                size=fm.Vector3(x=2 * r, y=2 * r, z=2 * half),
                bottom_scale=1.0,
                top_scale=1.0,
                color=_color(model, g),
            )
        ]
        if gtype == T.mjGEOM_CAPSULE:
            axis = quat_rotate(np.asarray(quat, np.float64), np.array([0.0, 0.0, half]))
            kw["spheres"] = [
                fm.SpherePrimitive(
                    pose=pose(pos + s * axis, quat),
                    size=fm.Vector3(x=2 * r, y=2 * r, z=2 * r),
                    color=_color(model, g),
                )
                for s in (-1.0, 1.0)
            ]
    elif gtype == T.mjGEOM_BOX:
        kw["cubes"] = [fm.CubePrimitive(pose=pose(pos, quat), size=vector3(2 * size), color=_color(model, g))]
    elif gtype == T.mjGEOM_SPHERE:
        d = 2 * float(size[0])
        kw["spheres"] = [
            fm.SpherePrimitive(pose=pose(pos, quat), size=fm.Vector3(x=d, y=d, z=d), color=_color(model, g))
        ]
    elif gtype == T.mjGEOM_PLANE:
        hx = float(size[0]) or FLOOR_HALF_EXTENT_M
        hy = float(size[1]) or FLOOR_HALF_EXTENT_M
        thick = 0.002
        top = np.asarray(pos, np.float64) - quat_rotate(
            np.asarray(quat, np.float64), np.array([0, 0, thick / 2])
        )
        kw["cubes"] = [
            fm.CubePrimitive(
                pose=pose(top, quat), size=fm.Vector3(x=2 * hx, y=2 * hy, z=thick), color=_floor_color()
            )
        ]
    elif gtype == T.mjGEOM_HFIELD:
        kw["triangles"] = [_hfield_triangles(model, g)]
    else:  # ellipsoid, mesh, sdf: not in the Quadson model
        return None
    return fm.SceneEntity(timestamp=timestamp(0), frame_id=frame_id, id=entity_id, frame_locked=True, **kw)
