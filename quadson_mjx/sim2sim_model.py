"""The MuJoCo model of the sim-to-sim plant (quadson_mjx.sim2sim_plant), built from the robot's MJCF
the other way from quadson_mjx.env_model.training_model: nothing stripped, more added.

- a 2 ms timestep (training: the model's 4 ms), the implicit-fast integrator, Newton with MuJoCo's
  default 100 iterations and an elliptic friction cone (training: Euler, 1 iteration, pyramidal);
  sensors and joint limits on.
- the FULL contact model: the base box, the feet and every leg link and hip touch the ground, and
  each leg touches the other legs (training: the feet, and the base only where the config says).
  A leg's own links do not collide with each other (they overlap at their joints); the closed
  five-bar chains stay closed by the model's equality constraints.
- the position servos become torque motors (ctrl = torque [N m]): the plant computes the torque.
- ground: the plane, or the training stone field (the same heights, quadson_mjx.mjcf's map as the
  robot's rough scene scales it) mirror-tiled 3 x 3 into a 24 x 24 m field, so that a 20 s
  command at 0.5 m/s stays on it; the flat start patch at the origin is filled with the stones
  2 m beside it, so that a run starts ON stones; or the tiled ground of a policy's env config
  (quadson_mjx.terrain_tiles: the same heights, extent and floor height as training's).
"""

from __future__ import annotations

import os
import re
import tempfile

import mujoco
import numpy as np

TIMESTEP_S = 0.002  # [s]; training steps the model's 0.004 s
STONES_TILES = 3  # the stone field mirrored 3 x 3: 24 x 24 m
STONES_PATCH_FILL_SHIFT_M = 2.0  # the start patch takes the stones this far along +x
TERRAINS = ("flat", "stones")  # and "tiles", with a TerrainSpec


def _tiled_stones(rough: mujoco.MjModel) -> np.ndarray:
    """The rough scene's height data (nrow, ncol) in [0, 1], start patch filled, mirror-tiled."""
    h = np.asarray(rough.hfield_data, np.float64).reshape(
        int(rough.hfield_nrow[0]), int(rough.hfield_ncol[0])
    )
    h = h.copy()
    nrow, ncol = h.shape
    half = rough.hfield_size[0][:2]
    cell = 2.0 * half[0] / (ncol - 1)
    x = np.linspace(-half[0], half[0], ncol)[None, :]
    y = np.linspace(-half[1], half[1], nrow)[:, None]
    patch = (np.abs(x) < 0.3 + cell) & (np.abs(y) < 0.3 + cell)
    shift = int(round(STONES_PATCH_FILL_SHIFT_M / cell))
    h[patch] = np.roll(h, -shift, axis=1)[patch]
    for r, c, dr, dc in ((0, 0, 1, 1), (0, -1, 1, -1), (-1, 0, -1, 1), (-1, -1, -1, -1)):
        h[r, c] = h[r + dr, c + dc]  # the generator pins one corner to the full scale
    row = np.concatenate([np.flip(h, 1)[:, :-1], h, np.flip(h, 1)[:, 1:]], axis=1)
    return np.concatenate([np.flip(row, 0)[:-1], row, np.flip(row, 0)[1:]], axis=0)


def _model_xml(m: mujoco.MjModel) -> str:
    """The MJCF text of a just-loaded model (mj_saveLastXML: includes flattened)."""
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "scene.xml")
        mujoco.mj_saveLastXML(path, m)
        with open(path) as f:
            return f.read()


