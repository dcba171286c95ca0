"""The get-up task's part of the env config (`env.getup.*`): start states, success, reward weights.

`env_config(task="getup")` builds the get-up task (quadson_mjx.getup_env); every env config carries
these keys (a locomotion config ignores them), so that one rule table checks every config.
"""

from __future__ import annotations

import math

from quadson_mjx.config import Rule

# The success measure of the task: upright (tilt < 10 deg) with the base within 2 cm of the standing
# height, held for 1 s without a break, reached within 5 s of the drop. An episode runs the 5 s plus
# the 1 s hold, so that a stand reached at 5 s can still be confirmed.
SUCCESS = {
    "success_tilt_rad": math.radians(10.0),
    "success_height_m": 0.02,
    "success_hold_s": 1.0,
    "success_within_s": 5.0,
}
EPISODE_S = SUCCESS["success_within_s"] + SUCCESS["success_hold_s"]

# Reward terms of quadson_mjx.rewards.getup_terms, named <quantity>_<kernel> (a weight of 0 switches
# one off), after MuJoCo Playground's Go1 getup. The positive terms: upright_sq ((1 + cos tilt) / 2)^2,
# 1 upright, 0 on the back, with a slope all the way round so that a robot on its back is paid for
# rolling; height_lin the base height as a share of the standing height (capped at 1), everywhere,
# so that lying flat is never the best pose; height_exp and home_pose_exp count only once the base
# is within upright_gate_rad of upright (lifting one side is not standing); stand_still_exp pays a
# zero action (the home stance, chain_guard.getup_targets) once upright at the standing height. The penalties keep the motion gentle
# on a 3D-printed robot: motor speeds (and a hinge above the servo's no-load speed), action rate,
# torques, and a step on which two legs' collision geometry overlaps (the training model has no
# leg-leg contacts).
WEIGHTS = {
    "upright_sq": 1.0,
    "height_lin": 1.0,
    "height_exp": 1.0,
    "home_pose_exp": 1.0,
    "stand_still_exp": 1.0,
    "joint_speed_l2": -1e-4,
    "joint_speed_limit": -0.05,
    "action_rate_l2": -0.01,
    "torque_l2": -2e-3,
    "legs_overlap": -1.0,
}

GETUP = {
    "drop_height_m": (0.2, 0.5),  # lowest point of the robot above the ground under it [m]
    # share of training episodes that start standing at home instead of dropped (Playground's Go1
    # getup: 40 %): standing still is then a trained state, not only an end; evaluations drop always
    "stand_start_prob": 0.4,
    # share of those standing starts knocked over at once: the base given a tipping rate about a
    # random horizontal axis and the matching speed of a pivot on its feet (rate x the standing height),
    # as a shove leaves it. Standing at home with the home targets held, Quadson tipped faster than
    # 6 rad/s goes over 90 deg, slower than 2.5 rad/s stays within 20 deg (MuJoCo C,
    # tests/test_getup_env.py); a policy that acts during the fall can catch it or land on a side.
    # 0 here (the first get-up runs had none); env_config(task="getup") sets TOPPLE_PROB
    "topple_prob": 0.0,
    "topple_rate_rps": (2.0, 8.0),  # the tipping rate, uniform [rad/s]
    # the servos' torque-speed limit in the physics (env_model.motoring_forcerange: full torque to
    # constants.MOTOR_VELOCITY_LIMIT, 31.4 rad/s, none at twice it, as sim2sim's servo model);
    # without it the trained policies drove motors to 62-80 rad/s. Not yet in a trained run
    "servo_speed_limit": False,
    # train on one side only (robots.quadson.mirror): "left" runs every episode whose start has the
    # body's right side lower on the robot's mirror image (the actor's observation mirrored in, its
    # action mirrored out), so that the policy meets every side fall as a left one and gets twice
    # the practice of it; "right" the other way; "none" never. The side is taken as the deploy
    # loop's get-up policy takes it (deploy_supervisor.GetupPolicy): from the gravity direction the
    # IMU reads at the start (a knock-over: the side it tips toward). A policy trained so runs with
    # the same mirror_to wherever it runs (the export carries it)
    "mirror_to": "none",
    **SUCCESS,
    "upright_gate_rad": math.radians(30.0),  # height and pose terms fade in from this tilt to 0
    "height_sigma_m": 0.03,
    "pose_sigma_rad": 0.6,  # of the 12 motors' distance to home (root of the sum of squares)
    "weights": dict(WEIGHTS),
}

TOPPLE_PROB = 0.5  # getup.topple_prob of the get-up task (env_config(task="getup"))

TASKS = ("locomotion", "getup")
MIRROR_TO = ("none", "left", "right")  # env.getup.mirror_to; "none" is mirror.MIRROR_TO's None

_M, _S, _RAD = "m", "s", "rad"
GETUP_RULES: dict[str, Rule] = {
    "task": Rule("name"),
    "getup.drop_height_m": Rule("pair", 0.0, 2.0, _M),
    "getup.stand_start_prob": Rule("number", 0.0, 1.0, "(a probability)"),
    "getup.topple_prob": Rule("number", 0.0, 1.0, "(a probability)"),
    "getup.topple_rate_rps": Rule("pair", 0.0, 50.0, "rad/s"),
    "getup.servo_speed_limit": Rule("bool"),
    "getup.mirror_to": Rule("name"),
    "getup.success_tilt_rad": Rule("number", 0.0, math.pi / 2, _RAD, lo_open=True),
    "getup.success_height_m": Rule("number", 0.0, 0.5, _M, lo_open=True),
    "getup.success_hold_s": Rule("number", 0.0, 60.0, _S),
    "getup.success_within_s": Rule("number", 0.0, 600.0, _S, lo_open=True),
    "getup.upright_gate_rad": Rule("number", 0.0, math.pi, _RAD, lo_open=True),
    "getup.height_sigma_m": Rule("number", 0.0, 1.0, "m (a kernel width)", lo_open=True),
    "getup.pose_sigma_rad": Rule("number", 0.0, 10.0, "rad (a kernel width)", lo_open=True),
    "getup.weights.*": Rule("number", -1e4, 1e4),
}


def check_getup_config(cfg) -> None:
    """What relates the get-up keys to the rest of the config: ValueError naming the key."""
    task = cfg.get("task", "locomotion")
    if task not in TASKS:
        raise ValueError(f"env.task is {task!r}; choose from {list(TASKS)}")
    if cfg.getup.mirror_to not in MIRROR_TO:
        raise ValueError(f"env.getup.mirror_to is {cfg.getup.mirror_to!r}; choose from {list(MIRROR_TO)}")
    if task != "getup":
        return
    if cfg.robot != "quadson":
        raise ValueError(f"env.task=getup: the get-up start states are Quadson's; env.robot is {cfg.robot!r}")
    if cfg.terrain not in ("flat", "rough"):
        raise ValueError(f"env.task=getup runs on flat or rough ground; env.terrain is {cfg.terrain!r}")
    if cfg.observation != "sensors" or cfg.obs_history != 1 or cfg.command_tracking or cfg.gait_action:
        raise ValueError(
            "env.task=getup observes the robot's own sensors without history or command "
            "(env.observation=sensors, env.obs_history=1, env.command_tracking=False, env.gait_action=False)"
        )
    g = cfg.getup
    need = g.success_within_s + g.success_hold_s
    if cfg.episode_length_s + 1e-9 < need:
        raise ValueError(
            f"env.episode_length_s {cfg.episode_length_s} s is shorter than getup.success_within_s + "
            f"getup.success_hold_s ({need} s): a stand reached in time could not be confirmed"
        )
