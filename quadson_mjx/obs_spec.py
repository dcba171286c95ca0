"""The observation and the action of a task, specified once: ordered entries with sizes, units and
the sensor each comes from.

The environment builds its observation with `Spec.assemble` (JAX arrays, under jit), the deploy loop
builds the same vector on the robot from the same spec (numpy), and the exported policy file carries
`Spec.to_json()` in its metadata, so the robot side checks the file against the spec it builds
before it runs anything. No observation or action size is written anywhere else.

Only numpy and array-api-compat are imported: the robot's computer loads this module too.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence

from quadson_mjx.arrays import namespace

# sensors an observation entry may come from: "estimator" is a state estimator the robot would need
# (the project provides none), "calibration" a constant measured on the robot before it walks (the
# servos' latency), "simulator" what only a simulator knows (the critic's privileged view)
SENSORS = ("imu", "encoders", "estimator", "clock", "command", "policy", "calibration", "simulator")
# where a policy whose observation has an "estimator" entry gets its base velocity outside training
# (policy_eval in MJX, sim2sim in MuJoCo C): the simulator's true value, zeros (no estimator), or
# the commanded vx, vy as the estimate
VELOCITY_SOURCES = ("true", "zero", "command")
# what the robot measures or knows by itself: an actor whose spec uses only these runs on the robot
ROBOT_SENSORS = ("imu", "encoders", "clock", "command", "policy", "calibration")


@dataclasses.dataclass(frozen=True)
class Entry:
    """One named block of a vector: its components (element names, in order), their units and the
    sensor the block comes from (SENSORS)."""

    name: str
    components: tuple[str, ...]
    units: tuple[str, ...]
    sensor: str
    doc: str = ""

    def __post_init__(self):
        if len(self.units) != len(self.components):
            raise ValueError(f"{self.name}: {len(self.components)} components but {len(self.units)} units")
        if self.sensor not in SENSORS:
            raise ValueError(f"{self.name}: unknown sensor {self.sensor!r}; choose from {SENSORS}")

    @property
    def size(self) -> int:
        return len(self.components)


def entry(
    name: str, components: Sequence[str], unit: str | Sequence[str], sensor: str, doc: str = ""
) -> Entry:
    """An Entry whose components share `unit` (a str) or have one unit each (a sequence)."""
    components = tuple(components)
    units = (unit,) * len(components) if isinstance(unit, str) else tuple(unit)
    return Entry(name, components, units, sensor, doc)


@dataclasses.dataclass(frozen=True)
class Spec:
    """An ordered list of entries: a flat vector of `size` values."""

    entries: tuple[Entry, ...]

    @property
    def size(self) -> int:
        return sum(e.size for e in self.entries)

    @property
    def names(self) -> tuple[str, ...]:
        """Every element's name, in order: "entry.component"."""
        return tuple(f"{e.name}.{c}" for e in self.entries for c in e.components)

    def slices(self) -> dict[str, slice]:
        """Entry name -> its slice of the vector."""
        out, start = {}, 0
        for e in self.entries:
            out[e.name] = slice(start, start + e.size)
            start += e.size
        return out

    def assemble(self, parts: Mapping):
        """parts: entry name -> (..., size) array, numpy or JAX (every entry, no other) ->
        (..., self.size), the entries concatenated in order. Raises ValueError for a missing or
        unknown entry or a wrong size (shapes are static, so also under jit)."""
        names = [e.name for e in self.entries]
        if set(parts) != set(names):
            missing, extra = sorted(set(names) - set(parts)), sorted(set(parts) - set(names))
            raise ValueError(f"observation parts: missing {missing}, unknown {extra}")
        for e in self.entries:
            if parts[e.name].shape[-1:] != (e.size,):
                raise ValueError(f"{e.name} has shape {parts[e.name].shape}, the spec says (..., {e.size})")
        xp = namespace(*(parts[n] for n in names))
        return xp.concat([parts[n] for n in names], axis=-1)

    def split(self, vector) -> dict:
        """(..., size) -> entry name -> (..., entry size), the inverse of `assemble`."""
        if vector.shape[-1] != self.size:
            raise ValueError(f"vector has {vector.shape[-1]} values, the spec has {self.size}")
        return {name: vector[..., s] for name, s in self.slices().items()}

    def sensors(self) -> set[str]:
        return {e.sensor for e in self.entries}

    def robot_measurable(self) -> bool:
        """True when every entry comes from a sensor the robot has (ROBOT_SENSORS)."""
        return self.sensors() <= set(ROBOT_SENSORS)

    def to_json(self) -> str:
        return json.dumps([dataclasses.asdict(e) for e in self.entries])

    @classmethod
    def from_json(cls, text: str) -> Spec:
        return cls(tuple(Entry(**{**d, "components": tuple(d["components"]), "units": tuple(d["units"])}) for d in json.loads(text)))  # fmt: skip

    def describe(self) -> str:
        """One line for people: "name (size) [unit] from sensor; ..."."""
        parts = []
        for e in self.entries:
            units = e.units[0] if len(set(e.units)) == 1 else ", ".join(e.units)
            parts.append(f"{e.name} ({e.size}) [{units or '-'}] from {e.sensor}")
        return "; ".join(parts)


