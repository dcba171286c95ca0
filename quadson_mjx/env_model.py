"""The MuJoCo model an environment steps: the robot's scene with the env config's physics options.

`training_model` loads the robot's flat or rough scene, or builds the tiled ground (`tiles_model`),
and applies what the config chooses for speed (no sensor evaluation, feet-only ground contact, no
joint-limit rows) and the solver options (cone, solver, mass-matrix storage); `put_model` hands it
to MJX with the chosen implementation. Under MJX's Warp implementation the feet's contacts come
from their height over the plane on the flat scene (`feet_on_plane`), else from contact sensors
(`foot_contact_sensors`); its buffers are sized by `warp_buffers` and the reset's data is built
from the MjModel (`make_env_data`); `check_warp_ground` refuses the get-up task on a height field.
`name_ids` looks names up once (Python never hard-codes a model index); `device_constant` puts an
environment's constants on the device without compiling a program for each.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from quadson_mjx import terrain_tiles, warp_notice
from quadson_mjx.env_config import CONES, JACOBIANS, SOLVERS
from quadson_mjx.sim2sim_model import leg_of_body
from quadson_mjx.terrain import FLOOR_GEOM
from quadson_mjx.terrain_tiles import tile_spec

BASE_GEOM = "base_collision"  # the base's box, every robot's
# a contact sensor's intprm: its data (mjtConDataField bits: 1 = "found"), its reduction (1 =
# "mindist"), its number of contacts
CONTACT_FOUND, REDUCE_MINDIST = 1, 1


def device_constant(x, dtype=None) -> jax.Array:
    """x (a numpy array or a sequence) converted on the host to `dtype` (default: JAX's canonical
    dtype of x: float32, int32 without x64) and put on the default device. jnp.asarray converts in a
    small device program instead, one per new shape and dtype: about 0.1 s each to compile on a GPU,
    and an environment's constructor made about 15 of them."""
    a = np.asarray(x)
    return jax.device_put(
        a.astype(jax.dtypes.canonicalize_dtype(a.dtype) if dtype is None else dtype, copy=False)
    )


def name_ids(model: mujoco.MjModel, objtype: mujoco.mjtObj, names) -> np.ndarray:
    """Ids of `names` of one object type; KeyError naming the missing ones."""
    ids = np.array([mujoco.mj_name2id(model, objtype, n) for n in names], dtype=np.int64)
    missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
    if missing:
        raise KeyError(f"{objtype.name} {missing} not in the model")
    return ids


def training_model(robot, cfg, contact_sensors: bool | None = None) -> mujoco.MjModel:
    """robot: quadson_mjx.robots.Robot; cfg: an env config -> a fresh MjModel of its terrain's scene.
    contact_sensors: the feet's contact sensors in place of the model's sensors (default: under
    Warp, off the plane; see feet_on_plane)."""
    variant = cfg.get("fivebar_model", "full")
    warp = cfg.get("impl", "jax") == "warp"
    sensed_feet = (warp and not feet_on_plane(cfg)) if contact_sensors is None else contact_sensors
    spec = None
    if cfg.terrain == "tiles":
        spec = tiles_spec(robot, variant, tile_spec(cfg))
    elif sensed_feet:
        spec = mujoco.MjSpec.from_file(str(robot.scene_path(cfg.terrain, variant)))
    if sensed_feet:
        foot_contact_sensors(spec, robot)
    m = robot.load_model(cfg.terrain, variant) if spec is None else spec.compile()
    # Observations and rewards read qpos/qvel directly, so MJX need not evaluate the sensors
    # (measured on one H100: ~7% of a physics step). Rollouts that log sensors use their own model.
    # Under Warp off the plane the only sensors are the feet's contact sensors (foot_contact_sensors).
    if not sensed_feet:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    if not cfg.base_terrain_contact:
        base_geom = int(name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, [BASE_GEOM])[0])
        m.geom_contype[base_geom] = 0
        m.geom_conaffinity[base_geom] = 0
    if not cfg.joint_limits:
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    if cfg.get("task", "locomotion") == "getup":
        legs_touch_ground(m, robot)
    m.opt.cone = CONES[cfg.cone]
    m.opt.solver = SOLVERS[cfg.solver]
    m.opt.iterations = int(cfg.solver_iterations)
    if cfg.get("sim_dt", 0.0) > 0.0:
        m.opt.timestep = float(cfg.sim_dt)
    m.opt.jacobian = JACOBIANS[cfg.jacobian]
    return m


