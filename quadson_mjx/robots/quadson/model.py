"""The Quadson MuJoCo model: MJCF generator, loader, cached ids, home pose and closure residual.

`python -m quadson_mjx.robots.quadson.model` (or `write_model_files()`) regenerates models/quadson/*.xml and the
rough-ground height map from `constants`; the committed files are tested to equal this output.

Each leg is a tree cut open at p3: hip (motor 0 about the leg-frame x axis) -> link 1 (motor 1 at
p1) -> link 2 (knee 2 at p2, runs on through p3 to the foot), and hip -> link 5 (motor 5 at p5)
-> link 4 (knee 4 at p4). An `<equality><connect>` between a site on link 2 at L2 and a site on
link 4 at L4 closes the five-bar at p3. Every hinge in the leg plane has axis -z of the leg frame,
so with the links along +x at zero the motor joints read the seed's t1, t5 (seed 000 Algorithm 1)
and the passive joints read knee2 = theta2 - t1, knee4 = theta4 - t5 (`fivebar.leg_points`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from quadson_mjx import fivebar
from quadson_mjx.mjcf import num, png_gray8, vec
from quadson_mjx.robots.quadson import constants as C

MODEL_DIR = Path(__file__).resolve().parents[3] / "models" / "quadson"
SCENES = {"flat": "scene.xml", "rough": "scene_rough.xml"}
ROUGH_PNG = "rough.png"
_BODY_XML = "quadson.xml"


# --- home pose ------------------------------------------------------------------------------------


def home_foot_targets() -> np.ndarray:
    """(4, 2) planar foot (x, y) in each shoulder frame [m] at home: the middle of the trot stance
    (STANCE_START_X + direction x step_length / 2) at STANCE_HEIGHT below the shoulder."""
    half = 0.5 * C.GAITS["trot"]["step_length_m"]
    x = C.STANCE_START_X + C.STANCE_DIRECTION * half
    return np.stack([x, np.full(C.NUM_LEGS, -C.STANCE_HEIGHT)], axis=-1)


def _solve_planar_ik(target: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """Motor angles (t1, t5) whose `fivebar.leg_fk` foot (t0 = 0) is the planar target (2,) [m].
    Newton on leg_fk in float64; no separate IK to keep consistent."""

    def planar(t15):
        return fivebar.leg_fk(jnp.concatenate([jnp.zeros(1, t15.dtype), t15]))[:2]

    with jax.enable_x64(True):
        t = jnp.asarray(guess, jnp.float64)
        tgt = jnp.asarray(target, jnp.float64)
        for _ in range(20):
            err = planar(t) - tgt
            if float(jnp.max(jnp.abs(err))) < 1e-14:
                break
            t = t - jnp.linalg.solve(jax.jacfwd(planar)(t), err)
        if float(jnp.max(jnp.abs(planar(t) - tgt))) > 1e-12:
            raise RuntimeError(f"home IK did not converge for {target}")
        return np.asarray(t, np.float64)


@functools.cache
def home_motor_angles() -> np.ndarray:
    """(4, 3) motor angles (t0, t1, t5) [rad] of the home keyframe, leg order LEGS."""
    solved = {}  # left and right legs share a target
    for xy in home_foot_targets():
        if tuple(xy) not in solved:
            solved[tuple(xy)] = _solve_planar_ik(xy, C.INITIAL_MOTOR_ANGLES[1:])
    return np.asarray([[0.0, *solved[tuple(xy)]] for xy in home_foot_targets()])


@functools.cache
def _home_leg_qpos() -> np.ndarray:
    """(4, 5) per-leg joint angles (motor0, motor1, knee2, motor5, knee4) [rad] at home."""
    angles = home_motor_angles()
    with jax.enable_x64(True):
        pts = fivebar.leg_points(jnp.asarray(angles, jnp.float64))
        knee2, knee4 = np.asarray(pts.knee2), np.asarray(pts.knee4)
    return np.stack([angles[:, 0], angles[:, 1], knee2, angles[:, 2], knee4], axis=-1)


HOME_BASE_HEIGHT = C.STANCE_HEIGHT + C.FOOT_RADIUS  # shoulders lie in the base's z = 0 plane


# --- MJCF generation ------------------------------------------------------------------------------


def _rod_inertia(mass: float, length: float) -> str:
    """Inertial of a thin rod of radius LINK_RADIUS along +x from the body origin."""
    r = C.LINK_RADIUS
    ixx = 0.5 * mass * r * r
    iyy = mass * (3 * r * r + length * length) / 12.0
    return f'<inertial pos="{num(length / 2)} 0 0" mass="{num(mass)}" diaginertia="{vec([ixx, iyy, iyy])}"/>'


def _box_inertia(mass: float, half, pos=(0.0, 0.0, 0.0)) -> str:
    a, b, c = (2 * h for h in half)
    diag = [mass * (b * b + c * c) / 12, mass * (a * a + c * c) / 12, mass * (a * a + b * b) / 12]
    return f'<inertial pos="{vec(pos)}" mass="{num(mass)}" diaginertia="{vec(diag)}"/>'


def _quat_of(rot: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot, dtype=np.float64).ravel())
    return q


def _leg_xml(i: int, leg: str) -> str:
    L, m = C.LINK_MASSES, C
    j = functools.partial(C.joint_name, leg)
    hip_c = (C.L0 / 2, 0.0, 0.0)
    return f"""\
      <body name="{leg}_hip" pos="{vec(C.SHOULDER_POS[i])}" quat="{vec(_quat_of(C.SHOULDER_ROT[i]))}">
        {_box_inertia(m.HIP_MASS, C.HIP_HALF_SIZE, hip_c)}
        <joint name="{j("motor0")}" class="motor0"/>
        <geom class="visual" type="box" pos="{vec(hip_c)}" size="{vec(C.HIP_HALF_SIZE)}"/>
        <body name="{leg}_link1">
          {_rod_inertia(L["link1"], C.L1)}
          <joint name="{j("motor1")}" class="motor1"/>
          <geom class="visual" fromto="0 0 0 {num(C.L1)} 0 0"/>
          <body name="{leg}_link2" pos="{num(C.L1)} 0 0">
            {_rod_inertia(L["link2"], C.L2 + C.L3)}
            <joint name="{j("knee2")}" class="knee"/>
            <geom class="visual" fromto="0 0 0 {num(C.L2 + C.L3)} 0 0"/>
            <geom name="{leg}_foot_collision" class="foot" pos="{num(C.L2 + C.L3)} 0 0"/>
            <site name="{leg}_closure2" pos="{num(C.L2)} 0 0" size="0.004"/>
            <site name="{C.foot_name(leg)}" class="foot_site" pos="{num(C.L2 + C.L3)} 0 0"/>
          </body>
        </body>
        <body name="{leg}_link5" pos="{num(C.L0)} 0 0">
          {_rod_inertia(L["link5"], C.L5)}
          <joint name="{j("motor5")}" class="motor5"/>
          <geom class="visual" fromto="0 0 0 {num(C.L5)} 0 0"/>
          <body name="{leg}_link4" pos="{num(C.L5)} 0 0">
            {_rod_inertia(L["link4"], C.L4)}
            <joint name="{j("knee4")}" class="knee"/>
            <geom class="visual" fromto="0 0 0 {num(C.L4)} 0 0"/>
            <site name="{leg}_closure4" pos="{num(C.L4)} 0 0" size="0.004"/>
          </body>
        </body>
      </body>
