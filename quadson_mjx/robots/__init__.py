"""One package per robot (the layout of mujoco_playground / mujoco_menagerie): everything that is one
robot's lives in its own folder: constants, MJCF generator, leg kinematics, body frames and gait
table (quadson/: the five-bar legs; caramel/: seed 003's serial legs). The generic layers (the gait
machinery, swing curves, serial-leg kinematics, the stabilizer, reward terms, the one environment
quadson_mjx.env) take what they need from a `Robot` and never import one robot's constants.

What the environment needs from a robot is a `Robot` (each folder's robot.py defines ROBOT): the model
and the names in it, the home pose, the gait in the robot's own foot frames, and the mapping from foot
targets to motor targets (the five-bar IK for Quadson, the serial-leg IK for Caramel). `get_robot(name)`
imports only the robot asked for.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

ROBOT_NAMES: tuple[str, ...] = ("quadson", "caramel")
TERRAINS: tuple[str, ...] = ("flat", "rough")  # every robot's scenes: a plane, the stone field


@dataclasses.dataclass(frozen=True)
class Robot:
    """A robot as the environment sees it. Foot frames ("gait frames") are the robot's own: Quadson's
    shoulder frames (x along p1 -> p5, y up, z lateral), Caramel's body frame (x forward, y left, z up);
    every (4, 3) foot array is in them, leg order `legs`."""

    name: str
    legs: tuple[str, ...]  # leg order of every per-leg array
    load_model: Callable[..., Any]  # (scene (TERRAINS), variant="full") -> mujoco.MjModel
    model_xml_text: Callable[..., str]  # (scene, variant="full") -> robot and scene MJCF text (logs)
    scene_path: Callable[..., Any]  # (scene, variant="full") -> Path of the scene's MJCF file
    motor_joints: tuple[str, ...]  # the 12 observed joints, legs x motors order
    actuators: tuple[str, ...]  # the 12 actuators in the same order
    root_body: str  # the free-floating base; its free joint comes first in qpos / qvel
    home_keyframe: str  # keyframe with the standing qpos and ctrl
    home_feet: np.ndarray  # (4, 3) foot targets of the home keyframe, gait frames [m]
    gait_names: tuple[str, ...]
    default_gait: str
    gait_params: Callable  # (name, **overrides) -> quadson_mjx.gait.GaitParams
    foot_targets: Callable  # (t (...) [s], command (..., 3), params) -> (..., 4, 3) gait frames [m]
    motor_targets: Callable  # feet (..., 4, 3) -> (angles (..., 4, 3) clamped [rad], valid (..., 4))
    # body kinematics for the roll / pitch stabilizer: feet (4, 3) of the level body, body roll and
    # pitch (2,) [rad] -> the same ground points in the gait frames of the tilted body
    tilt_feet: Callable
    # closed chains: (model, site_xpos (..., nsite, 3)) -> (..., 4) gap of each leg's loop [m];
    # None for a robot without loops (Caramel)
    closure_residual: Callable | None
    height_target_m: float  # base height the reward holds [m]
    gait_action: bool  # the gait may be scaled per step by the policy (traced step length, cycle)
    env_defaults: Mapping[str, Any]  # env config values of this robot, dotted keys (env_config)
    # leg models load_model accepts (env.fivebar_model): Quadson's "full" and "light" five-bar
    model_variants: tuple[str, ...] = ("full",)

    def foot_geoms(self) -> tuple[str, ...]:
        return tuple(f"{leg}_foot_collision" for leg in self.legs)


def get_robot(name: str) -> Robot:
    """The Robot of quadson_mjx.robots.<name>.robot. Raises ValueError for an unknown name."""
    if name not in ROBOT_NAMES:
        raise ValueError(f"unknown robot {name!r}; choose from {ROBOT_NAMES}")
    return importlib.import_module(f"quadson_mjx.robots.{name}.robot").ROBOT
