"""Factories for the environment's config: the seed's formulation by default, options beyond it.

Every number here is SI. `env_config()` is the seed 000 section 8 formulation on the closed-chain
model; keyword presets switch on what a modern locomotion environment adds (velocity commands,
domain randomization, pushes, rough ground). Dotted overrides (`--env.reward.forward_target=0.4`)
go through `quadson_mjx.config.apply_overrides`.
"""

from __future__ import annotations

import functools
import math
import re

import ml_collections
import mujoco

from quadson_mjx.config import Rule, rule_for
from quadson_mjx.env_recipes import (
    GAIT_RECIPE_OBSERVATION,
    GAIT_RECIPE_ORIENTATION_COEFFS,
    GAIT_RECIPES,
    JOYSTICK_COMMAND_RANGE,
    JOYSTICK_WEIGHTS,
    SENSOR_MODEL,
    reward_config,
)
from quadson_mjx.gait import GaitParams
from quadson_mjx.getup_config import EPISODE_S as GETUP_EPISODE_S
from quadson_mjx.getup_config import GETUP, GETUP_RULES, TOPPLE_PROB, check_getup_config
from quadson_mjx.hfield_contact import CHOICES as HFIELD_FOOT_CONTACTS
from quadson_mjx.robots import ROBOT_NAMES, TERRAINS, get_robot
from quadson_mjx.terrain_tiles import TILES, tile_spec

# The env's grounds: the robots' scene files (a plane, the stone field) and "tiles", the tiled
# training ground of quadson_mjx.terrain_tiles built from the `tiles` keys.
ENV_TERRAINS: tuple[str, ...] = (*TERRAINS, "tiles")

SEED_EPISODE_S = 4500 / 240.0  # seed 000: 4500 PyBullet steps at 240 Hz = 18.75 s


# Env keys added after runs were already published, with the value that reproduces what those runs
# did (dotted names). A config saved before a key existed gets it from `with_added_keys`, which the
# environment applies to every config it is given.
ENV_KEYS_ADDED = {
    "robot": "quadson",
    "base_terrain_contact": True,
    "joint_limits": True,
    "cone": "pyramidal",
    "impl": "jax",
    "warp_max_worlds": 8192,
    "solver": "newton",
    "solver_iterations": 1,
    "sim_dt": 0.0,
    "jacobian": "auto",
    "command_resample_s": (0.0, 0.0),
    "command_zero_prob": 0.0,
    "termination.base_below_terrain": False,
    "termination.base_clearance_m": 0.0,
    "termination.off_field_margin_m": 0.3,
    "reward.weights.lin_vel_z_l2": 0.0,
    "reward.weights.ang_vel_xy_l2": 0.0,
    "reward.weights.contact_phase": 0.0,
    "reward.weights.contact_pattern": 0.0,
    "reward.weights.termination": 0.0,
    "reward.weights.yaw_rate_error_l2": 0.0,
    "reward.weights.swing_touch": 0.0,
    "reward.weights.stance_lift": 0.0,
    "reward.weights.lin_vel_ema_error": 0.0,
    "reward.velocity_ema_s": 0.5,
    "reward.target_gait_speed": False,
    "gait_scale.cycle_s": 1.0,
    "gait_scale.step_length_m": 1.0,
    "gait_scale.step_height_m": 1.0,
    "observation": "true_state",
    "obs_history": 1,
    "yaw_error_tau_s": 0.0,
    "observe_servo_latency": False,
    "asymmetric_critic": False,
    "critic_scan_points": 0,
    "critic_scan_spacing_m": 0.05,
    "fivebar_model": "full",
    "hfield_foot_contacts": 4,
    **{f"tiles.{k}": v for k, v in TILES.items()},
    "task": "locomotion",
    **{f"getup.{k}": v for k, v in GETUP.items() if k != "weights"},
    **{f"getup.weights.{k}": v for k, v in GETUP["weights"].items()},
}

