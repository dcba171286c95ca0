"""Every number of the Caramel model (seed 003), in SI units, with its source.

Sources, named at each number:
  * "seed 003": the paper (kinematics, gait and experiment settings, Tables I-III).
  * "robots.md": the project's reference notes on the robot's published code and numbers
    (hip spacing, stance height, link lengths, total mass, servo torque and speed, joint limits).
  * "MX-28 datasheet": ROBOTIS e-manual of the Dynamixel MX-28 (Protocol 1.0 control table).
  * "assumed": this project's choice where no source gives the number; randomize these.
models/caramel/README.md repeats the table with the reasoning.

Frames: body x forward, y left, z up, origin at the centre of the four hips (the hips lie in the
body's z = 0 plane). Each hip frame is the body frame translated to that hip (quadson_mjx.serial).
"""

from __future__ import annotations

import math

import numpy as np

from quadson_mjx import serial
from quadson_mjx.mjcf import actuator_name, foot_name, joint_name

# --- geometry [m] ---------------------------------------------------------------------------------
HIP_SPACING_X = 0.2291  # L, front to rear hip (robots.md)
HIP_SPACING_Y = 0.140  # W, left to right hip (robots.md)
STANCE_HEIGHT = 0.170  # hip to foot centre, standing (robots.md; the IK vectors' z = -0.17)
LEG = serial.CARAMEL  # L1 = 0.048 (hip offset), L2 = L3 = 0.120 (femur, tibia) (robots.md, seed 003)
FOOT_RADIUS = 0.010  # rubber foot sphere (assumed); the foot point of the kinematics is its centre

# --- names and leg order: the same as Quadson's (quadson_mjx.robots.quadson.constants.LEGS) ----------------------
LEGS: tuple[str, ...] = ("FL", "FR", "RL", "RR")
NUM_LEGS = 4
IS_FRONT = np.array([True, True, False, False])
IS_LEFT = np.array([True, False, True, False])
SIDE = np.where(IS_LEFT, serial.LEFT, serial.RIGHT)  # (4,) +1 left, -1 right (serial.py's `side`)
JOINTS: tuple[str, ...] = serial.JOINTS  # ("hip_roll", "hip_pitch", "knee"): q1, q2, q3 of serial.py
# Hip (roll-axis origin) positions in the body frame, (4, 3), leg order LEGS.
HIP_POS = np.stack(
    [
        np.where(IS_FRONT, 0.5, -0.5) * HIP_SPACING_X,
        np.where(IS_LEFT, 0.5, -0.5) * HIP_SPACING_Y,
        np.zeros(NUM_LEGS),
    ],
    axis=-1,
)
# Diagonal pairs of the trot (seed 003 Fig. 2 / robots.md: FR + RL swing, then FL + RR).
TROT_PAIRS: tuple[tuple[str, str], ...] = (("FR", "RL"), ("FL", "RR"))


JOINT_NAMES: tuple[str, ...] = tuple(joint_name(leg, p) for leg in LEGS for p in JOINTS)
ACTUATORS: tuple[str, ...] = tuple(actuator_name(leg, p) for leg in LEGS for p in JOINTS)
FEET: tuple[str, ...] = tuple(foot_name(leg) for leg in LEGS)
ROOT_BODY = "base"
IMU_SITE = "imu"
HOME_KEYFRAME = "home"

# --- joint limits [rad]: (3, 2) rows (lo, hi) for q1, q2, q3 of serial.py --------------------------
# The robot's command limits (roll +-pi/4, pitch +-pi/3, knee +-pi/5; robots.md) in serial.py's angles:
# q1 in [-pi/4, pi/4], q2 in [-pi/12, 7 pi/12], q3 in [-7 pi/10, -3 pi/10].
JOINT_LIMITS = np.asarray(serial.CARAMEL_LIMITS, dtype=float)

# --- masses [kg] (total 2.2 kg: robots.md "about 2.2 kg"; the split is assumed) -------------------
# Twelve MX-28 servos weigh 12 x 0.077 = 0.924 kg (MX-28 datasheet: 77 g). Seed 003 puts "the majority
# of its mass in the body or as close to it as possible" and the knee servo "in the upper part of the
# femur", driving the tibia through a rod. Assumed split:
#   base 1.50: ABS frame, Raspberry Pi 4, battery, MPU6050, the four hip-roll servos (4 x 0.077);
#   hip bracket 0.12 per leg: rotates with the roll joint, carries the pitch and knee servos (2 x 0.077);
#   femur 0.035 per leg: printed link and the knee push rod;
#   tibia 0.020 per leg: printed link and the rubber foot.
BASE_MASS = 1.50
HIP_MASS = 0.12
FEMUR_MASS = 0.035
TIBIA_MASS = 0.020
TOTAL_MASS = BASE_MASS + NUM_LEGS * (HIP_MASS + FEMUR_MASS + TIBIA_MASS)  # 2.2
SERVO_MASS = 0.077  # MX-28 datasheet

# --- shapes for inertia, collision and drawing [m] (assumed, sized to the hip spacing) -------------
BASE_HALF_SIZE = (0.145, 0.055, 0.035)  # solid box: the base's inertia; reaches past the hips in x
HIP_HALF_SIZE = (0.036, 0.020, 0.025)  # bracket around the two leg servos, centred at the femur joint
LINK_RADIUS = 0.008  # capsules drawn for femur and tibia; thin rods for inertia