def feet_on_plane(cfg) -> bool:
    """Under MJX's Warp implementation on the flat scene (a plane at z = 0) the env tells a foot's
    ground contact from the foot sphere's height (LocomotionEnv.foot_contact), the same test as
    MuJoCo's sphere-plane collision; the contact sensors it needs elsewhere cost 11-12 % of Warp's
    physics (benchmarks/warp_sensor_cost.py)."""
    return cfg.get("impl", "jax") == "warp" and cfg.terrain == "flat"


def check_floor_plane(m: mujoco.MjModel) -> None:
    """ValueError unless the floor is an unrotated plane at z = 0 (what feet_on_plane assumes)."""
    g = int(name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, [FLOOR_GEOM])[0])
    plane = m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE
    if not (plane and m.geom_pos[g][2] == 0.0 and np.allclose(m.geom_quat[g], (1, 0, 0, 0))):
        raise ValueError(f"the flat scene's {FLOOR_GEOM!r} geom must be an unrotated plane at z = 0")


def foot_contact_sensors(spec: mujoco.MjSpec, robot) -> None:
    """Replaces the sensors of `spec` (in place) by one contact sensor per foot, LEGS order, between
    the foot's collision sphere and the ground geom: 1 when they have a contact (data "found",
    reduced to the deepest one), else 0. MJX's Warp implementation keeps one contact list for all
    worlds, so a world reads its feet's contacts from these (sensordata) instead of that list."""
    for sensor in list(spec.sensors):
        spec.delete(sensor)
    for geom in robot.foot_geoms():
        spec.add_sensor(
            name=f"{geom}_ground",
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_GEOM,
            objname=geom,
            reftype=mujoco.mjtObj.mjOBJ_GEOM,
            refname=FLOOR_GEOM,
            intprm=[CONTACT_FOUND, REDUCE_MINDIST, 1],
        )


def warp_buffers(m: mujoco.MjModel, worlds: int) -> tuple[int, int]:
    """The buffer sizes MJX's Warp implementation needs to step up to `worlds` worlds of model m ->
    (naconmax: contacts, one list for all worlds; njmax: constraint rows per world): the contacts
    and rows the JAX implementation allocates for one world (its static upper bound: every geom
    pair that may collide, with the contacts each pair type can make, and their rows), the
    contacts times `worlds`. Warp drops contacts or rows past these and prints an overflow warning."""
    d = mjx.make_data(m, impl="jax")
    per_world = max(int(d._impl.contact.dist.shape[0]), 1)
    return per_world * int(worlds), max(int(d._impl.efc_J.shape[0]), 1)


def make_env_data(m: mujoco.MjModel, sys, buffers: tuple[int, int] | None):
    """A fresh mjx.Data for the environment's reset: from the device model `sys` (JAX
    implementation, buffers None) or, under Warp, from the MjModel m with buffers (naconmax, njmax)
    of warp_buffers."""
    if buffers is None:
        return mjx.make_data(sys)
    naconmax, njmax = buffers
    return mjx.make_data(m, impl="warp", naconmax=naconmax, njmax=njmax)