def plant_model(robot, terrain: str, timestep_s: float = TIMESTEP_S, tiles=None) -> mujoco.MjModel:
    """robot: quadson_mjx.robots.Robot; terrain: "flat" | "stones" | "tiles" (with tiles: the
    terrain_tiles.TerrainSpec of the policy's env config) -> the sim2sim MjModel: the robot's MJCF
    with full contacts, torque motors, sensors and limits on, the given timestep."""
    if terrain not in (*TERRAINS, "tiles") or (terrain == "tiles") != (tiles is not None):
        raise ValueError(f"unknown terrain {terrain!r}: flat, stones, or tiles with its TerrainSpec")
    src = robot.load_model("flat" if terrain == "flat" else "rough")
    xml = _model_xml(src)
    heights, data, floor_z = None, None, None
    if terrain != "flat":
        if terrain == "stones":
            heights = _tiled_stones(src)
            sx, sy, sz, base = src.hfield_size[0]
            size = f"{sx * STONES_TILES:.9g} {sy * STONES_TILES:.9g} {sz:.9g} {base:.9g}"
            data = heights.ravel()
        else:  # the training ground (env_model.tiles_model builds the same from the same scene)
            from quadson_mjx import terrain_tiles  # JAX: imported for the tiles only
            from quadson_mjx.terrain import FLOOR_GEOM

            heights = terrain_tiles.tile_grid(tiles)
            size_m, floor_z = terrain_tiles.hfield_size(heights, tiles)
            size = " ".join(f"{v:.9g}" for v in size_m)
            data = terrain_tiles.hfield_data(heights)
        nrow, ncol = heights.shape
        xml, n = re.subn(
            r'<hfield name="([^"]+)"[^>]*/>',
            rf'<hfield name="\1" nrow="{nrow}" ncol="{ncol}" size="{size}"/>',
            xml,
        )
        if n != 1:
            raise ValueError("the rough scene must have exactly one height field")
    spec = mujoco.MjSpec.from_string(xml)
    if floor_z is not None:  # MuJoCo raises the field's [0, 1] data by its relief from the geom's z
        spec.geom(FLOOR_GEOM).pos = [0.0, 0.0, floor_z]
    base_geom = mujoco.mj_name2id(src, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
    ref = spec.geoms[base_geom]  # the collision class's contact parameters
    root = mujoco.mj_name2id(src, mujoco.mjtObj.mjOBJ_BODY, robot.root_body)
    # Every geom of a leg touches the ground (conaffinity bit 0) and the other legs (bit 1 + leg),
    # not its own leg, whose links overlap at their joints; the base box touches the ground only.
    leg_of_body_ = leg_of_body(src, robot, root)
    all_legs = sum(1 << (1 + i) for i in range(len(robot.legs)))
    for g, geom in enumerate(spec.geoms):  # the spec lists the geoms in the compiled order
        leg = leg_of_body_.get(int(src.geom_bodyid[g]))
        if leg is None:
            continue
        geom.contype = 1 << (1 + leg)
        geom.conaffinity = 1 | (all_legs & ~(1 << (1 + leg)))
        geom.friction, geom.solref, geom.solimp, geom.condim = (
            ref.friction,
            ref.solref,
            ref.solimp,
            ref.condim,
        )
    for a in spec.actuators:  # position servos -> torque motors: ctrl is the servo model's torque [N m]
        a.gainprm = [1.0] + [0.0] * (len(a.gainprm) - 1)
        a.biasprm = [0.0] * len(a.biasprm)
        a.biastype = mujoco.mjtBias.mjBIAS_NONE
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    m = spec.compile()
    if data is not None:
        m.hfield_data[:] = data
    m.opt.timestep = timestep_s
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    m.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    m.opt.iterations, m.opt.ls_iterations = 100, 50
    m.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    m.opt.disableflags = 0
    return m


def leg_of_body(m, robot, root: int) -> dict[int, int]:
    """body id -> leg index for every body below the root whose subtree holds one leg's motor joint."""
    out = {}
    for i, leg in enumerate(robot.legs):
        joints = [n for n in robot.motor_joints if n.startswith(f"{leg}_")]
        top = {int(m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in joints}
        top = min(top)  # the leg's first body (bodies are numbered depth-first)
        for b in range(m.nbody):
            p = b
            while p not in (0, root) and p != top:
                p = int(m.body_parentid[p])
            if p == top:
                out[b] = i
    return out
