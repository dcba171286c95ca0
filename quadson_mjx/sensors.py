"""What the environment's sensors read: the entries of the observation spec (quadson_mjx.obs_spec)
from a physics state, with the config's sensor noise when randomized.

Pure JAX, jitted and vmapped as part of the environment's step. The deploy loop builds the same
entries from the robot's own sensors (quadson_mjx.deploy).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import terrain
from quadson_mjx.obs_spec import HISTORY_ENTRIES, lagged, yaw_error_step
from quadson_mjx.quat import quat_mul, quat_rotate_inverse, quat_to_rpy, tilt_quat


def base_state(qpos, qvel):
    """The base as the IMU and a velocity estimator see it, from the free joint's qpos (nq,) and qvel
    (nv,): -> rpy (3,) [rad] (ZYX), body-frame linear velocity (3,) [m/s] (qvel[0:3] is world-frame),
    body-frame angular velocity (3,) [rad/s] (qvel[3:6] is already in the body frame)."""
    quat = qpos[3:7]
    return quat_to_rpy(quat), quat_rotate_inverse(quat, qvel[0:3]), qvel[3:6]


def observation_parts(cfg, rpy, lin_vel, ang_vel, motor_pos, phase, command, rng) -> dict:
    """cfg: the env config; rpy (3,) [rad], body-frame lin_vel (3,) [m/s] and ang_vel (3,) [rad/s],
    motor_pos (12,) [rad], phase (4,) [rad] (2 pi x each leg's gait phase), command (3,) (read only
    when the config tracks commands), rng: the step's noise key (read only when randomized) -> entry name -> value, the entries of obs_spec.locomotion_observation.
    Randomized configs add Gaussian noise of std cfg.noise.* to the IMU, velocity and encoders."""
    if cfg.randomize:
        k = jax.random.split(jax.random.fold_in(rng, 1), 4)
        n = cfg.noise
        rpy = rpy + n.rpy * jax.random.normal(k[0], (3,))
        lin_vel = lin_vel + n.lin_vel * jax.random.normal(k[1], (3,))
        ang_vel = ang_vel + n.ang_vel * jax.random.normal(k[2], (3,))
        motor_pos = motor_pos + n.motor_pos * jax.random.normal(k[3], motor_pos.shape)
    parts = {
        "base_rpy": rpy,
        "base_lin_vel": lin_vel,
        "base_ang_vel": ang_vel,
        "motor_pos": motor_pos,
        "phase_sin": jnp.sin(phase),
        "phase_cos": jnp.cos(phase),
    }
    if cfg.command_tracking:
        parts["command"] = command
    return parts


# --- the robot's own sensors (the "sensors" observation, obs_spec.sensor_observation) ---------------


def episode_sensor_errors(cfg, timestep: float, rng) -> dict:
    """The sensor errors of one episode, drawn from cfg.sensor when cfg.randomize (else none):
    gyro_bias (3,) [rad/s] uniform in +-gyro_bias_rps, imu_tilt (2,) roll and pitch of the IMU's
    mounting [rad] uniform in +-imu_tilt_rad, sensor_latency_steps () int32: the readings' age in
    physics timesteps (latency_s uniform, rounded to the model's timestep [s])."""
    s = cfg.sensor
    if not cfg.randomize:
        return {
            "gyro_bias": jnp.zeros(3),
            "imu_tilt": jnp.zeros(2),
            "sensor_latency_steps": jnp.zeros((), jnp.int32),
        }
    k_b, k_t, k_l = jax.random.split(rng, 3)
    latency = jax.random.uniform(k_l, (), minval=s.latency_s[0], maxval=s.latency_s[1])
    return {
        "gyro_bias": jax.random.uniform(k_b, (3,), minval=-s.gyro_bias_rps, maxval=s.gyro_bias_rps),
        "imu_tilt": jax.random.uniform(k_t, (2,), minval=-s.imu_tilt_rad, maxval=s.imu_tilt_rad),
        "sensor_latency_steps": jnp.round(latency / timestep).astype(jnp.int32),
    }


def servo_latency_reading(cfg, latency_s, rng):
    """The servos' latency as the robot's calibration reports it for an episode whose actuation
    latency is latency_s [s] (the env's, in physics timesteps): latency_s + an error uniform in
    +-cfg.sensor.servo_latency_error_s when cfg.randomize (else latency_s), not below 0 -> () [s]."""
    if not cfg.randomize:
        return jnp.asarray(latency_s, jnp.float32)
    e = cfg.sensor.servo_latency_error_s
    return jnp.maximum(latency_s + jax.random.uniform(rng, (), minval=-e, maxval=e), 0.0).astype(jnp.float32)


def gravity_direction(imu_quat):
    """(..., 4) wxyz orientation of the IMU in a z-up world -> (..., 3) the unit gravity direction in
    the IMU's frame ((0, 0, -1) when level); yaw-independent. The deploy loop computes the same."""
    return quat_rotate_inverse(
        imu_quat, jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0]), imu_quat.shape[:-1] + (3,))
    )