# What the actor observes (obs_spec): "sensors", the robot's own sensors only (sensor_observation);
# "true_state", seed 000's observation with the simulator's base velocity and yaw
# (locomotion_observation), which a robot can only feed from a state estimator.
OBSERVATIONS = ("sensors", "true_state")

ENV_KEYS_ADDED.update({f"sensor.{k}": v for k, v in SENSOR_MODEL.items()})


def with_added_keys(cfg) -> ml_collections.ConfigDict:
    """A copy of cfg (ConfigDict or dict) with every key of ENV_KEYS_ADDED it lacks set to the value
    that reproduces the older run; keys it has are kept."""
    data = cfg.to_dict() if hasattr(cfg, "to_dict") else dict(cfg)
    for dotted, value in ENV_KEYS_ADDED.items():
        *path, leaf = dotted.split(".")
        node = data
        for p in path:
            node = node.setdefault(p, {})
        node.setdefault(leaf, value)
    out = ml_collections.ConfigDict(data)
    out.lock()
    return out


def env_config(
    command_tracking: bool = False,
    randomize: bool = False,
    pushes: bool = False,
    terrain: str = "flat",
    gait: str | None = None,
    base_terrain_contact: bool = True,
    joint_limits: bool = True,
    joystick: bool = False,
    gait_recipe: bool = False,
    robot: str = "quadson",
    observation: str = "true_state",
    asymmetric_critic: bool = False,
    task: str = "locomotion",
) -> ml_collections.ConfigDict:
    """The environment config. Defaults reproduce seed 000's RL formulation.

    task: "locomotion" (LocomotionEnv: the gait plus the policy's foot offsets) or "getup"
        (quadson_mjx.getup_env: getting up after a fall; Quadson only; implies the sensor-only
        actor and privileged critic, a 6 s episode and the robot's legs touching the ground; the
        gait and command keys are then unused; quadson_mjx.getup_config).

    observation: what the actor observes, "true_state" (seed 000's, with the simulator's base
        velocity) or "sensors" (the robot's own sensors only; OBSERVATIONS); asymmetric_critic: the
        critic observes the privileged state (obs_spec.privileged_observation).

    robot: "quadson" or "caramel" (quadson_mjx.robots); the robot's env_defaults replace the values
        below that it names (Caramel: its gait, action scale, height target, kernels, command range).
    gait: a gait of the robot (default: the robot's default gait, Quadson's trot).

    command_tracking: sample (vx, vy, yaw rate) per episode and reward tracking it (observation +3).
    randomize: domain randomization of friction, masses, motor strength, latency, sensor noise.
    pushes: random horizontal velocity kicks to the base.
    terrain: "flat", "rough" (the stone field) or "tiles" (the tiled ground with its curriculum,
        the `tiles` keys; ENV_TERRAINS).
    base_terrain_contact: False lets only the feet touch the ground (see the key's comment).
    joint_limits: False drops the motor joints' limit rows from the solver (see the key's comment).
    joystick: the joystick recipe (implies command_tracking): commands resampled every 4-8 s, 10 %
        zero commands, the range vx [-0.3, 0.5], vy [-0.2, 0.2], yaw rate [-0.8, 0.8], the vz and
        roll/pitch-rate penalties instead of the seed's vz/wz pairing, and termination when the base
        box goes below the ground under it.
    gait_recipe: the gait's recipe of GAIT_RECIPES (implies randomize): its step length scale, the
        gait's own speed as the forward target, the contact-pattern rewards, the sensor-only actor
        and privileged critic (GAIT_RECIPE_OBSERVATION).
    """
    command_tracking = command_tracking or joystick
    spec = get_robot(robot)
    gait = spec.default_gait if gait is None else gait
    if terrain not in ENV_TERRAINS:
        raise ValueError(f"terrain must be one of {ENV_TERRAINS}, got {terrain!r}")
    if gait not in spec.gait_names:
        raise ValueError(f"unknown gait {gait!r} for {robot}; choose from {spec.gait_names}")
    if gait_recipe and (robot != "quadson" or gait not in GAIT_RECIPES):
        raise ValueError(
            f"no gait recipe for {robot}'s {gait!r}; recipes exist for Quadson's {sorted(GAIT_RECIPES)}"
        )
    randomize = randomize or gait_recipe
    if task == "getup":
        observation, asymmetric_critic, base_terrain_contact = "sensors", True, True
    cfg = ml_collections.ConfigDict(
        {
            "task": task,
            "robot": robot,
            "terrain": terrain,
            # Base box <-> ground contacts. MJX's box-heightfield collision is expensive: on the rough
            # scene it made physics 22-36x slower on the 2-core CPU (two runs of
            # benchmarks/terrain_contact_cost.py, benchmarks/results/terrain_contact_cpu.log). False
            # leaves only the feet touching the ground (the usual choice for MJX rough-terrain
            # training). At the termination limits (45 deg tilt, base 0.1 m up) the 34 x 16 x 8 cm
            # base box is still clear of level ground unless the body is both low and steeply tilted.
            "base_terrain_contact": base_terrain_contact,
            # Joint-limit rows of the 12 motor joints. MJX's solver carries one constraint row per
            # limited joint every step, active or not; the servos' targets stay inside the ranges
            # (the IK clamps), so False trades that guard for speed (benchmarks/physics_vs_go1.py).
            "joint_limits": joint_limits,
            # Friction cone of the contacts: "pyramidal" (MuJoCo's default, 4 rows per condim-3
            # contact) or "elliptic" (3 rows).
            "cone": "pyramidal",
            # Constraint solver: "newton" (MuJoCo's default: one Hessian Cholesky per iteration) or
            # "cg" (conjugate gradient preconditioned by the mass matrix, no Hessian), both with the
            # model's line-search iterations (5).
            "solver": "newton",
            # The solver's iterations per physics step: the model's 1 (the usual MJX training
            # choice, each iteration a constraint solve) or more, for a contact and closed-chain
            # solution nearer MuJoCo's converged one (the sim-to-sim plant runs 100).
            "solver_iterations": 1,
            # Mass-matrix storage in MJX: "auto" (dense below 60 dofs on a GPU), "dense" or "sparse"
            # (factored level by level along the kinematic tree instead of by a batched Cholesky).
            "jacobian": "auto",
            # MJX implementation: "jax", or "warp" (MuJoCo Warp through mujoco.mjx; needs the
            # warp extra, warp-lang). Under Warp the feet's ground contact comes from four contact
            # sensors (the model's other sensors removed) and one contact buffer serves all worlds
            # (env_model.warp_buffers; docs/benchmarks.md "MJX's Warp implementation").
            "impl": "jax",
            # Under Warp: the most worlds one batch steps (the contact buffer is sized for them;
            # a larger batch is refused at reset). Playground's Go1 uses 8192 too.
            "warp_max_worlds": 8192,
            # The leg model (Robot.model_variants): "full" five-bar, or Quadson's "light" one, whose
            # passive link 4 is a fixed-length tendon (4 DoFs and 1 equality row per leg instead of
            # 5 and 3; docs/physics.md, benchmarks/fivebar_light_vs_full.py).
            "fivebar_model": "full",
            # Contacts per foot sphere on a height field (the stone field, the tiles; a plane makes
            # one): 4, MJX's own collider (up to four points of the grid cells under the foot), or
            # 1, the surface's nearest point, MuJoCo C's deepest contact (quadson_mjx.hfield_contact;
            # 1.43x the stone field's physics on one H200 at 32768 worlds, the tiles' environment
            # 1.68x). MJX's JAX implementation and the walking tasks only.
            "hfield_foot_contacts": 4,
            # 50 Hz control: the control rate of seed 003's gait planner and of MJX locomotion
            # benchmarks; the seed's 240 Hz with one action per physics step would make PPO's
            # horizon 5x longer for no gain in what a position servo can follow.
            "ctrl_dt": 0.02,
            # The physics timestep [s]: 0 keeps the model's (4 ms, the usual MJX training step);
            # a finer one (the sim-to-sim plant's 0.002) integrates contacts more accurately at
            # that many more physics steps per control step. ctrl_dt must be a whole multiple.
            "sim_dt": 0.0,
            "episode_length_s": SEED_EPISODE_S,
            "gait": gait,
            # the robot's gait table's cycle time, step length and swing height, scaled;
            # the gait's speed (its command without command_tracking) scales with length / cycle
            "gait_scale": {"cycle_s": 1.0, "step_length_m": 1.0, "step_height_m": 1.0},
            "swing": "bezier_seed",  # seed 000 Algorithm 6 (the apex variant tips the open-loop trot)
            "gait_ramp_s": 0.5,  # blend from the home stance into the gait at the episode start
            "action_scale_m": 0.05,  # seed: offsets bounded to +-5 cm
            "gait_action": False,  # if True, two extra actions scale step length and cycle time
            "gait_action_range": 0.5,  # +-50 % of the gait's step length and cycle frequency
            "command_tracking": command_tracking,
            "command_range": {  # per-episode uniform sampling when command_tracking
                # measured: the trot's foot targets stay reachable up to |vx| = 0.48 m/s; the joystick
                # range's vx 0.5 clamps up to 4.9 % of leg-steps of a cycle (with |vy| 0.2, |yaw| 0.8)
                **(
                    JOYSTICK_COMMAND_RANGE
                    if joystick
                    else {"vx": (-0.3, 0.45), "vy": (-0.2, 0.2), "yaw_rate": (-0.5, 0.5)}
                ),
            },
            # a new command every U(lo, hi) seconds within the episode; (0, 0): one per episode
            "command_resample_s": (4.0, 8.0) if joystick else (0.0, 0.0),
            "command_zero_prob": 0.1 if joystick else 0.0,  # share of sampled commands set to zero
            "termination": {
                "max_tilt_rad": math.radians(45.0),
                "min_height_m": 0.1,  # base origin above the ground under it
                # With base_terrain_contact off the base box passes through stones unseen: end the
                # episode when a point of its bottom face comes within base_clearance_m of the
                # ground under it (always counted in metrics["base_below_terrain"]).
                "base_below_terrain": joystick,
                "base_clearance_m": 0.0,
                # The stone field is 8 x 8 m with nothing beyond: an episode whose base comes this
                # close to the edge ends as a truncation (metrics["off_field"]), not a fall.
                "off_field_margin_m": 0.3,
            },
            "reward": reward_config(spec.height_target_m, command_tracking),
            "noise": {  # Gaussian sensor noise std, used when randomize is on
                "rpy": 0.02,
                "lin_vel": 0.05,
                "ang_vel": 0.1,
                "motor_pos": 0.01,
            },
            # what the actor observes (OBSERVATIONS), how many ticks of its IMU, encoder and action
            # entries (obs_spec.HISTORY_ENTRIES), and whether the critic observes the privileged
            # state (obs_spec.privileged_observation; brax PPO's value_obs_key)
            "observation": observation,
            "obs_history": 1,
            # the "sensors" observation's yaw_error entry (obs_spec.yaw_error_step): a leaky
            # integral of the gyro's yaw rate minus the commanded one, with this time constant [s];
            # 0: no such entry. Needs command_tracking.
            "yaw_error_tau_s": 0.0,
            # the "sensors" observation's servo_latency entry (obs_spec.SERVO_LATENCY): the servos'
            # actuation latency as measured on the robot before it walks (in training the episode's
            # randomization.latency_s with the calibration's error sensor.servo_latency_error_s)
            "observe_servo_latency": False,
            "asymmetric_critic": asymmetric_critic,
            # the critic's ground scan (asymmetric_critic, locomotion): an n x n grid of ground
            # heights (n = critic_scan_points, 0: none), spacing apart, centred under the base and
            # turned with its heading (terrain.ground_scan)
            "critic_scan_points": 0,
            "critic_scan_spacing_m": 0.05,
            "sensor": dict(SENSOR_MODEL),
            "randomize": randomize,
            "randomization": {
                "friction": (0.5, 1.2),  # sliding friction, seed nominal 0.8
                "mass_scale": (0.85, 1.15),  # every body's mass
                "motor_strength": (0.8, 1.2),  # kp and force range of every servo
                "latency_s": (0.0, 0.02),  # delay before a new motor target reaches the servos
                "base_com_shift_m": (-0.02, 0.02),  # the base CoM (+5 cm) is an assumption
            },
            "pushes": pushes,
            "push": {"interval_s": (2.0, 4.0), "speed_mps": (0.1, 0.4)},
            "tiles": dict(TILES),
            "getup": {**GETUP, "weights": dict(GETUP["weights"])},
        }
    )
    if task == "getup":
        cfg.episode_length_s = GETUP_EPISODE_S
        cfg.getup.topple_prob = TOPPLE_PROB
    if joystick:
        cfg.reward.weights.update(JOYSTICK_WEIGHTS)
    if gait_recipe:
        recipe = GAIT_RECIPES[gait]
        cfg.gait_scale.step_length_m = recipe["step_length_m"]
        cfg.reward.forward_sigma = recipe["forward_sigma"]
        cfg.reward.target_gait_speed = True
        cfg.reward.weights.contact_phase = recipe["contact_phase"]
        cfg.reward.weights.contact_pattern = recipe["contact_pattern"]
        cfg.reward.orientation_coeffs = GAIT_RECIPE_ORIENTATION_COEFFS
        cfg.update(GAIT_RECIPE_OBSERVATION)
    for dotted, value in spec.env_defaults.items():
        *path, leaf = dotted.split(".")
        node = cfg
        for p in path:
            node = node[p]
        if leaf not in node:
            raise KeyError(f"{robot}'s env_defaults name env.{dotted}, which the config does not have")
        node[leaf] = ml_collections.ConfigDict(value) if isinstance(value, dict) else value
    cfg.lock()
    check_env_config(cfg)  # typed (a locked ConfigDict keeps each value's type) and checked where built
    return cfg


