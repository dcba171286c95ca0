"""Reward terms of the locomotion environment: pure functions of arrays, named `<quantity>_<kernel>`.

Each term returns an unweighted value of shape (...,); the environment multiplies it by its weight
from the config and logs it as `reward/<term>`. Seed 000 section 8.2 gives

    r = 1.0 exp(-0.5 (vx - 0.5)^2)                  forward_velocity_exp (sigma = 1 m/s)
      - 0.8 (0.5 vy^2 + 0.3 wy^2)                    lateral_l2
      - 0.8 (0.5 vz^2 + 0.3 wz^2)                    vertical_l2
      - 1.0 (40 roll^2 + 30 pitch^2 + 5 yaw^2)       orientation_l2
      - 0.5 (additional terms for stability and efficiency)

The seed pairs vy with wy and vz with wz as printed; we keep its pairing. Its "additional terms" are not
listed; this project takes the seed's stated goals (hold 0.2 m of height, smooth motion, efficiency) as
height_l2, action_rate_l2 and torque_l2, each weighted separately in the config.
Velocities: body-frame linear [m/s] and angular [rad/s] velocity of the base.
"""

from __future__ import annotations

import jax.numpy as jnp


def tracking_exp(error_sq, sigma):
    """exp(-error^2 / (2 sigma^2)): 1 at zero error, exp(-0.5) at one sigma."""
    return jnp.exp(-error_sq / (2.0 * sigma**2))


def forward_velocity_exp(lin_vel, target, sigma):
    """lin_vel (..., 3) body frame [m/s], target [m/s] -> (...,). Seed: sigma = 1 m/s."""
    return tracking_exp(jnp.square(lin_vel[..., 0] - target), sigma)


def lateral_l2(lin_vel, ang_vel):
    """0.5 vy^2 + 0.3 wy^2 (seed 000 lateral penalty, its pairing as printed) -> (...,)."""
    return 0.5 * jnp.square(lin_vel[..., 1]) + 0.3 * jnp.square(ang_vel[..., 1])


def vertical_l2(lin_vel, ang_vel):
    """0.5 vz^2 + 0.3 wz^2 (seed 000 vertical penalty) -> (...,)."""
    return 0.5 * jnp.square(lin_vel[..., 2]) + 0.3 * jnp.square(ang_vel[..., 2])


def orientation_l2(rpy, coeffs=(40.0, 30.0, 5.0)):
    """coeffs . (roll^2, pitch^2, yaw^2), rpy (..., 3) [rad] -> (...,)."""
    return jnp.sum(jnp.asarray(coeffs) * jnp.square(rpy), axis=-1)


def height_l2(base_z, target_z):
    """(z - z_target)^2 [m^2] -> (...,)."""
    return jnp.square(base_z - target_z)


def action_rate_l2(action, last_action):
    """Sum of squared changes of the normalised action between control steps -> (...,)."""
    return jnp.sum(jnp.square(action - last_action), axis=-1)


def torque_l2(torque):
    """Sum of squared motor torques [N^2 m^2] -> (...,)."""
    return jnp.sum(jnp.square(torque), axis=-1)


def lin_vel_tracking_exp(lin_vel, command, sigma):
    """Planar velocity command tracking: command (..., 3) = (vx, vy, yaw rate) -> (...,)."""
    err = jnp.sum(jnp.square(lin_vel[..., :2] - command[..., :2]), axis=-1)
    return tracking_exp(err, sigma)


def ang_vel_tracking_exp(ang_vel, command, sigma):
    """Yaw-rate command tracking -> (...,)."""
    return tracking_exp(jnp.square(ang_vel[..., 2] - command[..., 2]), sigma)


def yaw_rate_error_l2(ang_vel, command):
    """(wz - commanded yaw rate)^2 [rad^2/s^2]: the square whose mean the yaw-rate RMS measures, a
    penalty that keeps growing with the error where ang_vel_tracking_exp flattens -> (...,)."""
    return jnp.square(ang_vel[..., 2] - command[..., 2])


