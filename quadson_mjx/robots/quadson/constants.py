"""Every number and name of the Quadson robot, in one place, in SI units (m, rad, s, kg).

Sources: the seed document "Quadson" (Spring 2025) and the robot's public code and CAD, which
publish centimetres; they are converted here once. Nothing else in the project hard-codes a
length, a limit, a leg order or a model name.

Frames (used everywhere in the project, also written down in docs/kinematics.md):
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

from quadson_mjx.mjcf import actuator_name, foot_name, joint_name

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

# Seed 003 (robots.md): trot with a 0.5 s cycloid swing, 5 cm height, P_T 0.66, P_N 0.33, a
# 0.05 m/s command, body shifts between swings. The shift duration is not published: this project
# takes shift = swing = 0.5 s (duty 0.75, cycle 2 s) and a 10 cm step, so the default speed
# step / cycle equals seed 003's 0.05 m/s command.
SEED_003_P_T = 0.66
SEED_003_P_N = 0.33
DISCONTINUOUS_TROT = {
    "phase_offset": GAITS["trot"]["phase_offset"],
    "cycle_s": 2.0,
    "duty": 0.75,
    "step_height_m": 0.05,
    "step_length_m": 0.10,
    "swing": "cycloid",
    "p_t": SEED_003_P_T,
    "p_n": SEED_003_P_N,
    "discontinuous": True,
}

# --- MJCF names: {LEG}_{part}_joint, actuators {LEG}_{part}, feet {LEG}_foot ---
MOTORS: tuple[str, ...] = ("motor0", "motor1", "motor5")  # t0 (abduction), t1 (at p1), t5 (at p5)
PASSIVE: tuple[str, ...] = ("knee2", "knee4")  # passive hinges at p2 and p4


MOTOR_JOINTS: tuple[str, ...] = tuple(joint_name(leg, m) for leg in LEGS for m in MOTORS)
ACTUATORS: tuple[str, ...] = tuple(actuator_name(leg, m) for leg in LEGS for m in MOTORS)
PASSIVE_JOINTS: tuple[str, ...] = tuple(joint_name(leg, p) for leg in LEGS for p in PASSIVE)
FEET: tuple[str, ...] = tuple(foot_name(leg) for leg in LEGS)
ROOT_BODY = "base"
IMU_SITE = "imu"
HOME_KEYFRAME = "home"


# ==================================================================================================
# Physics of the MuJoCo model (models/quadson/): masses, inertias, motor model, gains, contact and
# solver settings. The robot's public URDF has placeholder masses (7.8 kg in all) and no torque or
# speed limits, so the numbers below are chosen to be plausible for a ~3 kg 3D-printed robot of
# this size and are meant to be randomized (scale BASE_MASS, HIP_MASS, LINK_MASSES, MOTOR_KP, ...).
# models/quadson/README.md says where each number came from.
# ==================================================================================================

# --- masses [kg] (total 3.28 kg) ---
# base: printed frame ~0.42, 6S 2200 mAh LiPo ~0.35, computer + IMU + 12 motor drivers ~0.25, and
# the four abduction motors (motor 0, mounted on the frame) 4 x 0.12.
BASE_MASS = 1.5
# hip assembly (rotates with motor 0): the motor-1 and motor-5 actuators (2 x 0.12) + printed housing.
HIP_MASS = 0.3
# printed PLA links with bearings and screws: link 1 (p1-p2), link 2 (p2-p3-foot, with the rubber
# foot), link 4 (p4-p3), link 5 (p5-p4).
LINK_MASSES = {"link1": 0.03, "link2": 0.05, "link4": 0.035, "link5": 0.03}
TOTAL_MASS = BASE_MASS + NUM_LEGS * (HIP_MASS + sum(LINK_MASSES.values()))

# --- centre of mass [m] (an assumption, not a measurement: randomize it) ---
# The gait table puts the stance feet ahead of the body centre. At the trot's stance midpoint (the
# `home` pose) the front feet are at body x = 15.3 - 2 = 13.3 cm and the rear feet at -15.3 + 7 =
# -8.3 cm: the centre of support is SUPPORT_CENTRE_X = +2.5 cm. A gait table tuned on hardware
# carries the CoM near its support centre; with the CoM at the body centre (the legs alone put it at
# +0.21 cm) every gait fell nose-up in 1-3.5 s (models/quadson/README.md, "Centre of mass").
# Assumed layout: the battery and the electronics (0.6 kg of the base) sit forward in the frame,
# their mean at +12.5 cm (the base box reaches +17 cm), so the base's own CoM is at
# (0.35 + 0.25) x 0.125 / 1.5 = +5.0 cm. Derivation of the number: the legs at home contribute
# 3.28 kg x 0.00213 m = 0.0070 kg m (compiled model, base CoM at 0), and
# (3.28 x 0.025 - 0.0070) / 1.5 = 0.0500 m puts the whole robot's CoM on SUPPORT_CENTRE_X
# (tests/test_model.py). Open-loop trot and walk stay up for BASE_COM_X in [0.02, 0.07] m and fall
# at 0: randomize within about +-2 cm.
_HOME_FOOT_X = STANCE_START_X + STANCE_DIRECTION * 0.5 * GAITS["trot"]["step_length_m"]  # leg frame
SUPPORT_CENTRE_X = float(np.mean(SHOULDER_POS[:, 0] + SHOULDER_ROT[:, 0, 0] * _HOME_FOOT_X))  # 0.025
BASE_COM_X = 0.05  # base CoM ahead of the body centre (base frame x)

# --- shapes used for inertia, collision and drawing [m] ---
BASE_HALF_SIZE = (0.17, 0.08, 0.04)  # box around the frame; its inertia is a solid box's
HIP_HALF_SIZE = (L0 / 2 + 0.025, 0.025, 0.02)  # box spanning both hip motors (leg frame x, y, z)
LINK_RADIUS = 0.006  # capsules drawn for the links; links are thin rods for inertia
FOOT_RADIUS = 0.015  # rubber foot sphere at the end of link 2

# --- motor model (all 12 motors identical) ---
# A 5010-size brushless outrunner (KV 200 rpm/V) behind an 8:1 printed planetary gearbox, driven by
# a field-oriented-control board in position mode: the class of actuator the robot's firmware
# addresses (CAN position/velocity/current goals, gear ratio and pole pairs as parameters).
MOTOR_KV_RPM_PER_V = 200.0
MOTOR_KT = 60.0 / (2.0 * math.pi * MOTOR_KV_RPM_PER_V)  # torque constant [N m / A] = 0.0477
MOTOR_PEAK_CURRENT = 10.0  # [A], driver limit
GEAR_RATIO = 8.0
GEAR_EFFICIENCY = 0.9
SUPPLY_VOLTAGE = 24.0  # [V], 6S LiPo
ROTOR_INERTIA = 2.5e-5  # [kg m^2], 5010 rotor: ~45 g ring at ~23 mm radius
# output torque limit [N m] = 0.0477 * 10 * 8 * 0.9 = 3.44
MOTOR_EFFORT_LIMIT = MOTOR_KT * MOTOR_PEAK_CURRENT * GEAR_RATIO * GEAR_EFFICIENCY
# no-load output speed [rad/s] = 200 rpm/V * 24 V / 8 = 62.8; at full torque the back-EMF leaves
# about half of it: 31.4 rad/s. MuJoCo has no velocity limit; the env may penalize |qvel| above it.
MOTOR_VELOCITY_LIMIT = 0.5 * MOTOR_KV_RPM_PER_V * SUPPLY_VOLTAGE * 2.0 * math.pi / 60.0 / GEAR_RATIO
MOTOR_ARMATURE = ROTOR_INERTIA * GEAR_RATIO**2  # reflected rotor inertia [kg m^2] = 1.6e-3
MOTOR_DAMPING = 0.01  # gearbox viscous friction [N m s / rad]
# Position-servo gains as mjlab derives them: a second-order joint of inertia MOTOR_ARMATURE
# tuned to natural frequency f_n and damping ratio zeta: kp = J w^2, kd = 2 zeta J w.
MOTOR_NATURAL_FREQ = 2.0 * math.pi * 20.0  # [rad/s]
MOTOR_DAMPING_RATIO = 1.0
MOTOR_KP = MOTOR_ARMATURE * MOTOR_NATURAL_FREQ**2  # [N m / rad]
MOTOR_KD = 2.0 * MOTOR_DAMPING_RATIO * MOTOR_ARMATURE * MOTOR_NATURAL_FREQ  # [N m s / rad]

# --- passive hinges at p2 and p4 (printed bearings, no rotor) ---
PASSIVE_ARMATURE = 1e-5  # [kg m^2], small numerical armature that helps the closed loop
PASSIVE_DAMPING = 0.001  # [N m s / rad]

# --- ground contact (seed 000 section 8: lateral 0.8, spinning 0.1, rolling 0.01, restitution 0.2) ---
# Bullet and MuJoCo both bound the spinning/rolling friction torque by coefficient x normal force,
# so the coefficients carry over as lengths [m]; with condim 3 (the MJX choice) only sliding acts.
GROUND_FRICTION = (0.8, 0.1, 0.01)  # (sliding, torsional [m], rolling [m])
RESTITUTION = 0.2
# MuJoCo has no restitution: a contact is a damped spring whose damping ratio zeta sets the bounce,
# e = exp(-pi zeta / sqrt(1 - zeta^2)), so zeta = -ln e / sqrt(pi^2 + ln^2 e) = 0.456 for e = 0.2.
CONTACT_DAMPING_RATIO = -math.log(RESTITUTION) / math.sqrt(math.pi**2 + math.log(RESTITUTION) ** 2)
CONTACT_TIMECONST = 0.02  # [s], MuJoCo's default contact stiffness time constant
CONTACT_CONDIM = 3

# --- solver (chosen by measurement, models/quadson/README.md) ---
SIM_DT = 0.004  # [s]; 5 physics steps per 0.02 s control step
SOLVER_ITERATIONS = 1
SOLVER_LS_ITERATIONS = 5
INTEGRATOR = "Euler"
CLOSURE_SOLREF = (0.008, 1.0)  # (time constant [s] = 2 SIM_DT, the stiffest MuJoCo allows; damping ratio)
# impedance 0.9999 (MuJoCo's maximum): the closure's softness R = (1 - d) / d x (constraint-space
# inverse mass) is large for these light links, and d = 0.95 left 0.4-0.7 mm of sag standing.
CLOSURE_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)

# --- rough terrain (seed 003's "ground formed by small loose stones") ---
# the stone field's map is both robots' (quadson_mjx.mjcf.stone_field_heights); its relief is each robot's
ROUGH_MAX_HEIGHT = 0.04  # relief [m]