"""


def _motor_class(part: str, axis: str, rng) -> str:
    lo, hi = num(rng[0]), num(rng[1])
    return f"""\
      <default class="{part}">
        <joint axis="{axis}" range="{lo} {hi}"/>
        <position ctrlrange="{lo} {hi}"/>
      </default>
"""


def robot_xml() -> str:
    """Text of models/quadson/quadson.xml."""
    ranges = dict(zip(C.MOTORS, C.MOTOR_RANGES, strict=True))
    legs = "".join(_leg_xml(i, leg) for i, leg in enumerate(C.LEGS))
    eff = num(C.MOTOR_EFFORT_LIMIT)
    closure = "".join(
        f'    <connect name="{leg}_closure" site1="{leg}_closure2" site2="{leg}_closure4"/>\n'
        for leg in C.LEGS
    )
    motors = "".join(
        f'    <position class="{p}" name="{C.actuator_name(leg, p)}" joint="{C.joint_name(leg, p)}"/>\n'
        for leg in C.LEGS
        for p in C.MOTORS
    )
    sensors = "".join(
        f'    <jointpos name="{C.joint_name(leg, p)}_pos" joint="{C.joint_name(leg, p)}"/>\n'
        for leg in C.LEGS
        for p in C.MOTORS
    )
    sensors += "".join(
        f'    <jointvel name="{C.joint_name(leg, p)}_vel" joint="{C.joint_name(leg, p)}"/>\n'
        for leg in C.LEGS
        for p in C.MOTORS
    )
    sensors += "".join(
        f'    <touch name="{C.foot_name(leg)}_touch" site="{C.foot_name(leg)}"/>\n' for leg in C.LEGS
    )
    key_qpos = np.concatenate([[0.0, 0.0, HOME_BASE_HEIGHT, 1.0, 0.0, 0.0, 0.0], _home_leg_qpos().ravel()])
    solref = vec([C.CONTACT_TIMECONST, C.CONTACT_DAMPING_RATIO])
    return f"""\
