"""The robot side of each robot for the deploy loop, in numpy: names, limits, home stance, servo speed,
the gait and the foot -> motor mapping (Quadson's five-bar IK, Caramel's serial IK).

`robot_kinematics(env_cfg, meta)` builds it from a policy file's env config (and, for Caramel, the
geometry and gait the export wrote into the metadata, so the robot's computer needs no jax). Every
function mirrors the environment's JAX code (quadson_mjx.env.LocomotionEnv.gait_targets and
_motor_targets); tests/test_deploy.py and tests/test_deploy_caramel.py compare them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from quadson_mjx.mjcf import actuator_name, joint_name


class RobotKinematics(NamedTuple):
    """What the loop needs of a robot. Arrays: 12 motors in motor_names order (legs x 3)."""

    name: str
    legs: tuple[str, ...]
    motor_names: tuple[str, ...]  # the encoders / joints, policy order
    actuator_names: tuple[str, ...]  # the servos, same order
    motor_limits: np.ndarray  # (12, 2) [rad]
    home_motor: np.ndarray  # (12,) targets of the home stance [rad]
    home_feet: np.ndarray  # (4, 3) home stance in the gait frames [m]
    servo_speed_rps: float  # the servo's speed: the safety layer's default rate limit [rad/s]
    gait: Any  # the gait the env ran (robot-specific NamedTuple)
    gait_action: bool  # the policy may scale step length and cycle frequency
    foot_targets: Callable  # (t [s], command (3,), gait) -> (4, 3) gait frames [m]
    leg_phases: Callable  # (t [s], gait) -> (4,) in [0, 1)
    motor_targets: Callable  # feet (4, 3) -> (angles (4, 3) clamped, valid (4,))
    clamp: Callable  # angles (12,) -> (12,) inside the limits (and Quadson's toe-in guard)
    seed_speed: float  # the gait's own forward speed [m/s] (the command a command-free policy walked at)

    def scaled_gait(self, length_scale: float, freq_scale: float):
        """The gait with step length and cycle frequency scaled (env._motor_targets' gait_action)."""
        g = self.gait
        return g._replace(step_length_m=g.step_length_m * length_scale, cycle_s=g.cycle_s / freq_scale)


def quadson(env_cfg: dict) -> RobotKinematics:
    from quadson_mjx.robots.quadson import constants as C
    from quadson_mjx.robots.quadson import gait_np

    g = gait_np.gait_params(env_cfg["gait"], swing=env_cfg["swing"], scale=env_cfg.get("gait_scale"))
    home_feet = gait_np.home_feet()
    home, _ = gait_np.motor_targets(home_feet)
    limits = np.tile(C.MOTOR_RANGES, (4, 1))

    def clamp(angles):
        a = np.minimum(np.maximum(np.asarray(angles, np.float64), limits[:, 0]), limits[:, 1]).reshape(4, 3)
        a[:, 2] = np.minimum(
            np.maximum(np.minimum(a[:, 2], a[:, 1] + C.TOE_IN_MAX), limits[2, 0]), limits[2, 1]
        )
        return a.reshape(12)

    return RobotKinematics(
        name="quadson",
        legs=tuple(C.LEGS),
        motor_names=tuple(C.MOTOR_JOINTS),
        actuator_names=tuple(C.ACTUATORS),
        motor_limits=limits,
        home_motor=home.reshape(12),
        home_feet=home_feet,
        servo_speed_rps=float(C.MOTOR_VELOCITY_LIMIT),
        gait=g,
        gait_action=bool(env_cfg.get("gait_action", False)),
        foot_targets=gait_np.foot_targets,
        leg_phases=gait_np.leg_phases,
        motor_targets=gait_np.motor_targets,
        clamp=clamp,
        seed_speed=float(gait_np.seed_speed(g)),
    )


def caramel(env_cfg: dict, meta: dict | None) -> RobotKinematics:
    """Caramel from the file's metadata "caramel" ({"geometry", "gait"}, written by the export); a
    file without it is read with constants.py and the JAX gait table (needs jax)."""
    from quadson_mjx.robots.caramel import gait_np

    data = (meta or {}).get("caramel")
    if data is not None:
        geo, g = gait_np.Geometry.from_dict(data["geometry"]), gait_np.gait_params(data["gait"])
    else:
        import ml_collections

        from quadson_mjx.env_config import env_gait

        g = env_gait(ml_collections.ConfigDict(env_cfg))
        geo, g = gait_np.geometry(), gait_np.gait_params({k: np.asarray(v) for k, v in g._asdict().items()})
    home_feet = gait_np.nominal_feet(geo)
    home, _ = gait_np.motor_targets(home_feet, geo)
    limits = np.tile(geo.joint_limits, (4, 1))
    return RobotKinematics(
        name="caramel",
        legs=geo.legs,
        motor_names=tuple(joint_name(leg, j) for leg in geo.legs for j in geo.joints),
        actuator_names=tuple(actuator_name(leg, j) for leg in geo.legs for j in geo.joints),
        motor_limits=limits,
        home_motor=home.reshape(12),
        home_feet=home_feet,
        servo_speed_rps=geo.servo_speed_rps,
        gait=g,
        gait_action=False,
        foot_targets=lambda t, command, gait: gait_np.foot_targets(t, command, gait, geo),
        leg_phases=gait_np.leg_phases,
        motor_targets=lambda feet: gait_np.motor_targets(feet, geo),
        clamp=lambda a: np.minimum(np.maximum(np.asarray(a, np.float64), limits[:, 0]), limits[:, 1]),
        seed_speed=float(gait_np.seed_speed(g)),
    )


def robot_kinematics(env_cfg: dict, meta: dict | None = None) -> RobotKinematics:
    """The RobotKinematics of the env config's robot; ValueError for a robot without a deploy loop."""
    robot = env_cfg.get("robot", "quadson")
    if robot == "quadson":
        return quadson(env_cfg)
    if robot == "caramel":
        return caramel(env_cfg, meta)
    raise ValueError(f"no deploy loop for robot {robot!r}; the loop runs quadson and caramel")
