"""Quadson as the environment sees it: five-bar legs, gaits of seed 000 in the shoulder frames."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from quadson_mjx.robots import Robot
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import gait, model


def tilt_feet(feet, roll_pitch):
    """Shoulder-frame feet (4, 3) -> the same world points for the body rolled and pitched by
    roll_pitch (2,) [rad] about its origin (gait.apply_body_offset)."""
    zero = jnp.zeros((), feet.dtype)
    pose = jnp.stack([zero, zero, zero, roll_pitch[0], roll_pitch[1], zero])
    return gait.apply_body_offset(feet, pose)


def closure_residual(mj_model, site_xpos):
    """(..., nsite, 3) site positions -> (..., 4) five-bar closure gap [m] (model.closure_residual_mjx)."""
    return model.closure_residual_mjx(site_xpos, model.model_ids(mj_model))


ROBOT = Robot(
    name="quadson",
    legs=C.LEGS,
    load_model=model.load_model,
    model_xml_text=model.model_xml_text,
    scene_path=model.scene_path,
    motor_joints=C.MOTOR_JOINTS,
    actuators=C.ACTUATORS,
    root_body=C.ROOT_BODY,
    home_keyframe=C.HOME_KEYFRAME,
    home_feet=np.pad(model.home_foot_targets(), ((0, 0), (0, 1))),  # planar (x, y), z = 0
    gait_names=gait.GAIT_NAMES,
    default_gait="trot",
    gait_params=gait.gait_params,
    foot_targets=gait.foot_targets,
    motor_targets=gait.motor_targets,
    tilt_feet=tilt_feet,
    closure_residual=closure_residual,
    height_target_m=C.STANCE_HEIGHT,  # seed 000's 0.2 m
    gait_action=True,
    env_defaults={},  # env_config's defaults are Quadson's
    model_variants=model.FIVEBAR_MODELS,
)