def legs_touch_ground(m: mujoco.MjModel, robot) -> None:
    """Every geom of every leg (hip box, link capsules, foot sphere) touches the ground, with the
    base box's contact parameters (its collision class), in place: a fallen robot lies on its hips
    and links, not on its feet. The legs do not touch each other (MJX would test every pair of
    their geoms each step); the get-up task penalises poses where they overlap instead
    (getup_start.self_clearance). The ground geoms have contype 1, so conaffinity 1 suffices."""
    base = int(name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, [BASE_GEOM])[0])
    root = int(name_ids(m, mujoco.mjtObj.mjOBJ_BODY, [robot.root_body])[0])
    legs = leg_of_body(m, robot, root)
    for g in range(m.ngeom):
        if int(m.geom_bodyid[g]) in legs:
            m.geom_contype[g], m.geom_conaffinity[g] = 0, 1
            m.geom_friction[g] = m.geom_friction[base]
            m.geom_solref[g], m.geom_solimp[g] = m.geom_solref[base], m.geom_solimp[base]
            m.geom_condim[g] = m.geom_condim[base]


def tiles_model(robot, variant: str, spec: terrain_tiles.TerrainSpec) -> mujoco.MjModel:
    """The robot over the tiled ground of `spec` (terrain_tiles.tile_grid), compiled (tiles_spec)."""
    return tiles_spec(robot, variant, spec).compile()


def tiles_spec(robot, variant: str, spec: terrain_tiles.TerrainSpec) -> mujoco.MjSpec:
    """The robot over the tiled ground of `spec` (terrain_tiles.tile_grid): its stone-field scene
    (the same floor geom, contact and materials) with the height field's samples, extent and relief
    replaced, the floor geom lowered to the field's lowest point. Built in memory (no file; MjSpec,
    whose XML writer would round the model's numbers to 6 digits, so none is written)."""
    heights = terrain_tiles.tile_grid(spec)
    size, lowest = terrain_tiles.hfield_size(heights, spec)
    mj_spec = mujoco.MjSpec.from_file(str(robot.scene_path("rough", variant)))
    floor = mj_spec.geom(FLOOR_GEOM)
    field = mj_spec.hfield(floor.hfieldname)
    field.file = ""
    field.nrow, field.ncol = heights.shape
    field.size = size
    field.userdata = terrain_tiles.hfield_data(heights).tolist()
    floor.pos = [0.0, 0.0, lowest]
    return mj_spec


def scene_xml_text(robot, cfg) -> str:
    """The robot and scene MJCF of an env config as text (stored beside checkpoints and rollouts):
    the robot's scene file, or for the tiled ground its stone-field scene, whose height field
    `tiles_model` replaces by the env config's `tiles` (stored beside it)."""
    variant = cfg.get("fivebar_model", "full")
    if cfg.terrain != "tiles":
        return robot.model_xml_text(cfg.terrain, variant)
    note = (
        "<!-- terrain=tiles: the height field below is replaced by quadson_mjx.terrain_tiles.tile_grid of "
        "the env config's tiles keys (env_model.tiles_model) -->\n"
    )
    return note + robot.model_xml_text("rough", variant)


def check_env_impl(impl: str) -> None:
    """Raises ValueError when the environments cannot run on MJX implementation `impl`: "jax"
    always can; "warp" needs warp-lang (warp_notice.require_warp says what is missing)."""
    if impl not in ("jax", "warp"):
        raise ValueError(f"env.impl is {impl!r}; choose from ['jax', 'warp']")
    if impl == "warp":
        warp_notice.require_warp()


def check_warp_ground(cfg) -> None:
    """Raises ValueError for the one task MJX's Warp implementation steps wrongly here: the get-up
    task (base and every leg link colliding) on a height field (stones, tiles). From the task's own
    drops its worlds turn non-finite within 40 control steps where the JAX implementation's stay
    finite (its contact buffer not full; on a GPU Warp also reports height-field collision
    overflow, more than 50 prisms touching one geom): benchmarks/warp_getup_ground.py."""
    if (
        cfg.get("impl", "jax") == "warp"
        and cfg.get("task", "locomotion") == "getup"
        and cfg.terrain != "flat"
    ):
        raise ValueError(
            f"env.impl=warp cannot run the get-up task on env.terrain={cfg.terrain} (a height field): "
            "Warp turns its worlds non-finite there (benchmarks/warp_getup_ground.py); use env.impl=jax"
        )