def env_gait(cfg) -> GaitParams:
    """The gait an env config runs: the robot's gait table entry cfg.gait with cfg.swing and
    cfg.gait_scale (Quadson: robots/quadson/constants.GAITS)."""
    gait_params = get_robot(cfg.get("robot", "quadson")).gait_params
    base = gait_params(cfg.gait)
    scale = cfg.get("gait_scale") or {}
    return gait_params(
        cfg.gait,
        swing=cfg.swing,
        cycle_s=base.cycle_s * scale.get("cycle_s", 1.0),
        step_length_m=base.step_length_m * scale.get("step_length_m", 1.0),
        step_height_m=base.step_height_m * scale.get("step_height_m", 1.0),
    )


def _number(key: str, value, ok, what: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or not ok(value)
    ):
        raise ValueError(f"env.{key} must be {what}, got {value!r}")
    return value


def _walk(cfg, prefix: str = ""):
    for k, v in cfg.items():
        if isinstance(v, ml_collections.ConfigDict | dict):
            yield from _walk(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


# Every env key's allowed values. The upper bounds are what this robot class can use, far beyond
# the presets (so a typo like 100 for 0.1 is caught, not a deliberate experiment): speeds a 20 cm
# robot cannot reach, episodes of an hour, reward weights of 10^4 (the largest preset weight is
# height_l2's 50). A new key without an entry fails tests/test_training_hardening.py.
_M, _S, _RAD = "m", "s", "rad"
ENV_RULES: dict[str, Rule] = {
    "robot": Rule("name"),
    "terrain": Rule("name"),
    "base_terrain_contact": Rule("bool"),
    "joint_limits": Rule("bool"),
    "cone": Rule("name"),
    "solver": Rule("name"),
    "solver_iterations": Rule("int", 1, 100),
    "jacobian": Rule("name"),
    "impl": Rule("name"),
    "warp_max_worlds": Rule("int", 1, 1 << 20, "worlds"),
    "fivebar_model": Rule("name"),
    "hfield_foot_contacts": Rule("int", 1, 4, "contacts"),  # and one of hfield_contact.CHOICES
    "ctrl_dt": Rule("number", 0.0, 1.0, _S, lo_open=True),  # and a multiple of the model timestep
    "sim_dt": Rule("number", 0.0, 0.02, _S),  # 0: the model's; ctrl_dt a multiple of it
    "episode_length_s": Rule("number", 0.0, 3600.0, _S, lo_open=True),  # and >= ctrl_dt
    "gait": Rule("name"),
    "gait_scale.*": Rule("number", 0.0, 10.0, "(a factor on the gait table)", lo_open=True),
    "swing": Rule("name"),
    "gait_ramp_s": Rule("number", 0.0, 60.0, _S, lo_open=True),
    "action_scale_m": Rule("number", 0.0, 0.2, _M),  # the legs are about 0.2 m long
    "gait_action": Rule("bool"),
    "gait_action_range": Rule("number", 0.0, 0.99, "(the scale 1 +- range must stay > 0)"),
    "command_tracking": Rule("bool"),
    "command_range.*": Rule("pair", -5.0, 5.0, "m/s or rad/s"),
    "command_resample_s": Rule("pair", 0.0, 3600.0, _S),
    "command_zero_prob": Rule("number", 0.0, 1.0, "(a probability)"),
    "termination.max_tilt_rad": Rule("number", 0.0, math.pi, _RAD, lo_open=True),
    "termination.min_height_m": Rule("number", 0.0, 2.0, _M),
    "termination.base_below_terrain": Rule("bool"),
    "termination.base_clearance_m": Rule("number", 0.0, 0.5, _M),
    "termination.off_field_margin_m": Rule("number", 0.0, 4.0, _M),  # the stone field is 8 x 8 m
    "reward.weights.*": Rule("number", -1e4, 1e4),
    "reward.forward_target": Rule("number", -5.0, 5.0, "m/s"),
    "reward.target_gait_speed": Rule("bool"),
    "reward.forward_sigma": Rule("number", 0.0, 10.0, "m/s (a kernel width)", lo_open=True),
    "reward.tracking_sigma": Rule("number", 0.0, 10.0, "(a kernel width)", lo_open=True),
    "reward.velocity_ema_s": Rule("number", 0.0, 60.0, _S, lo_open=True),  # and >= ctrl_dt
    "reward.orientation_coeffs": Rule("vector", 0.0, 1e4),
    "reward.height_target": Rule("number", 0.0, 2.0, _M, lo_open=True),
    "noise.rpy": Rule("number", 0.0, 0.5, _RAD),
    "noise.lin_vel": Rule("number", 0.0, 2.0, "m/s"),
    "noise.ang_vel": Rule("number", 0.0, 5.0, "rad/s"),
    "noise.motor_pos": Rule("number", 0.0, 0.5, _RAD),
    "observation": Rule("name"),
    "obs_history": Rule("int", 1, 16, "ticks"),
    "yaw_error_tau_s": Rule("number", 0.0, 60.0, _S),
    "observe_servo_latency": Rule("bool"),
    "asymmetric_critic": Rule("bool"),
    "critic_scan_points": Rule("int", 0, 31),
    "critic_scan_spacing_m": Rule("number", 0.0, 0.5, _M, lo_open=True),
    "sensor.gravity_noise": Rule("number", 0.0, 1.0, "(of a unit vector)"),
    "sensor.gyro_noise_rps": Rule("number", 0.0, 10.0, "rad/s"),
    "sensor.gyro_bias_rps": Rule("number", 0.0, 10.0, "rad/s"),
    "sensor.imu_tilt_rad": Rule("number", 0.0, 0.5, _RAD),
    "sensor.encoder_noise_rad": Rule("number", 0.0, 0.5, _RAD),
    "sensor.encoder_resolution_rad": Rule("number", 0.0, 0.5, _RAD),
    "sensor.latency_s": Rule("pair", 0.0, 0.5, _S),
    "sensor.servo_latency_error_s": Rule("number", 0.0, 0.1, _S),
    "randomize": Rule("bool"),
    "randomization.friction": Rule("pair", 0.0, 5.0, lo_open=True),
    "randomization.mass_scale": Rule("pair", 0.0, 5.0, lo_open=True),
    "randomization.motor_strength": Rule("pair", 0.0, 5.0, lo_open=True),
    "randomization.latency_s": Rule("pair", 0.0, 0.5, _S),
    "randomization.base_com_shift_m": Rule("pair", -0.1, 0.1, _M),
    "pushes": Rule("bool"),
    "push.interval_s": Rule("pair", 0.0, 3600.0, _S, lo_open=True),
    "push.speed_mps": Rule("pair", 0.0, 5.0, "m/s"),
    "tiles.types": Rule("name"),  # and each a known tile type, once
    "tiles.levels": Rule("int", 1, 100, "rows"),
    "tiles.tile_m": Rule("number", 0.5, 20.0, _M),  # and a whole number of cells
    "tiles.border_m": Rule("number", 0.0, 20.0, _M),  # and a whole number of cells
    "tiles.cell_m": Rule("number", 0.005, 0.2, _M),
    "tiles.seed": Rule("int", 0, 2**31 - 1),
    "tiles.min_init_level": Rule("int", 0, 99, "(a level)"),  # and <= max_init_level
    "tiles.max_init_level": Rule("int", 0, 99, "(a level)"),  # and < levels
    "tiles.spawn_margin_m": Rule("number", 0.0, 10.0, _M),  # and < tile_m / 2
    "tiles.curriculum": Rule("bool"),
    "tiles.curriculum_up": Rule("number", 0.0, 10.0, "(of the commanded distance)"),
    "tiles.curriculum_down": Rule("number", 0.0, 10.0, "(of the commanded distance)"),  # <= up
    "tiles.type_weights": Rule("name"),  # "type:weight,...", checked by terrain_tiles.type_weights
    **GETUP_RULES,
}


@functools.cache
def model_timestep(robot: str) -> float:
    """The physics timestep of `robot`'s MJCF [s], read from its <option> (no model compiled)."""
    match = re.search(r'<option[^>]*\btimestep="([^"]+)"', get_robot(robot).model_xml_text("flat"))
    return float(match.group(1)) if match else 0.002  # MuJoCo's default


# MuJoCo option values of the env's physics keys
CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}
SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
JACOBIANS = {"auto": mujoco.mjtJacobian.mjJAC_AUTO, "dense": mujoco.mjtJacobian.mjJAC_DENSE, "sparse": mujoco.mjtJacobian.mjJAC_SPARSE}  # fmt: skip


