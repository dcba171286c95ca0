"""The robot as a deploy loop meets it, simulated in MuJoCo C: the plant of the sim-to-sim evaluation
(quadson_mjx.sim2sim), on the model of quadson_mjx.sim2sim_model (2 ms timestep, full contacts,
torque motors, the stone field started on stones). Deliberately not the training simulator:

- servos (`ServoParams`): each physics step computes tau = kp e - kd qdot in Python, with e the
  position error and no P torque inside a deadband, the torque clamped by a DC motor's
  torque-speed limit (the peak torque; while motoring at most stall (1 - |qdot| / no_load_speed),
  zero at the no-load speed) and the targets acting `latency_s` after the deploy loop sent them
  (training: MuJoCo's position servo, 0-20 ms). kp, kd and the peak torque are the robot model's
  actuator gains (its constants module derives them) times ServoParams' scales.
- sensors (`SensorParams`): the IMU's quaternion with mounting tilt, white attitude noise and a
  heading that drifts with the integrated z gyro bias (a 6-axis fusion has no magnetometer), the
  gyro with bias, bias random walk and white noise, encoders with noise and quantisation.
- optionally a randomized model (friction, body masses, motor strength, base CoM; seeded) and pushes
  (horizontal velocity kicks of the base at random intervals), over the training config's ranges.

Robot-generic: names from the quadson_mjx.robots.Robot; the MuJoCo sensors "imu_quat", "imu_gyro",
"imu_acc" are every robot's (quadson_mjx.mjcf.robot_tail). numpy and mujoco only.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from quadson_mjx.quat import axis_quat, quat_mul, quat_rotate, quat_rotate_inverse, quat_to_rpy
from quadson_mjx.sim2sim_model import TERRAINS, TIMESTEP_S, plant_model  # noqa: F401 (the plant's model)

FIELD_GROUP = 0  # geom group of the ground (the scenes' floor); the robot's geoms are groups 2 and 3
SETTLE_S = 0.5  # the robot stands on its home targets this long before the walk starts [s]

# The no-load output speed of each robot's motor [rad/s], where the torque-speed line reaches zero,
# and the stall torque of that line [N m] (None: the model's joint damping already is the back-EMF).
# Quadson: KV 200 rpm/V x 24 V / 8:1 = 62.8 rad/s (robots/quadson/constants.py); the driver's 10 A
# limit (3.44 N m) holds up to half of it (constants.MOTOR_VELOCITY_LIMIT = 31.4 rad/s), so the
# voltage line starts at 2 x 3.44 N m. Caramel's MX-28 model carries its back-EMF as joint damping
# (robots/caramel/constants.py SERVO_DAMPING = stall torque / no-load speed): no second limit.
MOTOR_TORQUE_SPEED = {"quadson": (62.8318530718, 6.8754935416), "caramel": (None, None)}


@dataclasses.dataclass(frozen=True)
class ServoParams:
    """The servo model. kp, kd, peak torque: scales of the model's actuator (kp, kv, forcerange);
    the rest absolute."""

    kp_scale: float = 1.0
    kd_scale: float = 1.0
    peak_scale: float = 1.0
    deadband_rad: float = (
        0.002  # |error| below this gives no P torque (assumed: ~ 1 count of a 12-bit encoder)
    )
    latency_s: float = 0.02  # sent targets act this long after the loop's step [s]


@dataclasses.dataclass(frozen=True)
class SensorParams:
    """Noise of the robot's sensors (std of white noise per reading, uniform +-bound for biases).
    Assumed for a MEMS IMU of the MPU-6050 / ICM-20948 class with a 6-axis fusion, and a 12-bit
    magnetic encoder on each motor's output; the bounds are the residuals after a start-up
    calibration, not the datasheets' uncalibrated offsets."""

    gyro_noise: float = 0.01  # [rad/s]; datasheets give 0.001-0.003 at 100 Hz, x3-10 for frame vibration
    gyro_bias: float = 0.02  # [rad/s] per axis, +-; ~1 deg/s left after calibration
    gyro_bias_walk: float = 0.001  # [rad/s/sqrt(s)] random walk of the bias (drift)
    attitude_noise: float = 0.005  # [rad] per axis of the fused orientation
    mount_tilt: float = 0.02  # [rad] roll and pitch of the IMU on the frame, +- (~1 deg)
    encoder_noise: float = 0.001  # [rad]
    encoder_resolution: float = 2.0 * math.pi / 4096  # [rad] one count of 12 bits per turn
    enabled: bool = True


# --- the servo ---------------------------------------------------------------------------------------