COMMAND = entry(
    "command", ("vx", "vy", "yaw_rate"), ("m/s", "m/s", "rad/s"), "command", "body-frame velocity command"
)


def locomotion_observation(legs: Sequence[str], motor_joints: Sequence[str], command_tracking: bool) -> Spec:
    """The locomotion task's observation (seed 000's 29 values, + the command when tracking one):
    base orientation (ZYX roll, pitch, yaw of the IMU), base linear velocity in the body frame (no
    sensor measures it: a state estimator on the robot, the simulator's true value in training),
    gyroscope (body frame), the motor encoders (motor_joints order, legs x motors), sin and cos of
    each leg's gait phase (2 pi phase; the robot's code forgot the 2 pi), and the command."""
    entries = [
        entry("base_rpy", ("roll", "pitch", "yaw"), "rad", "imu", "IMU orientation, ZYX angles"),
        entry("base_lin_vel", ("x", "y", "z"), "m/s", "estimator", "base velocity, body frame"),
        entry("base_ang_vel", ("x", "y", "z"), "rad/s", "imu", "gyroscope, body frame"),
        entry("motor_pos", tuple(motor_joints), "rad", "encoders", "motor angles"),
        entry("phase_sin", tuple(legs), "", "clock", "sin(2 pi phase) of each leg's gait phase"),
        entry("phase_cos", tuple(legs), "", "clock", "cos(2 pi phase)"),
    ]
    if command_tracking:
        entries.append(COMMAND)
    return Spec(tuple(entries))


def locomotion_action(legs: Sequence[str], gait_action: bool, action_scale_m: float) -> Spec:
    """The locomotion task's action in [-1, 1]: a foot offset (x, y, z) per leg in the robot's gait
    frames, times action_scale_m, added to the gait's foot targets; with gait_action two more that
    scale the gait's step length and cycle frequency by 1 + range * a."""
    unit = f"{action_scale_m:g} m"
    entries = [
        entry(
            "foot_offset", tuple(f"{leg}.{a}" for leg in legs for a in "xyz"), unit, "policy", "gait frames"
        )
    ]
    if gait_action:
        entries.append(entry("gait_scale", ("step_length", "frequency"), "", "policy", "1 + range * a"))
    return Spec(tuple(entries))


# entries of the sensor observation that are also observed at earlier ticks when history > 1
HISTORY_ENTRIES = ("gravity", "gyro", "motor_pos", "motor_vel", "last_action")


def lagged(name: str, lag: int) -> str:
    """The name of entry `name` observed `lag` control ticks ago ("gyro@-2"); lag 0 is the name."""
    return name if lag == 0 else f"{name}@-{lag}"


def unlagged(name: str) -> str:
    """The entry that `name` is an earlier tick of ("gyro@-2" -> "gyro"); a current entry's own name."""
    return name.split("@-", 1)[0]


def sensor_observation(
    legs: Sequence[str],
    motor_joints: Sequence[str],
    action_size: int,
    history: int = 1,
    command: bool = True,
    yaw_error: bool = False,
    servo_latency: bool = False,
) -> Spec:
    """The actor's observation from the robot's own sensors only (ROBOT_SENSORS): the IMU's gravity
    direction in the body frame (no absolute yaw) and gyroscope, the motor encoders' angles and their
    velocity by difference over one control tick, the policy's last action, sin and cos of each leg's
    gait phase, and the command (command=False: a policy of one gait at its own speed, which observes
    none). history > 1 adds the IMU, encoder and action entries of the
    history - 1 ticks before, newest first ("gyro@-1", ..., HISTORY_ENTRIES). yaw_error adds, last,
    a leaky integral of the gyro's yaw rate minus the commanded yaw rate (yaw_error_step):
    how far the body has turned off the commanded turn over the last time constant. servo_latency
    adds, last, the servos' actuation latency as measured on the robot (SERVO_LATENCY)."""
    if history < 1:
        raise ValueError(f"history {history}: need at least 1 tick")
    if yaw_error and not command:
        raise ValueError("yaw_error needs the command")
    actions = tuple(f"a{i}" for i in range(action_size))
    base = {
        "gravity": entry("gravity", ("x", "y", "z"), "1", "imu", "unit gravity direction, body frame"),
        "gyro": entry("gyro", ("x", "y", "z"), "rad/s", "imu", "gyroscope, body frame"),
        "motor_pos": entry("motor_pos", tuple(motor_joints), "rad", "encoders", "motor angles"),
        "motor_vel": entry(
            "motor_vel",
            tuple(motor_joints),
            "rad/s",
            "encoders",
            "encoder difference over one tick / ctrl_dt",
        ),
        "last_action": entry("last_action", actions, "", "policy", "the action of the previous tick"),
    }
    entries = list(base.values())
    for lag in range(1, history):
        entries += [dataclasses.replace(base[n], name=lagged(n, lag)) for n in HISTORY_ENTRIES]
    entries += [
        entry("phase_sin", tuple(legs), "", "clock", "sin(2 pi phase) of each leg's gait phase"),
        entry("phase_cos", tuple(legs), "", "clock", "cos(2 pi phase)"),
    ]
    if command:
        entries.append(COMMAND)
    if yaw_error:
        entries.append(YAW_ERROR)
    if servo_latency:
        entries.append(SERVO_LATENCY)
    return Spec(tuple(entries))


