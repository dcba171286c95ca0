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
from collections.abc import Mapping, Sequence

from array_api_compat import array_namespace

# sensors an observation entry may come from; "simulator" entries are what only a simulator knows
SENSORS = ("imu", "encoders", "estimator", "clock", "command", "policy")


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
        xp = array_namespace(*(parts[n] for n in names))
        return xp.concat([parts[n] for n in names], axis=-1)

    def split(self, vector) -> dict:
        """(..., size) -> entry name -> (..., entry size), the inverse of `assemble`."""
        if vector.shape[-1] != self.size:
            raise ValueError(f"vector has {vector.shape[-1]} values, the spec has {self.size}")
        return {name: vector[..., s] for name, s in self.slices().items()}

    def sensors(self) -> set[str]:
        return {e.sensor for e in self.entries}

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