def velocity_ema_step(vel_ema, lin_vel, dt, tau):
    """One control step of the planar velocity's exponential moving average: vel_ema (..., 2) ->
    vel_ema + (lin_vel[..., :2] - vel_ema) * dt / tau [m/s] (dt <= tau, checked in the config)."""
    return vel_ema + (lin_vel[..., :2] - vel_ema) * (dt / tau)


def lin_vel_ema_error(vel_ema, command):
    """|v_ema - command| [m/s], the planar norm: the error of the velocity averaged over about a gait
    cycle (vel_ema (..., 2), velocity_ema_step), with the gait's own oscillation filtered out. A
    steady speed deficit costs in proportion to its size, where lin_vel_tracking_exp's kernel,
    averaged over the step-to-step oscillation, charges it only to second order -> (...,)."""
    return jnp.linalg.norm(vel_ema - command[..., :2], axis=-1)


def lin_vel_z_l2(lin_vel):
    """vz^2 [m^2/s^2] (the joystick recipe's vertical penalty, MuJoCo Playground Go1) -> (...,)."""
    return jnp.square(lin_vel[..., 2])


def ang_vel_xy_l2(ang_vel):
    """wx^2 + wy^2 [rad^2/s^2]: roll and pitch rates, leaving the commanded yaw rate free -> (...,)."""
    return jnp.sum(jnp.square(ang_vel[..., :2]), axis=-1)


def contact_phase(contact, stance):
    """Share of the feet (4,) whose ground contact (bool) equals the phase table's stance (bool):
    1 when touching down exactly in stance and lifted exactly in swing, in [0, 1]."""
    return jnp.mean((contact == stance).astype(jnp.float32))


def contact_pattern(contact, stance_near):
    """1 when every foot's ground contact (4,) bool equals the phase table's stance at this control
    step or the one before or after (stance_near (3, 4) bool: the table one step earlier, now, one
    step later), else 0: the gait evaluation's pattern match within one step (gait_eval), as a
    reward. All four feet at once, so that a foot that scuffs in swing costs the whole step."""
    agree = jnp.any(contact[..., None, :] == stance_near, axis=-2)
    return jnp.all(agree, axis=-1).astype(jnp.float32)


def swing_touch(contact, stance_near):
    """Number of feet on the ground (contact (..., 4) bool) that the phase table has in swing at the
    control step before, at and after this one (stance_near (..., 3, 4) bool), in [0, 4]: the touches
    that the pattern match within one step counts as misses, each foot counted. contact_pattern
    pays nothing for a step with one such touch or with four; this term charges every foot that uses
    the ground in its swing (a bound policy's mid-swing supports, results/gaits/finetune/README.md)."""
    swing = ~jnp.any(stance_near, axis=-2)
    return jnp.sum((contact & swing).astype(jnp.float32), axis=-1)


def stance_lift(contact, stance_near):
    """Number of feet off the ground (contact (..., 4) bool) that the phase table has in stance at
    the control step before, at and after this one (stance_near (..., 3, 4) bool), in [0, 4]: the
    other misses of the pattern match within one step, swing_touch's mirror. It charges a foot that
    leaves the ground in the middle of its stance (a bounce, a flicker of contact)."""
    stance = jnp.all(stance_near, axis=-2)
    return jnp.sum((~contact & stance).astype(jnp.float32), axis=-1)