def quantize(x, step: float):
    """x rounded to multiples of step (an encoder's resolution [rad]); step 0: x unchanged."""
    return x if step <= 0 else jnp.round(x / step) * step


def read_sensors(cfg, qpos, qvel, motor_pos, errors: dict, rng) -> dict:
    """What the IMU and the encoders report for a physics state: qpos (nq,), qvel (nv,) (free joint
    first), motor_pos (12,) true motor angles [rad], errors: episode_sensor_errors, rng: noise key ->
    gravity (3,) (the IMU, mounted with errors["imu_tilt"], sees the base's orientation times the
    tilt), gyro (3,) [rad/s] (the base's angular velocity in the IMU frame + bias), motor_pos (12,)
    [rad] (quantised to cfg.sensor.encoder_resolution_rad). When cfg.randomize, Gaussian noise of
    cfg.sensor's stds is added (gravity_noise, gyro_noise_rps, encoder_noise_rad) before quantising."""
    s = cfg.sensor
    tilt = tilt_quat(errors["imu_tilt"])
    gravity = gravity_direction(quat_mul(qpos[3:7], tilt))
    gyro = quat_rotate_inverse(tilt, qvel[3:6]) + errors["gyro_bias"]
    if cfg.randomize:
        k = jax.random.split(jax.random.fold_in(rng, 2), 3)
        gravity = gravity + s.gravity_noise * jax.random.normal(k[0], (3,))
        gyro = gyro + s.gyro_noise_rps * jax.random.normal(k[1], (3,))
        motor_pos = motor_pos + s.encoder_noise_rad * jax.random.normal(k[2], motor_pos.shape)
    return {"gravity": gravity, "gyro": gyro, "motor_pos": quantize(motor_pos, s.encoder_resolution_rad)}


def history_block(parts: dict) -> jax.Array:
    """The entries of obs_spec.HISTORY_ENTRIES of one tick, concatenated: (3 + 3 + 12 + 12 + A,)."""
    return jnp.concatenate([parts[n] for n in HISTORY_ENTRIES])


def sensor_observation_parts(
    readings: dict, last_encoders, ctrl_dt: float, last_action, history, phase, command
) -> tuple[dict, jax.Array]:
    """The entries of obs_spec.sensor_observation from one tick's readings (read_sensors),
    last_encoders (12,): the previous tick's motor_pos reading (motor_vel is their difference over
    ctrl_dt), last_action (A,), history (H - 1, block): earlier ticks' history_block, newest first,
    phase (4,) [rad] (2 pi x the legs' gait phases), command (3,) -> (parts, the new history)."""
    parts = {
        "gravity": readings["gravity"],
        "gyro": readings["gyro"],
        "motor_pos": readings["motor_pos"],
        "motor_vel": (readings["motor_pos"] - last_encoders) / ctrl_dt,
        "last_action": last_action,
        "phase_sin": jnp.sin(phase),
        "phase_cos": jnp.cos(phase),
        "command": command,
    }
    sizes = [parts[n].shape[-1] for n in HISTORY_ENTRIES]
    for lag in range(1, history.shape[0] + 1):
        pieces = jnp.split(history[lag - 1], np.cumsum(sizes)[:-1])
        parts.update({lagged(n, lag): p for n, p in zip(HISTORY_ENTRIES, pieces, strict=True)})
    new_history = jnp.concatenate([history_block(parts)[None], history], axis=0)[: history.shape[0]]
    return parts, new_history


