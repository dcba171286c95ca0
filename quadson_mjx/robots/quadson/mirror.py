"""Quadson's left-right mirror symmetry: the reflection across the body's xz plane, as maps of its
motor angles, its get-up policy's observation and action, and the simulator's qpos.

The robot is mirror-symmetric (the model's geoms at home are mirror images to 0 m; tested on random
poses in tests/test_mirror.py): the reflection swaps the left and right legs (FL <-> FR, RL <-> RR),
negates each abduction angle t0 (it turns the leg plane about the body's x axis) and keeps the
in-plane angles t1, t5 and the passive knees (their axes lie along the body's y axis). Vectors
change as a reflection does: a polar vector (position, gravity direction) negates its y, an axial
vector (angular velocity) negates its x and z. The home stance has t0 = 0 and T0_RANGE is symmetric
about it, so a get-up action (0 home, -1 / +1 each limit) mirrors as the angles do.

Used to run a get-up policy mirrored (deploy_supervisor.GetupPolicy(mirror=True) and
getup_eval's "mirror" mode): a policy that gets up well from one side gets the other side's fall
as its mirror image. Works on numpy and JAX arrays alike (indexing and a sign vector only).
"""

from __future__ import annotations

import numpy as np

from quadson_mjx.robots.quadson import constants as C

LEG_SWAP = (1, 0, 3, 2)  # FL, FR, RL, RR -> the leg whose mirror image each is
assert [C.LEGS[i] for i in LEG_SWAP] == ["FR", "FL", "RR", "RL"]

_MOTOR_INDEX = np.array([3 * leg + k for leg in LEG_SWAP for k in range(3)])
_MOTOR_SIGN = np.tile([-1.0, 1.0, 1.0], 4)  # t0 negated, t1 and t5 kept
# getup_observation: gravity (3), gyro (3), motor_pos (12), last_action (12)
_OBS_INDEX = np.concatenate([np.arange(6), 6 + _MOTOR_INDEX, 18 + _MOTOR_INDEX])
_OBS_SIGN = np.concatenate([[1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], _MOTOR_SIGN, _MOTOR_SIGN])
OBS_SIZE = len(_OBS_INDEX)  # 30


MIRROR_TO = (None, "left", "right")
TRAINED = "trained"  # a mirror_to argument: the side the policy was trained on (resolve_mirror_to)


def wants_mirror(gravity_y, mirror_to: str | None):
    """Whether a get-up attempt runs on the mirror image, from gravity's body y at its start (a
    scalar or an array, numpy or JAX): mirror_to "left" mirrors when the right side is lower
    (gravity_y < 0), so the policy always meets the left side's fall; "right" the other way; None
    never."""
    if mirror_to not in MIRROR_TO:
        raise ValueError(f"mirror_to {mirror_to!r}; choose from None, 'left', 'right'")
    if mirror_to == "left":
        return gravity_y < 0
    if mirror_to == "right":
        return gravity_y > 0
    return (gravity_y < 0) & False  # never, in gravity_y's shape and array kind


def parse_mirror_to(text: str):
    """A command line's --mirror-to: "trained" (TRAINED), "none" (None), "left" or "right";
    ValueError for anything else."""
    choices = {TRAINED: TRAINED, "none": None, "left": "left", "right": "right"}
    if text not in choices:
        raise ValueError(f"--mirror-to {text}: choose from {', '.join(choices)}")
    return choices[text]


def trained_mirror_to(env_config) -> str | None:
    """The mirror_to a get-up policy was trained with: env.getup.mirror_to of its env config (a
    ConfigDict or the plain dict an export's meta carries); None for "none" or a config without it."""
    getup = env_config.get("getup", None) if env_config is not None else None
    side = getup.get("mirror_to", "none") if getup is not None else "none"
    return None if side == "none" else side


def resolve_mirror_to(requested, trained: str | None) -> str | None:
    """The mirror_to to run a policy trained with `trained` (trained_mirror_to) under: TRAINED gives
    the trained side; another value is taken as asked, unless the policy was trained on one side
    and the request differs, which would show it the other side's falls it never met: ValueError."""
    if requested == TRAINED:
        return trained
    wants_mirror(0.0, requested)  # a bad value: ValueError
    if trained is not None and requested != trained:
        raise ValueError(
            f"the get-up policy was trained mirrored to the {trained} (env.getup.mirror_to); "
            f"it runs with mirror_to {trained!r}, not {requested!r}"
        )
    return requested


def mirror_motors(x):
    """(..., 12) motor angles [rad], or get-up actions, in the robot's motor order -> their mirror
    image: legs swapped, t0 (and its action) negated."""
    return x[..., _MOTOR_INDEX] * _MOTOR_SIGN.astype(x.dtype)


def mirror_getup_observation(obs):
    """(..., 30) obs_spec.getup_observation -> the observation of the mirrored robot."""
    if obs.shape[-1] != OBS_SIZE:
        raise ValueError(f"mirror: a get-up observation has {OBS_SIZE} values, got {obs.shape[-1]}")
    return obs[..., _OBS_INDEX] * _OBS_SIGN.astype(obs.dtype)


def mirror_qpos(qpos, joint_names, qpos_adr):
    """(nq,) numpy qpos of the full model (free root joint first) -> the mirrored state's qpos.
    joint_names: the model's hinge joint names ("FL_motor0_joint", ...); qpos_adr: their qpos
    addresses. Root position (x, -y, z), root quaternion (w, -x, y, -z), each joint's value moved
    to its partner leg's joint, abduction joints negated."""
    out = np.array(qpos, np.float64, copy=True)
    out[1] = -qpos[1]
    out[3:7] = qpos[3:7] * np.array([1.0, -1.0, 1.0, -1.0])
    swap = {a: b for a, b in zip(C.LEGS, [C.LEGS[i] for i in LEG_SWAP], strict=True)}
    where = dict(zip(joint_names, qpos_adr, strict=True))
    for name, adr in where.items():
        leg, rest = name.split("_", 1)
        sign = -1.0 if rest == C.MOTORS[0] + "_joint" else 1.0
        out[where[f"{swap[leg]}_{rest}"]] = sign * qpos[adr]
    return out
