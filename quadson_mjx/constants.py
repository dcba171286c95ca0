"""Every number and name of the Quadson robot, in one place, in SI units (m, rad, s, kg).

Sources: the seed document "Quadson" (Spring 2025) and the robot's public code and CAD, which
publish centimetres; they are converted here once. Nothing else in the project hard-codes a
length, a limit, a leg order or a model name.

Frames (used everywhere in the project, also written down in the README):
  * world: z up, gravity -z (MuJoCo's convention).
  * body: origin at the body centre, x forward, y left, z up.
  * shoulder (leg) frame, one per leg, as in the seed: origin at p1 (motor 1's axis), x along the
    line p1 -> p5 (motor 5's axis), y up (a standing foot has y < 0), z = x cross y. Motor 0
    (abduction) rotates the whole leg plane about this x axis. Front legs' x points to body -x,
    rear legs' x to body +x, y is body z in both; so z is body +y for front legs and body -y for
    rear legs.
  * motor angles (t0, t1, t5) as in seed Algorithm 1: t1, t5 measured in the leg plane from +x,
    clockwise when seen from +z (p2 = L1 (cos t1, -sin t1)); t0 rotates the plane about +x.
"""

from __future__ import annotations

import math

import numpy as np

CM = 0.01  # the seeds' unit, converted once here

# --- leg order: one order for the whole project (the seed's observation order LF, RF, LH, RH) ---
LEGS: tuple[str, ...] = ("FL", "FR", "RL", "RR")
NUM_LEGS = 4
IS_FRONT = np.array([True, True, False, False])
IS_LEFT = np.array([True, False, True, False])

# --- five-bar link lengths (seed 000; robots.md) ---
L0 = 8.16 * CM  # p1 - p5, between the two hip motors
L1 = 8.0 * CM  # p1 - p2 (driven by motor 1)
L2 = 10.0 * CM  # p2 - p3
L3 = 8.0 * CM  # p3 - foot; the p2 link runs straight on through p3 to the foot
L4 = 13.0 * CM  # p4 - p3
L5 = 8.0 * CM  # p5 - p4 (driven by motor 5)
LINK_LENGTHS = (L0, L1, L2, L3, L4, L5)

# --- motor limits of the real robot [rad] ---
T0_RANGE = (-math.pi / 2, math.pi / 2)
T1_RANGE = (0.25 * math.pi, 1.2 * math.pi)
T5_RANGE = (0.0, 0.75 * math.pi)
MOTOR_RANGES = np.array([T0_RANGE, T1_RANGE, T5_RANGE])  # (3, 2) rows t0, t1, t5
TOE_IN_MAX = 0.06  # guard of the robot's code: t5 - t1 <= 0.06 rad keeps the knees from crossing

# --- published reference pose (robots.md): (t0, t1, t5) = (0, pi, pi/2) ---
INITIAL_MOTOR_ANGLES = np.array([0.0, math.pi, math.pi / 2])

# --- body geometry ---
BODY_LENGTH = 30.6 * CM  # between front and rear shoulders
BODY_WIDTH = 22.4 * CM  # between left and right shoulders
# Shoulder (p1) positions in the body frame, (4, 3), leg order LEGS.
SHOULDER_POS = np.array(
    [
        [+BODY_LENGTH / 2, +BODY_WIDTH / 2, 0.0],
        [+BODY_LENGTH / 2, -BODY_WIDTH / 2, 0.0],
        [-BODY_LENGTH / 2, +BODY_WIDTH / 2, 0.0],
        [-BODY_LENGTH / 2, -BODY_WIDTH / 2, 0.0],
    ]
)
# Shoulder-frame axes expressed in the body frame: R[i] maps shoulder-frame vectors of leg i to the
# body frame, columns = (x_leg, y_leg, z_leg) in body coordinates.
_R_FRONT = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])  # x=-X, y=Z, z=+Y
_R_REAR = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # x=+X, y=Z, z=-Y
SHOULDER_ROT = np.stack([_R_FRONT, _R_FRONT, _R_REAR, _R_REAR])  # (4, 3, 3)

# --- gait table of the robot's code (robots.md), SI ---
STANCE_HEIGHT = 20.0 * CM  # base_y = -20 cm: foot 20 cm below the shoulder line
STANCE_START_X = np.array([-4.0, -4.0, 13.0, 13.0]) * CM  # leg-frame x where stance begins
STANCE_DIRECTION = np.array([1.0, 1.0, -1.0, -1.0])  # leg-frame x direction of stance motion


def _gait(offsets, cycle_s, duty, step_height_cm, step_length_cm):
    return {
        "phase_offset": tuple(offsets),  # per leg, in LEGS order, fraction of a cycle
        "cycle_s": cycle_s,
        "duty": duty,
        "step_height_m": step_height_cm * CM,
        "step_length_m": step_length_cm * CM,
    }


# The robot's code has pace = bound (0, 0, 0.5, 0.5); a pace moves same-side legs together, so
# pace here is FL+RL then FR+RR: offsets (0, 0.5, 0, 0.5). Timing numbers are the robot's.
GAITS: dict[str, dict] = {
    "walk": _gait((0.0, 0.5, 0.25, 0.75), 1.2, 0.75, 3.0, 8.0),
    "trot": _gait((0.0, 0.5, 0.5, 0.0), 0.8, 0.5, 5.0, 12.0),
    "pace": _gait((0.0, 0.5, 0.0, 0.5), 0.7, 0.5, 5.0, 12.0),
    "bound": _gait((0.0, 0.0, 0.5, 0.5), 0.6, 0.4, 8.0, 16.0),
    "gallop": _gait((0.1, 0.25, 0.6, 0.75), 0.5, 0.35, 7.0, 21.0),
}

# --- MJCF names: {LEG}_{part}_joint, actuators {LEG}_{part}, feet {LEG}_foot ---
MOTORS: tuple[str, ...] = ("motor0", "motor1", "motor5")  # t0 (abduction), t1 (at p1), t5 (at p5)
PASSIVE: tuple[str, ...] = ("knee2", "knee4")  # passive hinges at p2 and p4


def joint_name(leg: str, part: str) -> str:
    return f"{leg}_{part}_joint"


def actuator_name(leg: str, part: str) -> str:
    return f"{leg}_{part}"


def foot_name(leg: str) -> str:
    return f"{leg}_foot"


MOTOR_JOINTS: tuple[str, ...] = tuple(joint_name(leg, m) for leg in LEGS for m in MOTORS)
ACTUATORS: tuple[str, ...] = tuple(actuator_name(leg, m) for leg in LEGS for m in MOTORS)
PASSIVE_JOINTS: tuple[str, ...] = tuple(joint_name(leg, p) for leg in LEGS for p in PASSIVE)
FEET: tuple[str, ...] = tuple(foot_name(leg) for leg in LEGS)
ROOT_BODY = "base"
IMU_SITE = "imu"
HOME_KEYFRAME = "home"