def servo_torque(target, q, qdot, kp, kd, peak, stall, no_load_speed, deadband):
    """The servo model, per motor (arrays (n,) or scalars): target, q [rad], qdot [rad/s], gains kp
    [N m/rad], kd [N m s/rad], peak torque [N m], stall torque of the voltage line [N m] and no-load
    speed [rad/s] (None: no speed limit) and deadband [rad] -> torque [N m].
    tau = kp e - kd qdot with e = 0 where |target - q| < deadband; |tau| <= peak, and while motoring
    (tau qdot > 0) |tau| <= stall max(0, 1 - |qdot| / no_load_speed)."""
    e = np.asarray(target, np.float64) - q
    e = np.where(np.abs(e) < deadband, 0.0, e)
    tau = kp * e - kd * qdot
    limit = np.broadcast_to(np.asarray(peak, np.float64), np.shape(tau))
    if no_load_speed is not None:
        line = stall * np.maximum(0.0, 1.0 - np.abs(qdot) / no_load_speed)
        limit = np.where(tau * qdot > 0.0, np.minimum(limit, line), limit)
    return np.clip(tau, -limit, limit)


def latency_steps(latency_s: float, timestep_s: float) -> int:
    """Physics steps between sending targets and their effect."""
    return int(round(latency_s / timestep_s))


# --- the plant ---------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Readings:
    """What the robot's sensors give the deploy loop at one tick."""

    imu_quat_wxyz: np.ndarray  # (4,) IMU orientation, its world frame (heading arbitrary)
    gyro: np.ndarray  # (3,) [rad/s], IMU frame
    motor_pos: np.ndarray  # (12,) [rad], robot.motor_joints order