# --- Dynamixel MX-28 position servo --------------------------------------------------------------
# Datasheet (MX-28, 12 V): stall torque 2.5 N m at 1.4 A, no-load speed 55 rpm, gear ratio 193:1,
# 4096 encoder counts per turn. Protocol 1.0 control table: P gain default 32 (D and I default 0), and
# the controller's proportional gain is Kp = P / 8 [PWM counts per encoder count]; the PWM output
# ("Torque Limit" scale) saturates at 1023 counts = 100 % duty.
DATASHEET_STALL_TORQUE = 2.5  # [N m] at 12 V (MX-28 datasheet)
DATASHEET_NO_LOAD_SPEED = 55.0 * 2.0 * math.pi / 60.0  # [rad/s] = 5.76 at 12 V (MX-28 datasheet)
GEAR_RATIO = 193.0  # MX-28 datasheet
ENCODER_COUNTS = 4096  # per turn (MX-28 datasheet: 12 bit, 0.088 deg)
P_GAIN = 32  # default P gain (MX-28 control table)
PWM_FULL_SCALE = 1023  # 100 % duty (MX-28 control table's torque scale)
# The model's torque limit and speed: robots.md (2 N m, 5.75 rad/s), the numbers of the robot as run;
# 2 N m is the datasheet's 12 V stall torque derated (the MX-28 gives 2.3 N m at 11.1 V).
EFFORT_LIMIT = 2.0  # [N m] -> actuator forcerange
VELOCITY_LIMIT = 5.75  # [rad/s] (robots.md); MuJoCo has no velocity limit, reported only
# A voltage-driven DC motor behind a gearbox gives output torque tau = tau_stall (duty - w / w0):
# the duty term is the position loop, the -w / w0 term is back-EMF damping. With duty = Kp e / 1023,
# e in encoder counts = q_err 4096 / (2 pi):
#   kp = tau_stall (P / 8) (4096 / 2 pi) / 1023 = 2.5 x 4 x 651.9 / 1023 = 6.37 N m / rad
#        (the full 2.5 N m at 0.39 rad = 22.5 deg of error);
#   damping = tau_stall / w0 = 2.5 / 5.76 = 0.434 N m s / rad (joint damping: acts at any duty).
# That the P term reaches full duty at 1023 counts is this project's reading of the control table
# (assumed; the e-manual gives no torque unit for Kp). The firmware's D gain defaults to 0: kv = 0.
SERVO_KP = DATASHEET_STALL_TORQUE * (P_GAIN / 8.0) * (ENCODER_COUNTS / (2.0 * math.pi)) / PWM_FULL_SCALE
SERVO_DAMPING = DATASHEET_STALL_TORQUE / DATASHEET_NO_LOAD_SPEED
SERVO_KV = 0.0
# Reflected rotor inertia: J_rotor N^2 with a rotor of 8.6e-8 kg m^2 (assumed: the order of a 17 mm
# coreless motor's rotor, the MX-28's motor class) and N = 193: 3.2e-3 kg m^2.
ROTOR_INERTIA = 8.6e-8  # [kg m^2] (assumed)
SERVO_ARMATURE = ROTOR_INERTIA * GEAR_RATIO**2
SERVO_FRICTIONLOSS = 0.0  # gearbox Coulomb friction: unknown, not modelled

# --- ground contact and solver: Quadson's (models/quadson/README.md) ------------------------------
GROUND_FRICTION = (0.8, 0.1, 0.01)  # (sliding, torsional [m], rolling [m])
RESTITUTION = 0.2
CONTACT_DAMPING_RATIO = -math.log(RESTITUTION) / math.sqrt(math.pi**2 + math.log(RESTITUTION) ** 2)
CONTACT_TIMECONST = 0.02  # [s]
CONTACT_CONDIM = 3
SIM_DT = 0.004  # [s]; 5 physics steps per 20 ms tick of seed 003's 50 Hz planner
SOLVER_ITERATIONS = 1
SOLVER_LS_ITERATIONS = 5
INTEGRATOR = "Euler"

# --- rough ground: Quadson's seeded loose-stone height map, at Caramel's scale ---------------------
# Seed 003's uneven terrain is "small loose stones" (Fig. 8b, no size given). The height map is
# quadson_mjx.mjcf.stone_field_heights() (8 x 8 m, stones 3-8 cm across, a flat 0.6 x 0.6 m patch at the
# origin); Caramel's scene scales its relief to 2 cm (assumed: less than half the 5 cm step height).
ROUGH_MAX_HEIGHT = 0.02  # [m]

# --- seed 003's planner and experiments ------------------------------------------------------------
TICK_S = 0.02  # 50 Hz (seed 003)
STEP_HEIGHT = 0.05  # [m] cycloid height H (seed 003; its "0.05 cm" in experiment 1 is 5 cm)
STEP_PERIOD = 0.5  # [s] T (seed 003); N = T / 0.02 = 25 points
TROT_P_T = 0.66  # seed 003, experiments 2 and 3
TROT_P_N = 0.33