def locomotion_terms(
    r,
    forward_target,
    *,
    lin_vel,
    ang_vel,
    rpy,
    height,
    action,
    last_action,
    actuator_force,
    command,
    contact,
    stance,
    stance_near,
    fallen,
    vel_ema=None,
) -> dict:
    """Every term of the locomotion environment, unweighted, by name (the config's reward.weights
    keys). r: the env config's `reward` group; forward_target [m/s]; body-frame velocities (3,);
    rpy (3,) [rad]; height above the ground under the base [m]; command (3,); contact, stance (4,)
    bool: feet on the ground and the phase table's stance legs; stance_near (3, 4) bool: the table's
    stance one control step before, at and after this one; fallen () bool: the episode ends by a
    fall on this step (tilt, height, base in the ground), the one step the termination term pays;
    vel_ema (2,): the planar velocity's moving average [m/s] (None: lin_vel_ema_error is 0, off)."""
    return {
        "forward_velocity_exp": forward_velocity_exp(lin_vel, forward_target, r.forward_sigma),
        "lateral_l2": lateral_l2(lin_vel, ang_vel),
        "vertical_l2": vertical_l2(lin_vel, ang_vel),
        "orientation_l2": orientation_l2(rpy, r.orientation_coeffs),
        "height_l2": height_l2(height, r.height_target),
        "action_rate_l2": action_rate_l2(action, last_action),
        "torque_l2": torque_l2(actuator_force),
        "lin_vel_tracking_exp": lin_vel_tracking_exp(lin_vel, command, r.tracking_sigma),
        "ang_vel_tracking_exp": ang_vel_tracking_exp(ang_vel, command, r.tracking_sigma),
        "yaw_rate_error_l2": yaw_rate_error_l2(ang_vel, command),
        "lin_vel_ema_error": jnp.zeros(()) if vel_ema is None else lin_vel_ema_error(vel_ema, command),
        "lin_vel_z_l2": lin_vel_z_l2(lin_vel),
        "ang_vel_xy_l2": ang_vel_xy_l2(ang_vel),
        "contact_phase": contact_phase(contact, stance),
        "contact_pattern": contact_pattern(contact, stance_near),
        "swing_touch": swing_touch(contact, stance_near),
        "stance_lift": stance_lift(contact, stance_near),
        "termination": jnp.asarray(fallen, jnp.float32),
    }


# --- the get-up task (quadson_mjx.getup_env; weights in env.getup.weights) -------------------------


def upright_gate(up, gate_rad):
    """up (...,) cos of the tilt -> (...,) in [0, 1]: 0 beyond gate_rad of tilt, rising linearly in
    cos(tilt) to 1 upright (height and pose count only once the robot is nearly up)."""
    c = jnp.cos(gate_rad)
    return jnp.clip((up - c) / (1.0 - c), 0.0, 1.0)


def upright_sq(up):
    """((1 + cos tilt) / 2)^2: 1 upright, 1/4 on a side, 0 on the back; its slope never vanishes
    between, so rolling off the back pays from the first degree."""
    return jnp.square(0.5 * (1.0 + up))


def getup_terms(g, *, up, height, stand_height, motor_pos, home_motor, motor_vel, speed_limit, action, last_action, actuator_force, legs_overlap) -> dict:  # fmt: skip
    """Every term of the get-up task, unweighted, by name (env.getup.weights keys). g: the env
    config's `getup` group; up (): cos of the tilt (the body z axis against the vertical); height:
    the base above the ground under it [m], stand_height: the home stance's [m]; motor_pos,
    home_motor, motor_vel (12,) [rad], [rad/s]; speed_limit: the servo's no-load speed [rad/s];
    action, last_action (12,); actuator_force (nu,) [N m]; legs_overlap (): True when two legs'
    collision geometry (or a leg and the base box) overlap."""
    gate = upright_gate(up, g.upright_gate_rad)
    pose_sq = jnp.sum(jnp.square(motor_pos - home_motor))
    at_height = jnp.exp(-jnp.square(height - stand_height) / g.height_sigma_m**2)
    return {
        "upright_sq": upright_sq(up),
        "height_lin": jnp.clip(height / stand_height, 0.0, 1.0),
        "height_exp": gate * at_height,
        "home_pose_exp": gate * jnp.exp(-pose_sq / g.pose_sigma_rad**2),
        "stand_still_exp": gate * at_height * jnp.exp(-0.5 * jnp.sum(jnp.square(action))),
        "joint_speed_l2": jnp.sum(jnp.square(motor_vel)),
        "joint_speed_limit": jnp.sum(jnp.maximum(jnp.abs(motor_vel) - speed_limit, 0.0)),
        "action_rate_l2": action_rate_l2(action, last_action),
        "torque_l2": torque_l2(actuator_force),
        "legs_overlap": legs_overlap.astype(jnp.float32),
    }