class Plant:
    """One simulated robot: reset(), then per control tick read() -> Readings, send(targets),
    advance(ctrl_dt). `truth()` gives the simulator's state for the metrics. Seeded; not thread-safe."""

    def __init__(
        self,
        robot,
        model: mujoco.MjModel,
        servo: ServoParams,
        sensors: SensorParams,
        seed: int = 0,
        randomization=None,
        push=None,
    ):
        """randomization: None or the env config's `randomization` dict (friction, mass_scale,
        motor_strength, base_com_shift_m ranges); push: None or its `push` dict (interval_s, speed_mps)."""
        self.robot, self.servo, self.sensors = robot, servo, sensors
        self.rng = np.random.default_rng(seed)
        self.m = model
        self.nominal = _copy_fields(model)
        self.d = mujoco.MjData(model)
        self.randomization, self.push = randomization, push
        ids = lambda t, names: np.array([mujoco.mj_name2id(model, t, n) for n in names])  # noqa: E731
        J = ids(mujoco.mjtObj.mjOBJ_JOINT, robot.motor_joints)
        self.act = ids(mujoco.mjtObj.mjOBJ_ACTUATOR, robot.actuators)
        if (J < 0).any() or (self.act < 0).any():
            raise KeyError("a motor joint or actuator of the robot is not in the model")
        self.qadr, self.dadr = model.jnt_qposadr[J], model.jnt_dofadr[J]
        self.root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, robot.root_body)
        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, robot.home_keyframe)
        self.home_qpos, home_ctrl = model.key_qpos[key].copy(), model.key_ctrl[key].copy()
        self.home_targets = home_ctrl[self.act]
        self.feet = ids(mujoco.mjtObj.mjOBJ_GEOM, robot.foot_geoms())
        self.sensor = {n: _sensor_adr(model, n) for n in ("imu_quat", "imu_gyro", "imu_acc")}
        base_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
        half = model.geom_size[base_geom]
        gx, gy = np.meshgrid(
            np.linspace(-half[0], half[0], 5), np.linspace(-half[1], half[1], 3), indexing="ij"
        )
        self.base_bottom = (
            np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -half[2])], -1) + model.geom_pos[base_geom]
        )
        self.field_half = _field_half(model)
        # the actuators' own gains are the servo's nominal ones (read from the robot's position servos)
        src = robot.load_model("flat")
        a = (
            src.actuator_gainprm[self.act, 0],
            -src.actuator_biasprm[self.act, 2],
            src.actuator_forcerange[self.act, 1],
        )
        self.kp0, self.kd0, self.peak0 = a[0] * servo.kp_scale, a[1] * servo.kd_scale, a[2] * servo.peak_scale
        self.no_load_speed, stall = MOTOR_TORQUE_SPEED.get(robot.name, (None, None))
        self.stall0 = None if stall is None else stall * servo.peak_scale
        self.delay = latency_steps(servo.latency_s, model.opt.timestep)
        self._closure_sites = []
        for leg in robot.legs:
            eq = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"{leg}_closure")
            site = eq >= 0 and model.eq_objtype[eq] == mujoco.mjtObj.mjOBJ_SITE
            self._closure_sites.append(
                (int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])) if site else (-1, -1)
            )
        self._geom_mask = np.zeros(mujoco.mjNGROUP, np.uint8)
        self._geom_mask[FIELD_GROUP] = 1

    # --- episode ---
    def reset(self, xy=(0.0, 0.0), yaw: float = 0.0) -> None:
        """The home pose at xy [m] and heading yaw [rad], raised or lowered until the foot over the
        highest ground is 2 mm above it, standing SETTLE_S on the home targets; draws the episode's
        model, biases and push times."""
        _restore_fields(self.m, self.nominal)
        self.kp, self.kd, self.peak, self.stall = (
            self.kp0.copy(),
            self.kd0.copy(),
            self.peak0.copy(),
            self.stall0,
        )
        if self.randomization is not None:
            self._randomize(self.randomization)
        d = self.d
        mujoco.mj_resetData(self.m, d)
        d.qpos[:] = self.home_qpos
        d.qpos[0:2] = xy
        d.qpos[3:7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        mujoco.mj_kinematics(self.m, d)
        feet = d.geom_xpos[self.feet]
        lift = max(
            self.ground_height(p[:2]) - (p[2] - self.m.geom_size[g][0])
            for p, g in zip(feet, self.feet, strict=True)
        )
        d.qpos[2] += lift + 0.002  # lowered, too, onto ground below 0 (a pit of the tiled ground)
        mujoco.mj_forward(self.m, d)
        self.step_index = 0
        self._queue = []  # (physics step at which it acts, targets)
        self.targets = self.home_targets.copy()
        s = self.sensors
        self.gyro_bias = self.rng.uniform(-s.gyro_bias, s.gyro_bias, 3) if s.enabled else np.zeros(3)
        tilt = self.rng.uniform(-s.mount_tilt, s.mount_tilt, 2) if s.enabled else np.zeros(2)
        self.mount = quat_mul(axis_quat(0, tilt[0]), axis_quat(1, tilt[1]))
        self.heading_drift = 0.0
        self.push_timer = self._next_push()
        self.pushes = 0
        for _ in range(int(round(SETTLE_S / self.m.opt.timestep))):
            self._physics_step()
        self.step_index = 0

    def _randomize(self, r) -> None:
        m, rng = self.m, self.rng
        m.geom_friction[:, 0] = rng.uniform(*r["friction"])
        scale = rng.uniform(*r["mass_scale"], m.nbody)
        m.body_mass[:] *= scale
        m.body_inertia[:] *= scale[:, None]
        strength = rng.uniform(*r["motor_strength"], len(self.act))
        self.kp, self.peak = self.kp * strength, self.peak * strength
        self.stall = None if self.stall is None else self.stall * strength
        m.body_ipos[self.root, 0] += rng.uniform(*r["base_com_shift_m"])
        mujoco.mj_setConst(m, self.d)

    def _next_push(self) -> float:
        return math.inf if self.push is None else self.rng.uniform(*self.push["interval_s"])

    # --- one tick ---
    def read(self) -> Readings:
        """The sensors now, as the robot reads them."""
        s, d = self.sensors, self.d
        q = d.sensordata[self.sensor["imu_quat"]]
        w = d.sensordata[self.sensor["imu_gyro"]]
        imu_q = quat_mul(q, self.mount)
        gyro = quat_rotate_inverse(self.mount, w) + self.gyro_bias
        if s.enabled:
            noise = self.rng.normal(0.0, s.attitude_noise, 3)
            imu_q = quat_mul(axis_quat(2, self.heading_drift), quat_mul(imu_q, _small_quat(noise)))
            gyro = gyro + self.rng.normal(0.0, s.gyro_noise, 3)
        motor = d.qpos[self.qadr].copy()
        if s.enabled:
            motor = motor + self.rng.normal(0.0, s.encoder_noise, motor.shape)
            motor = np.round(motor / s.encoder_resolution) * s.encoder_resolution
        return Readings(imu_q / np.linalg.norm(imu_q), gyro, motor)

    def send(self, targets) -> None:
        """Motor targets (12,) [rad] from the deploy loop; they act after the servo latency."""
        self._queue.append((self.step_index + self.delay, np.asarray(targets, np.float64).copy()))

    def advance(self, seconds: float) -> None:
        """Pushes when due, then physics steps for `seconds` (the control period); IMU drift."""
        if self.push is not None:
            self.push_timer -= seconds
            if self.push_timer <= 0.0:
                angle = self.rng.uniform(0.0, 2.0 * math.pi)
                speed = self.rng.uniform(*self.push["speed_mps"])
                self.d.qvel[0:2] += speed * np.array([math.cos(angle), math.sin(angle)])
                self.push_timer = self._next_push()
                self.pushes += 1
        for _ in range(int(round(seconds / self.m.opt.timestep))):
            self._physics_step()
        s = self.sensors
        if s.enabled:
            self.heading_drift += self.gyro_bias[2] * seconds  # a 6-axis fusion integrates the z bias
            self.gyro_bias = self.gyro_bias + s.gyro_bias_walk * math.sqrt(seconds) * self.rng.normal(size=3)

    def _physics_step(self) -> None:
        while self._queue and self._queue[0][0] <= self.step_index:
            self.targets = self._queue.pop(0)[1]
        d = self.d
        tau = servo_torque(
            self.targets,
            d.qpos[self.qadr],
            d.qvel[self.dadr],
            self.kp,
            self.kd,
            self.peak,
            self.stall,
            self.no_load_speed,
            self.servo.deadband_rad,
        )
        d.ctrl[self.act] = tau
        mujoco.mj_step(self.m, d)
        self.step_index += 1

    # --- the truth, for metrics and logs ---
    def truth(self) -> dict:
        """rpy (3,) [rad], body-frame lin_vel (3,) [m/s] and ang_vel (3,) [rad/s], base height above
        the ground under it [m], lowest base-bottom point above the ground [m], on_field."""
        d = self.d
        quat = d.qpos[3:7]
        points = d.qpos[:3] + _rotate(quat, self.base_bottom)
        clearance = min(p[2] - self.ground_height(p[:2]) for p in points)
        return {
            "rpy": quat_to_rpy(quat),
            "lin_vel": quat_rotate_inverse(quat, d.qvel[0:3]),
            "ang_vel": d.qvel[3:6].copy(),
            "height": d.qpos[2] - self.ground_height(d.qpos[:2]),
            "clearance": clearance,
            "on_field": self.field_half is None or bool(np.all(np.abs(d.qpos[:2]) <= self.field_half - 0.3)),
        }

    def ground_height(self, xy) -> float:
        """Height of the ground under world xy [m] (MuJoCo's ray against the ground geoms)."""
        geomid = np.zeros(1, np.int32)
        dist = mujoco.mj_ray(
            self.m,
            self.d,
            np.array([xy[0], xy[1], 10.0]),
            np.array([0.0, 0.0, -1.0]),
            self._geom_mask,
            1,
            -1,
            geomid,
        )
        return 10.0 - dist if dist >= 0 else -math.inf

    def foot_forces(self) -> np.ndarray:
        """(4,) normal contact force on each foot [N]."""
        d, out, f = self.d, np.zeros(len(self.feet)), np.zeros(6)
        for i in range(d.ncon):
            c = d.contact[i]
            for k, g in enumerate(self.feet):
                if g in (c.geom1, c.geom2):
                    mujoco.mj_contactForce(self.m, d, i, f)
                    out[k] += f[0]
        return out

    def closure_gaps(self) -> np.ndarray:
        """(legs,) gap [m] of each leg's `{LEG}_closure` connect constraint (site to site); 0 for a
        leg without one (serial legs)."""
        out = np.zeros(len(self.robot.legs))
        for i, (s1, s2) in enumerate(self._closure_sites):
            if s1 >= 0:
                out[i] = np.linalg.norm(self.d.site_xpos[s1] - self.d.site_xpos[s2])
        return out

    def imu_acc(self) -> np.ndarray:
        return self.d.sensordata[self.sensor["imu_acc"]].copy()


def _sensor_adr(m, name: str) -> slice:
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
    if i < 0:
        raise KeyError(f"sensor {name!r} not in the model")
    return slice(int(m.sensor_adr[i]), int(m.sensor_adr[i] + m.sensor_dim[i]))


def _field_half(m) -> np.ndarray | None:
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    if g < 0 or m.geom_type[g] != mujoco.mjtGeom.mjGEOM_HFIELD:
        return None
    return m.hfield_size[int(m.geom_dataid[g])][:2].copy()


_RANDOMIZED = ("geom_friction", "body_mass", "body_inertia", "body_ipos")


def _copy_fields(m) -> dict:
    return {k: getattr(m, k).copy() for k in _RANDOMIZED}


def _restore_fields(m, saved: dict) -> None:
    for k, v in saved.items():
        getattr(m, k)[:] = v


def _small_quat(v) -> np.ndarray:
    """wxyz of the rotation vector v (3,) [rad]."""
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[math.cos(a / 2)], math.sin(a / 2) * np.asarray(v) / a])


def _rotate(quat, v):
    return quat_rotate(np.broadcast_to(quat, (len(v), 4)), v)