<!-- Generated by `python -m quadson_mjx.robots.quadson.model` from quadson_mjx/robots/quadson/constants.py: edit those, not this. -->
<mujoco model="quadson">
  <compiler angle="radian" autolimits="true"/>

  <option timestep="{num(C.SIM_DT)}" iterations="{C.SOLVER_ITERATIONS}" ls_iterations="{C.SOLVER_LS_ITERATIONS}" integrator="{C.INTEGRATOR}">
    <flag eulerdamp="disable"/>
  </option>

  <default>
    <equality solref="{vec(C.CLOSURE_SOLREF)}" solimp="{vec(C.CLOSURE_SOLIMP)}"/>
    <default class="quadson">
      <geom contype="0" conaffinity="0"/>
      <joint damping="{num(C.MOTOR_DAMPING)}" armature="{num(C.MOTOR_ARMATURE)}"/>
      <position kp="{num(C.MOTOR_KP)}" kv="{num(C.MOTOR_KD)}" forcerange="-{eff} {eff}"/>
{_motor_class("motor0", "1 0 0", ranges["motor0"])}{_motor_class("motor1", "0 0 -1", ranges["motor1"])}{_motor_class("motor5", "0 0 -1", ranges["motor5"])}\
      <default class="knee">
        <joint axis="0 0 -1" limited="false" damping="{num(C.PASSIVE_DAMPING)}" armature="{num(C.PASSIVE_ARMATURE)}"/>
      </default>
      <default class="visual">
        <geom type="capsule" size="{num(C.LINK_RADIUS)}" group="2" density="0" rgba="0.85 0.55 0.2 1"/>
      </default>
      <default class="collision">
        <geom group="3" conaffinity="1" condim="{C.CONTACT_CONDIM}" friction="{vec(C.GROUND_FRICTION)}" solref="{solref}"/>
        <default class="foot">
          <geom type="sphere" size="{num(C.FOOT_RADIUS)}" priority="1" rgba="0.1 0.1 0.1 1"/>
        </default>
      </default>
      <default class="foot_site">
        <site type="sphere" size="{num(C.FOOT_RADIUS + 0.002)}" group="4"/>
      </default>
    </default>
  </default>

  <worldbody>
    <body name="{C.ROOT_BODY}" pos="0 0 {num(HOME_BASE_HEIGHT)}" childclass="quadson">
      <freejoint name="root"/>
      {_box_inertia(C.BASE_MASS, C.BASE_HALF_SIZE, (C.BASE_COM_X, 0.0, 0.0))}
      <geom name="base_collision" class="collision" type="box" size="{vec(C.BASE_HALF_SIZE)}"/>
      <geom class="visual" type="box" size="{vec(C.BASE_HALF_SIZE)}" rgba="0.3 0.3 0.35 1"/>
      <site name="{C.IMU_SITE}" size="0.01"/>
{legs}    </body>
  </worldbody>

  <equality>
{closure}  </equality>

  <actuator>
{motors}  </actuator>

  <sensor>
    <framequat name="imu_quat" objtype="site" objname="{C.IMU_SITE}"/>
    <gyro name="imu_gyro" site="{C.IMU_SITE}"/>
    <accelerometer name="imu_acc" site="{C.IMU_SITE}"/>
    <velocimeter name="imu_vel" site="{C.IMU_SITE}"/>
{sensors}  </sensor>

  <keyframe>
    <key name="{C.HOME_KEYFRAME}" qpos="{vec(key_qpos)}" ctrl="{vec(home_motor_angles().ravel())}"/>
  </keyframe>