# How Warp's foreign calls replay their CUDA graphs (a name of mujoco.mjx.warp.types.GraphMode):
# None, mujoco.mjx's choice ("WARP" on a GPU: one graph per set of buffer addresses; "JAX" on the
# CPU, the only one there), or e.g. "WARP_STAGED" (one graph per call site, inputs copied into
# staging buffers first; measured slower on one H100: benchmarks/warp_task_cost.py).
WARP_GRAPH_MODE: str | None = None


def put_model(m: mujoco.MjModel, impl: str):
    """mjx.put_model with the config's implementation; "warp" needs warp-lang (mujoco.mjx carries
    its own MuJoCo Warp), and its import error is reported here, where it matters, not at every
    import of mujoco.mjx."""
    if impl != "warp":
        return mjx.put_model(m, impl=impl)
    warp_notice.require_warp()
    from mujoco.mjx.warp.types import GraphMode

    mode = None if WARP_GRAPH_MODE is None else getattr(GraphMode, WARP_GRAPH_MODE)
    mx = mjx.put_model(m, impl=impl, graph_mode=mode)
    warn = quiet_overflow(mx.opt._impl.warn_overflow)
    return mx.replace(opt=mx.opt.replace(_impl=mx.opt._impl.replace(warn_overflow=warn)))


def quiet_overflow(warn):
    """MuJoCo Warp's overflow-warning bits `warn` without the solver's iteration limits: our models
    run one constraint-solver iteration on purpose (as Playground's Go1 does), which Warp reports as
    a limit reached at every step; its other warnings (contacts, constraint rows, height field)
    stay on."""
    from mujoco.mjx.third_party.mujoco_warp._src.types import OverflowType

    return warn & ~int(OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS)


def home_contact_points(
    m: mujoco.MjModel, key: int, foot_geoms, base_bottom
) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot at keyframe `key` could touch the ground, relative to its base origin, for
    placing it over uneven ground (terrain_tiles.spawn_lift) -> (points (P, 3) world axes [m]: the
    foot spheres' centres, then the base box's bottom points base_bottom (B, 3) base frame; radius
    (P,): the foot spheres', 0 for the box's points)."""
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, key)
    mujoco.mj_kinematics(m, d)
    base = np.asarray(d.qpos[:3])
    feet = np.asarray(foot_geoms)
    radius = m.geom_size[feet, 0]
    foot_centres = d.geom_xpos[feet] - base
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, d.qpos[3:7])
    box = np.asarray(base_bottom) @ rot.reshape(3, 3).T
    points = np.concatenate([foot_centres, box])
    return points, np.concatenate([radius, np.zeros(len(box))])


def base_bottom_points(half_size, n_x: int = 5, n_y: int = 3) -> np.ndarray:
    """(n_x * n_y, 3) grid over the bottom face of a box of half_size (3,) [m], box frame: where a
    tilted box meets a height field first (its lowest points are on that face up to 90 deg of tilt)."""
    hx, hy, hz = half_size
    x, y = np.meshgrid(np.linspace(-hx, hx, n_x), np.linspace(-hy, hy, n_y), indexing="ij")
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, -hz)], axis=-1)


def motoring_forcerange(forcerange, qdot, speed_knee):
    """A position servo's torque-speed limit for one physics step: forcerange (n, 2) [N m] of the
    servos' actuators, qdot (n,) their joints' speeds [rad/s] -> (n, 2). While motoring (torque
    along qdot) the torque is at most peak min(1, max(0, 2 - |qdot| / speed_knee)): the full peak up
    to speed_knee, falling to 0 at twice it; braking keeps the full range. This is
    sim2sim_plant.servo_torque's limit for a line whose stall torque is twice the peak (Quadson: the
    driver's 10 A up to 31.4 rad/s, the 24 V supply's line to 0 at 62.8 rad/s). JAX."""
    lo, peak = forcerange[:, 0], forcerange[:, 1]
    cap = peak * jnp.clip(2.0 - jnp.abs(qdot) / speed_knee, 0.0, 1.0)
    return jnp.stack([jnp.where(qdot < 0, -cap, lo), jnp.where(qdot > 0, cap, peak)], -1)