YAW_ERROR = entry(
    "yaw_error",
    ("z",),
    "rad",
    "imu",
    "leaky integral of gyro z - commanded yaw rate (time constant: env config yaw_error_tau_s)",
)


SERVO_LATENCY = entry(
    "servo_latency",
    ("measured",),
    "s",
    "calibration",
    "the servos' actuation latency, measured on the robot before it walks (the deploy loop's "
    "servo_latency_s); in training the episode's latency with the calibration's error "
    "(env sensor.servo_latency_error_s)",
)


def yaw_error_step(previous, gyro_z, command_yaw_rate, ctrl_dt: float, tau_s: float):
    """The yaw_error entry one control tick on [rad]: previous * exp(-ctrl_dt / tau_s) + ctrl_dt *
    (gyro_z - command_yaw_rate); 0 at an episode's first tick (the deploy loop's: after a reset or a
    resync), this step from the second on. The gyro's
    reading includes its bias: b rad/s of bias settle at b * ctrl_dt / (1 - exp(-ctrl_dt / tau_s))
    rad, about b * tau_s. numpy or JAX arrays alike (the environment and the deploy loop)."""
    return math.exp(-ctrl_dt / tau_s) * previous + ctrl_dt * (gyro_z - command_yaw_rate)


def getup_observation(motor_joints: Sequence[str]) -> Spec:
    """The get-up task's observation, from the robot's own sensors only (ROBOT_SENSORS): the IMU's
    gravity direction in the body frame and gyroscope, the motor encoders' angles, the policy's last
    action. No clock and no command: a get-up does not follow the gait."""
    motor_joints = tuple(motor_joints)
    return Spec(
        (
            entry("gravity", ("x", "y", "z"), "1", "imu", "unit gravity direction, body frame"),
            entry("gyro", ("x", "y", "z"), "rad/s", "imu", "gyroscope, body frame"),
            entry("motor_pos", motor_joints, "rad", "encoders", "motor angles"),
            entry(
                "last_action",
                tuple(f"a{i}" for i in range(len(motor_joints))),
                "",
                "policy",
                "the action of the previous tick",
            ),
        )
    )


def getup_action(motor_joints: Sequence[str]) -> Spec:
    """The get-up task's action in [-1, 1]: one motor target per motor, 0 the home stance, -1 / +1
    the motor's lower / upper limit, linear in between, then the five-bar's guards
    (chain_guard.getup_targets, deploy_supervisor.getup_targets)."""
    return Spec(
        (
            entry(
                "motor_target",
                tuple(motor_joints),
                "",
                "policy",
                "0: home, -1: lower limit, +1: upper limit (then the five-bar's guards)",
            ),
        )
    )


def privileged_observation(legs: Sequence[str], actor: Spec, scan_points: int = 0) -> Spec:
    """The critic's observation (asymmetric actor-critic): the actor's entries, then what only the
    simulator knows: the base's true velocity and height above the ground under it, each foot's
    contact and height above the ground under it, the ground under each foot relative to the ground
    under the base, and the episode's randomized physics and sensor parameters; with scan_points n
    > 0 last an n x n grid of ground heights around the base (terrain.ground_scan)."""
    legs = tuple(legs)
    sim = [
        entry("true_lin_vel", ("x", "y", "z"), "m/s", "simulator", "base velocity, body frame"),
        entry("true_ang_vel", ("x", "y", "z"), "rad/s", "simulator", "base angular velocity, body frame"),
        entry("base_height", ("z",), "m", "simulator", "base origin above the ground under it"),
        entry("foot_contact", legs, "", "simulator", "1 when the foot touches the ground"),
        entry("foot_clearance", legs, "m", "simulator", "foot above the ground under it"),
        entry("ground_under_feet", legs, "m", "simulator", "ground under each foot - ground under the base"),
        entry(
            "physics",
            ("friction", "mass_scale", "motor_strength", "actuation_latency"),
            ("", "", "", "s"),
            "simulator",
            "the episode's randomized model",
        ),
        entry(
            "sensor_model",
            ("gyro_bias.x", "gyro_bias.y", "gyro_bias.z", "imu_tilt.roll", "imu_tilt.pitch", "latency"),
            ("rad/s", "rad/s", "rad/s", "rad", "rad", "s"),
            "simulator",
            "the episode's sensor errors",
        ),
    ]
    if scan_points:
        cells = tuple(f"{i}.{j}" for i in range(scan_points) for j in range(scan_points))
        sim.append(
            entry(
                "ground_scan",
                cells,
                "m",
                "simulator",
                "ground around the base (heading frame) - ground under it",
            )
        )
    return Spec(tuple(actor.entries) + tuple(sim))
