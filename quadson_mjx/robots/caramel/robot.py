"""Caramel as the environment sees it: serial legs, seed 003's discontinuous trot in the body frame.

The environment config values below are this project's choices for a robot a third slower and
smaller than Quadson (2.2 kg, hips 17 cm up, a 0.05 m/s trot), named with their reason.
"""

from __future__ import annotations

from quadson_mjx.robots import Robot
from quadson_mjx.robots.caramel import constants as C
from quadson_mjx.robots.caramel import gait, model

ROBOT = Robot(
    name="caramel",
    legs=C.LEGS,
    load_model=model.load_model,
    model_xml_text=model.model_xml_text,
    scene_path=model.scene_path,
    motor_joints=C.JOINT_NAMES,
    actuators=C.ACTUATORS,
    root_body=C.ROOT_BODY,
    home_keyframe=C.HOME_KEYFRAME,
    home_feet=gait.nominal_feet(),
    gait_names=gait.GAIT_NAMES,
    default_gait="trot_discontinuous",
    gait_params=gait.gait_params,
    foot_targets=gait.foot_targets,
    motor_targets=gait.joint_targets,
    tilt_feet=gait.tilt_feet,
    closure_residual=None,
    height_target_m=model.HOME_BASE_HEIGHT,  # 0.18 m, base origin at home
    gait_action=False,  # the trot's tick table needs a fixed phase length
    env_defaults={
        "swing": "cycloid",  # seed 003's (Quadson's default is the seed 000 Bezier)
        # offsets up to +-3 cm: a quarter of a 12 cm link (Quadson's 5 cm on 20 cm legs)
        "action_scale_m": 0.03,
        "reward.target_gait_speed": True,  # without commands: the trot's own 0.05 m/s forward
        # kernels sized to the 0.05 m/s gait: standing still under a 0.05 m/s command earns
        # exp(-0.78) = 46 % of the tracking reward (Quadson's 0.25 would give 98 %)
        "reward.forward_sigma": 0.04,
        "reward.tracking_sigma": 0.04,
        "termination.min_height_m": 0.08,  # seed 003's experiments: base below 8 cm is a fall
        # seed 003's commands (0.05 m/s forward, 0.25 rad/s turn) inside the range
        "command_range": {"vx": (-0.02, 0.08), "vy": (-0.03, 0.03), "yaw_rate": (-0.3, 0.3)},
        "push.speed_mps": (0.05, 0.15),  # a 2.2 kg robot at 0.05 m/s
    },
)