def sensor_step(cfg, qpos, qvel, motor_pos, info: dict, ctrl_dt: float, phase) -> tuple[dict, dict]:
    """One tick of the "sensors" observation: read_sensors on qpos (nq,), qvel (nv,), motor_pos
    (12,) (the state the sensors see), then sensor_observation_parts with info's buffers
    (last_encoders, obs_history; None on reset: the first reading is also the one before, so
    motor_vel is 0 and the history holds it; with cfg.yaw_error_tau_s, yaw_error (1,): 0 on reset,
    and it stays 0 at that first tick), last_action, command, the episode's sensor errors and its
    noise key; phase (4,) [rad]. -> (entries, info with last_encoders, obs_history and yaw_error
    moved on)."""
    readings = read_sensors(cfg, qpos, qvel, motor_pos, info, jax.random.fold_in(info["rng"], 3))
    info = dict(info)
    first = info["last_encoders"] is None
    if first:
        info["last_encoders"] = readings["motor_pos"]
        tick0 = {**readings, "motor_vel": jnp.zeros_like(motor_pos), "last_action": info["last_action"]}
        info["obs_history"] = jnp.tile(history_block(tick0)[None], (cfg.obs_history - 1, 1))
    parts, info["obs_history"] = sensor_observation_parts(
        readings,
        info["last_encoders"],
        ctrl_dt,
        info["last_action"],
        info["obs_history"],
        phase,
        info["command"],
    )
    info["last_encoders"] = readings["motor_pos"]
    if cfg.yaw_error_tau_s:
        if not first:  # 0 at the first tick, as the deploy loop's
            info["yaw_error"] = yaw_error_step(
                info["yaw_error"], readings["gyro"][2:], info["command"][2:], ctrl_dt, cfg.yaw_error_tau_s
            )
        parts["yaw_error"] = info["yaw_error"]
    if cfg.observe_servo_latency:  # measured once before the walk (episode_info)
        parts["servo_latency"] = info["servo_latency_reading"][None]
    if not cfg.command_tracking:  # a gait policy at the gait's own speed observes no command
        del parts["command"]
    return parts, info


def privileged_parts(
    field, qpos, qvel, feet, foot_radius, contact, physics, info: dict, timestep, scan=None
) -> dict:
    """The simulator-only entries of obs_spec.privileged_observation: field the terrain's height
    field, qpos (nq,), qvel (nv,), feet (4, 3) foot positions [m] (world), foot_radius (4,) [m],
    contact (4,) bool, physics (4,) the episode's friction, mass scale, motor strength and actuation
    latency [s]; info: its sensor errors (absent for a true_state observation: zeros), timestep [s];
    scan: (n, 2) heading-frame offsets of the ground scan (terrain.scan_offsets; None or n = 0: none)."""
    rpy, lin_vel, ang_vel = base_state(qpos, qvel)
    ground = terrain.ground_height(field, qpos[:2])
    under_feet = terrain.ground_height(field, feet[:, :2])
    latency = info.get("sensor_latency_steps", jnp.zeros((), jnp.int32)) * timestep
    parts = {}
    if scan is not None and scan.shape[0]:
        parts["ground_scan"] = terrain.ground_scan(field, qpos[:2], rpy[2], scan, under=ground)
    return parts | {
        "true_lin_vel": lin_vel,
        "true_ang_vel": ang_vel,
        "base_height": (qpos[2] - ground)[None],
        "foot_contact": contact.astype(jnp.float32),
        "foot_clearance": feet[:, 2] - foot_radius - under_feet,
        "ground_under_feet": under_feet - ground,
        "physics": physics,
        "sensor_model": jnp.concatenate(
            [info.get("gyro_bias", jnp.zeros(3)), info.get("imu_tilt", jnp.zeros(2)), latency[None]]
        ),
    }