</mujoco>
"""


def _scene_common(floor: str, assets: str = "") -> str:
    solref = vec([C.CONTACT_TIMECONST, C.CONTACT_DAMPING_RATIO])
    return f"""\
<!-- Generated by `python -m quadson_mjx.robots.quadson.model` from quadson_mjx/robots/quadson/constants.py: edit those, not this. -->
<mujoco model="quadson scene">
  <include file="{_BODY_XML}"/>

  <statistic center="0 0 0.15" extent="0.6"/>

  <visual>
    <headlight diffuse="0.6 0.6 0.6" ambient="0.3 0.3 0.3" specular="0 0 0"/>
    <global azimuth="-130" elevation="-20"/>
  </visual>

  <asset>
    <texture type="skybox" builtin="gradient" rgb1="0.3 0.5 0.7" rgb2="0 0 0" width="512" height="3072"/>
    <texture type="2d" name="groundplane" builtin="checker" mark="edge" rgb1="0.2 0.3 0.4" rgb2="0.1 0.2 0.3"
      markrgb="0.8 0.8 0.8" width="300" height="300"/>
    <material name="groundplane" texture="groundplane" texuniform="true" texrepeat="5 5" reflectance="0.2"/>
{assets}  </asset>

  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    {floor.format(friction=vec(C.GROUND_FRICTION), solref=solref, condim=C.CONTACT_CONDIM)}
  </worldbody>