def check_env_config(cfg) -> None:
    """Raises ValueError naming the key (as `env.KEY`) for a value the environment would misread.

    Every key has a rule in ENV_RULES (a key without one is refused): numbers finite in float32 and
    inside their bounds, (low, high) ranges with low <= high, probabilities in [0, 1], sizes and
    durations positive; then what relates keys: ctrl_dt a multiple of the model's timestep,
    episode_length_s >= ctrl_dt, known names, a gait the robot can run.
    """
    from quadson_mjx.swing import SWING_SHAPES

    for key, value in _walk(cfg):
        rule = rule_for(ENV_RULES, key)
        if rule is None:
            raise ValueError(f"env.{key} has no range in env_config.ENV_RULES (a new key needs one)")
        rule.check(f"env.{key}", value)
    robot = cfg.get("robot", "quadson")
    if robot not in ROBOT_NAMES:
        raise ValueError(f"env.robot is {robot!r}; choose from {list(ROBOT_NAMES)}")
    spec = get_robot(robot)
    if cfg.terrain not in ENV_TERRAINS:
        raise ValueError(f"env.terrain is {cfg.terrain!r}; choose from {list(ENV_TERRAINS)}")
    if cfg.terrain == "tiles":
        tile_spec(cfg)
    if cfg.gait not in spec.gait_names:
        raise ValueError(f"env.gait is {cfg.gait!r}; {robot} has {list(spec.gait_names)}")
    fivebar = cfg.get("fivebar_model", "full")
    if fivebar not in spec.model_variants:
        raise ValueError(f"env.fivebar_model is {fivebar!r}; {robot} has {list(spec.model_variants)}")
    contacts = cfg.get("hfield_foot_contacts", 4)
    if contacts not in HFIELD_FOOT_CONTACTS:
        raise ValueError(
            f"env.hfield_foot_contacts is {contacts!r}; choose from {list(HFIELD_FOOT_CONTACTS)}"
        )
    if contacts != 4 and (cfg.impl != "jax" or cfg.get("task", "locomotion") != "locomotion"):
        raise ValueError(
            "env.hfield_foot_contacts=1 needs env.impl=jax and the locomotion task (it replaces a "
            "collider of MJX's JAX implementation for the feet alone; the walking tasks on rough "
            "ground set it): add env.hfield_foot_contacts=4"
        )
    if cfg.gait_action and not spec.gait_action:
        raise ValueError(f"env.gait_action: {robot}'s gait cannot be scaled by the policy")
    for key, names in (
        ("cone", CONES),
        ("solver", SOLVERS),
        ("jacobian", JACOBIANS),
        ("impl", ("jax", "warp")),
    ):
        if cfg[key] not in names:
            raise ValueError(f"env.{key} is {cfg[key]!r}; choose from {list(names)}")
    if cfg.swing not in SWING_SHAPES:
        raise ValueError(f"env.swing is {cfg.swing!r}; choose from {list(SWING_SHAPES)}")
    sim_dt = cfg.get("sim_dt", 0.0) or model_timestep(robot)
    source = "env.sim_dt" if cfg.get("sim_dt", 0.0) else f"{robot}'s model"
    substeps = round(cfg.ctrl_dt / sim_dt)
    if substeps < 1 or abs(substeps * sim_dt - cfg.ctrl_dt) > 1e-9:
        raise ValueError(
            f"env.ctrl_dt must be a whole multiple of the physics timestep {sim_dt} s ({source}), "
            f"got {cfg.ctrl_dt!r}"
        )
    _number(
        "episode_length_s", cfg.episode_length_s, lambda v: v >= cfg.ctrl_dt, f">= ctrl_dt ({cfg.ctrl_dt} s)"
    )
    _number(
        "reward.velocity_ema_s",
        cfg.reward.get("velocity_ema_s", ENV_KEYS_ADDED["reward.velocity_ema_s"]),
        lambda v: v >= cfg.ctrl_dt,
        f">= ctrl_dt ({cfg.ctrl_dt} s)",
    )
    try:
        env_gait(cfg)
    except ValueError as e:
        raise ValueError(f"env.gait, env.swing, env.gait_scale: {robot}'s {cfg.gait!r}: {e}") from e
    if cfg.observation not in OBSERVATIONS:
        raise ValueError(f"env.observation is {cfg.observation!r}; choose from {list(OBSERVATIONS)}")
    if cfg.obs_history > 1 and cfg.observation != "sensors":
        raise ValueError("env.obs_history > 1 needs env.observation=sensors")
    if cfg.yaw_error_tau_s and (cfg.observation != "sensors" or not cfg.command_tracking):
        raise ValueError("env.yaw_error_tau_s > 0 needs env.observation=sensors and a command to track")
    if cfg.observe_servo_latency and (cfg.observation != "sensors" or cfg.task != "locomotion"):
        raise ValueError("env.observe_servo_latency needs env.observation=sensors and the locomotion task")
    if cfg.critic_scan_points and (not cfg.asymmetric_critic or cfg.task != "locomotion"):
        raise ValueError(
            "env.critic_scan_points > 0 needs env.asymmetric_critic=true and the locomotion task"
        )
    check_getup_config(cfg)