</mujoco>
"""


def scene_xml() -> str:
    """Text of models/quadson/scene.xml: the robot on a flat floor."""
    floor = (
        '<geom name="floor" size="0 0 0.05" type="plane" material="groundplane" condim="{condim}" '
        'friction="{friction}" solref="{solref}"/>'
    )
    return _scene_common(floor)


def scene_rough_xml() -> str:
    """Text of models/quadson/scene_rough.xml: the robot on a seeded height field of loose stones."""
    hx, hy = C.ROUGH_SIZE
    nrow, ncol = _rough_shape()
    asset = (
        f'    <hfield name="rough" file="{ROUGH_PNG}" '
        f'size="{num(hx)} {num(hy)} {num(C.ROUGH_MAX_HEIGHT)} 0.05"/>\n'
    )
    del nrow, ncol
    floor = (
        '<geom name="floor" type="hfield" hfield="rough" material="groundplane" condim="{condim}" '
        'friction="{friction}" solref="{solref}"/>'
    )
    return _scene_common(floor, asset)


def _rough_shape() -> tuple[int, int]:
    hx, hy = C.ROUGH_SIZE
    return int(round(2 * hy / C.ROUGH_CELL)) + 1, int(round(2 * hx / C.ROUGH_CELL)) + 1


def rough_heights() -> np.ndarray:
    """(nrow, ncol) uint8 height map in [0, 255] of loose stones: seeded random round bumps of
    3-8 cm diameter, up to ROUGH_MAX_HEIGHT, the highest stone wins where they overlap; a flat
    patch of 0.6 m around the origin lets the robot start on level ground."""
    rng = np.random.default_rng(C.ROUGH_SEED)
    nrow, ncol = _rough_shape()
    hx, hy = C.ROUGH_SIZE
    y = np.linspace(-hy, hy, nrow)[:, None]
    x = np.linspace(-hx, hx, ncol)[None, :]
    h = np.zeros((nrow, ncol))
    n_stones = int(0.6 * (2 * hx) * (2 * hy) / 0.06**2)  # 0.6 stones per 6 x 6 cm: ~1/3 of the ground
    cx = rng.uniform(-hx, hx, n_stones)
    cy = rng.uniform(-hy, hy, n_stones)
    rad = rng.uniform(0.015, 0.04, n_stones)
    top = rng.uniform(0.2, 1.0, n_stones)
    for i in range(n_stones):
        r0 = int((cy[i] + hy) / C.ROUGH_CELL)
        c0 = int((cx[i] + hx) / C.ROUGH_CELL)
        k = int(math.ceil(rad[i] / C.ROUGH_CELL)) + 1
        rs, cs = slice(max(r0 - k, 0), r0 + k + 1), slice(max(c0 - k, 0), c0 + k + 1)
        d2 = ((x[:, cs] - cx[i]) ** 2 + (y[rs] - cy[i]) ** 2) / rad[i] ** 2
        bump = top[i] * np.sqrt(np.clip(1.0 - d2, 0.0, 1.0))  # a half-ellipsoid stone
        h[rs, cs] = np.maximum(h[rs, cs], bump)
    h[(np.abs(x) < 0.3) & (np.abs(y) < 0.3)] = 0.0
    h[0, 0] = 1.0  # pin the full scale: MuJoCo normalizes a PNG height field to [0, 1]
    return np.round(h * 255).astype(np.uint8)


def model_files() -> dict[str, bytes]:
    """Every generated file of models/quadson/, name -> content."""
    return {
        _BODY_XML: robot_xml().encode(),
        SCENES["flat"]: scene_xml().encode(),
        SCENES["rough"]: scene_rough_xml().encode(),
        ROUGH_PNG: png_gray8(rough_heights()),
    }


def write_model_files(directory: Path = MODEL_DIR) -> list[Path]:
    """Regenerate models/quadson/*.xml and the height map; returns the paths written."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for name, content in model_files().items():
        path = directory / name
        path.write_bytes(content)
        out.append(path)
    return out


# --- loading and ids ------------------------------------------------------------------------------


def scene_path(scene: str = "flat") -> Path:
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}: expected one of {sorted(SCENES)}")
    return MODEL_DIR / SCENES[scene]


def load_model(scene: str = "flat") -> mujoco.MjModel:
    """The compiled model of the robot in a scene: "flat" (scene.xml) or "rough" (scene_rough.xml)."""
    return mujoco.MjModel.from_xml_path(str(scene_path(scene)))


def model_xml_text(scene: str = "flat") -> str:
    """The robot and scene MJCF as text (to store beside checkpoints and logs)."""
    return (MODEL_DIR / _BODY_XML).read_text() + "\n" + scene_path(scene).read_text()


@dataclass(frozen=True)
class ModelIds:
    """Indices of named model elements, looked up once. Motor arrays are (12,) in LEGS x MOTORS order
    (C.MOTOR_JOINTS), passive arrays (8,) in LEGS x PASSIVE order, feet (4,) in LEGS order."""

    motor_joint: np.ndarray
    motor_qposadr: np.ndarray
    motor_dofadr: np.ndarray
    motor_actuator: np.ndarray
    passive_qposadr: np.ndarray
    passive_dofadr: np.ndarray
    foot_site: np.ndarray
    closure_site2: np.ndarray  # (4,) site on link 2 at L2
    closure_site4: np.ndarray  # (4,) site on link 4 at L4
    closure_eq: np.ndarray  # (4,) equality ids
    base_body: int
    imu_site: int
    root_qposadr: int  # free joint: qpos[adr:adr+7] = (x, y, z, qw, qx, qy, qz)
    root_dofadr: int
    sensor_adr: dict  # sensor name -> (adr, dim)


def _id(model, objtype, name: str) -> int:
    i = mujoco.mj_name2id(model, objtype, name)
    if i < 0:
        raise KeyError(f"{objtype.name} {name!r} not in the model")
    return i


def model_ids(model: mujoco.MjModel) -> ModelIds:
    """Looks every name of `constants` up in the model (raises KeyError on a missing one)."""
    J, A, S, B = (
        mujoco.mjtObj.mjOBJ_JOINT,
        mujoco.mjtObj.mjOBJ_ACTUATOR,
        mujoco.mjtObj.mjOBJ_SITE,
        mujoco.mjtObj.mjOBJ_BODY,
    )
    mj = np.array([_id(model, J, n) for n in C.MOTOR_JOINTS])
    pj = np.array([_id(model, J, n) for n in C.PASSIVE_JOINTS])
    base = _id(model, B, C.ROOT_BODY)
    root = int(model.body_jntadr[base])
    sensors = {}
    for i in range(model.nsensor):
        sensors[mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i)] = (
            int(model.sensor_adr[i]),
            int(model.sensor_dim[i]),
        )
    return ModelIds(
        motor_joint=mj,
        motor_qposadr=model.jnt_qposadr[mj].copy(),
        motor_dofadr=model.jnt_dofadr[mj].copy(),
        motor_actuator=np.array([_id(model, A, n) for n in C.ACTUATORS]),
        passive_qposadr=model.jnt_qposadr[pj].copy(),
        passive_dofadr=model.jnt_dofadr[pj].copy(),
        foot_site=np.array([_id(model, S, n) for n in C.FEET]),
        closure_site2=np.array([_id(model, S, f"{leg}_closure2") for leg in C.LEGS]),
        closure_site4=np.array([_id(model, S, f"{leg}_closure4") for leg in C.LEGS]),
        closure_eq=np.array([_id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"{leg}_closure") for leg in C.LEGS]),
        base_body=base,
        imu_site=_id(model, S, C.IMU_SITE),
        root_qposadr=int(model.jnt_qposadr[root]),
        root_dofadr=int(model.jnt_dofadr[root]),
        sensor_adr=sensors,
    )


def _key(model: mujoco.MjModel) -> int:
    return _id(model, mujoco.mjtObj.mjOBJ_KEY, C.HOME_KEYFRAME)


def home_qpos(model: mujoco.MjModel) -> np.ndarray:
    """(nq,) qpos of the `home` keyframe (closure satisfied, feet on the flat floor)."""
    return model.key_qpos[_key(model)].copy()


def home_ctrl(model: mujoco.MjModel) -> np.ndarray:
    """(nu,) ctrl of the `home` keyframe: the motor angles that hold the home pose [rad]."""
    return model.key_ctrl[_key(model)].copy()


# --- closure residual -------------------------------------------------------------------------------


def closure_residual(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """(4,) distance [m] between the two p3 sites of each leg (0 when the five-bar is closed).
    Reads data.site_xpos: call after mj_kinematics / mj_step."""
    ids = model_ids(model)
    d = data.site_xpos[ids.closure_site2] - data.site_xpos[ids.closure_site4]
    return np.linalg.norm(d, axis=-1)


def closure_residual_mjx(site_xpos: jax.Array, ids: ModelIds) -> jax.Array:
    """(..., 4) distance [m] between the p3 sites of each leg, from mjx.Data.site_xpos (..., nsite, 3)."""
    d = site_xpos[..., ids.closure_site2, :] - site_xpos[..., ids.closure_site4, :]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


if __name__ == "__main__":
    for p in write_model_files():
        print(p)
