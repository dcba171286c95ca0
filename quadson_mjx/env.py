"""The locomotion environment: seed 000's RL formulation on a robot of quadson_mjx.robots, in MJX.

A policy adds foot offsets to a classical gait (seed 000 section 8): each control step the gait gives
foot targets in the robot's gait frames, the action adds up to +-action_scale_m per axis (Quadson:
5 cm), the robot's inverse kinematics turns them into the 12 motor position targets (Quadson's
five-bar IK, Caramel's serial-leg IK), and MJX steps the model several physics steps. Quadson is
the default robot (its closed chain); `env_config(robot="caramel")` runs seed 003's robot and trot. Pure `reset(rng)` / `step(state, action)` in brax's `Env` interface, so
`brax.training.agents.ppo.train` takes it directly (wrap it with `quadson_mjx.wrappers`).

Safety inside jit: a non-finite or exploded physics state ends the episode, its observation and
reward are replaced by zeros, and `metrics["nan_reset"]` counts it. An unreachable foot target is
clamped by the inverse kinematics and counted in `metrics["ik_invalid_legs"]`; it never becomes NaN.

Heights are measured from the ground under the base (`quadson_mjx.terrain`), so the height reward and
the minimum-height termination mean the same on stones as on the plane. Per step, the metrics hold the
squared tracking errors of vx, vy and yaw rate against the command (brax sums them over an episode;
mean and RMS follow from the episode length), `fall`, `base_below_terrain` (a point of the base box's
bottom face below the ground under it: with feet-only contact the box would otherwise sink into a
stone unnoticed; it ends the episode when `termination.base_below_terrain`) and `off_field` (the
base reached the edge of the stone field: a truncation, not a fall).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import mjx

from quadson_mjx import commands, gait, hfield_contact, obs_spec, rewards, sensors, terrain, terrain_tiles
from quadson_mjx.config import freeze
from quadson_mjx.env_config import check_env_config, env_config, env_gait, with_added_keys
from quadson_mjx.env_model import (
    BASE_GEOM,
    base_bottom_points,
    check_floor_plane,
    device_constant,
    feet_on_plane,
    home_contact_points,
    make_env_data,
    name_ids,
    put_model,
    training_model,
    warp_buffers,
)
from quadson_mjx.quat import quat_mul, quat_rotate
from quadson_mjx.robots import get_robot
from quadson_mjx.terrain_tiles import tile_spec

EXPLODED_SPEED = 50.0  # m/s or rad/s: no state of either robot is this fast; treat it as a blown-up solve
SPAWN_CLEARANCE_M = 0.005  # a spawn on the tiled ground starts this far above its lowest contact (at most)


class _PhysicsState(NamedTuple):
    """The part of an mjx.Data that the observation reads."""

    qpos: jax.Array
    qvel: jax.Array


class LocomotionEnv(Env):
    """A robot of quadson_mjx.robots (config key `robot`) on flat or rough ground; immutable after
    __init__. The robot supplies model, names, home pose, gait and the foot -> motor mapping."""

    # info entries that restart from the first state when an episode ends (see wrappers.py; the
    # "sensors" observation adds its encoder and history buffers: `restart_info`)
    RESTART_INFO = ("gait_progress", "episode_time", "last_ctrl", "foot_targets")
    # info entries of the tiled ground (terrain="tiles"), per robot: its tile column and row, the
    # distance it covered along its commands and the distance they asked for in this episode [m],
    # and the result of its last finished episode (-1 none yet, 0 failed, 1 success; wrappers.py)
    TILE_INFO = ("tile_type", "tile_level", "tile_progress_m", "tile_commanded_m", "tile_result")
    SENSOR_RESTART_INFO = ("last_encoders", "obs_history")
    # per-step metrics besides the reward terms; brax's evaluator sums each over an episode
    STEP_METRICS = (
        "ik_invalid_legs",
        "nan_reset",
        "forward_speed",
        "abs_roll",
        "abs_pitch",
        "vx_sq_err",  # (vx - command vx)^2 [m^2/s^2], body frame
        "vy_sq_err",
        "yaw_rate_sq_err",  # (wz - command yaw rate)^2 [rad^2/s^2]
        "base_height",  # base origin above the ground under it [m]
        "base_below_terrain",  # 1 when the base box's bottom face is below the ground under it
        "fall",  # 1 on the step an episode ends by tilt, height or the base in the ground
        "off_field",  # 1 on the step an episode ends at the stone field's edge (a truncation)
        "contact_match",  # fraction of the 4 feet whose ground contact agrees with the phase table
    )

    def __init__(self, config=None):
        cfg = with_added_keys(env_config() if config is None else config)
        check_env_config(cfg)
        self._config = freeze(cfg)
        self._robot = robot = get_robot(cfg.robot)
        self._mj_model = training_model(robot, cfg)
        self.sys = put_model(self._mj_model, cfg.impl)
        self._field = terrain.heightfield(self._mj_model)
        self._tiles = tile_spec(cfg) if cfg.terrain == "tiles" else None
        self._type_shares = (
            None
            if self._tiles is None
            else terrain_tiles.type_weights(cfg.tiles.type_weights, self._tiles.types)
        )
        base_geom = int(name_ids(self._mj_model, mujoco.mjtObj.mjOBJ_GEOM, [BASE_GEOM])[0])
        if not np.allclose(self._mj_model.geom_quat[base_geom], (1, 0, 0, 0)):
            raise ValueError("base_collision must be aligned with the base body")
        self._base_bottom = device_constant(
            base_bottom_points(self._mj_model.geom_size[base_geom]) + self._mj_model.geom_pos[base_geom],
            jnp.float32,
        )  # (15, 3) base frame [m]
        sim_dt = float(self._mj_model.opt.timestep)
        n_sub = round(cfg.ctrl_dt / sim_dt)
        if n_sub < 1 or abs(n_sub * sim_dt - cfg.ctrl_dt) > 1e-9:
            raise ValueError(f"ctrl_dt {cfg.ctrl_dt} s is not a multiple of the model timestep {sim_dt} s")
        self._n_substeps = n_sub
        self._action_spec = obs_spec.locomotion_action(robot.legs, cfg.gait_action, cfg.action_scale_m)
        self._sensor_obs = cfg.observation == "sensors"
        self._vel_ema = cfg.reward.weights.lin_vel_ema_error != 0.0  # info["vel_ema"] kept only then
        if self._sensor_obs:
            self._obs_spec = obs_spec.sensor_observation(
                robot.legs,
                robot.motor_joints,
                self._action_spec.size,
                cfg.obs_history,
                cfg.command_tracking,
                yaw_error=bool(cfg.yaw_error_tau_s),
                servo_latency=cfg.observe_servo_latency,
            )
        else:
            self._obs_spec = obs_spec.locomotion_observation(
                robot.legs, robot.motor_joints, cfg.command_tracking
            )
        self._critic_spec = (
            obs_spec.privileged_observation(robot.legs, self._obs_spec, cfg.critic_scan_points)
            if cfg.asymmetric_critic
            else None
        )
        self._scan = device_constant(
            terrain.scan_offsets(cfg.critic_scan_points, cfg.critic_scan_spacing_m), jnp.float32
        )
        self._ctrl_dt = float(cfg.ctrl_dt)
        self.episode_length = int(round(cfg.episode_length_s / cfg.ctrl_dt))

        m = self._mj_model
        motor_joints = name_ids(m, mujoco.mjtObj.mjOBJ_JOINT, robot.motor_joints)
        self._motor_qpos = device_constant(m.jnt_qposadr[motor_joints])  # (12,) legs x motors order
        # (12,) ctrl index of each motor
        self._actuator_of_motor = device_constant(name_ids(m, mujoco.mjtObj.mjOBJ_ACTUATOR, robot.actuators))
        self._base_body = int(name_ids(m, mujoco.mjtObj.mjOBJ_BODY, [robot.root_body])[0])
        key = int(name_ids(m, mujoco.mjtObj.mjOBJ_KEY, [robot.home_keyframe])[0])
        self._home_qpos = device_constant(m.key_qpos[key])
        self._home_ctrl = device_constant(m.key_ctrl[key])
        points, radius = home_contact_points(
            m, key, name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, robot.foot_geoms()), self._base_bottom
        )
        self._contact_points = device_constant(points, jnp.float32)  # (P, 3) from the base origin [m]
        self._contact_radius = device_constant(radius, jnp.float32)
        self._spawn_spheres, self._spawn_points = np.flatnonzero(radius > 0), np.flatnonzero(radius == 0)
        self._home_feet = device_constant(robot.home_feet, jnp.float32)  # (4, 3) gait frames [m]
        self._gait = env_gait(cfg)
        self._seed_speed = float(gait.seed_speed(self._gait))
        self._forward_target = self._seed_speed if cfg.reward.target_gait_speed else cfg.reward.forward_target
        self._foot_geoms = device_constant(name_ids(m, mujoco.mjtObj.mjOBJ_GEOM, robot.foot_geoms()))
        self._warp_buffers, self._foot_sensors, self._feet_on_plane = None, None, False
        if cfg.impl == "warp":
            self._warp_buffers = warp_buffers(m, cfg.warp_max_worlds)
            self._feet_on_plane = feet_on_plane(cfg)
            if self._feet_on_plane:
                check_floor_plane(m)
            else:
                sensors = name_ids(m, mujoco.mjtObj.mjOBJ_SENSOR, [f"{g}_ground" for g in robot.foot_geoms()])
                self._foot_sensors = device_constant(m.sensor_adr[sensors])
        # nominal values the privileged observation divides the randomized model's by
        self._foot_radius = device_constant(m.geom_size[np.asarray(self._foot_geoms), 0])
        self._nominal_base_mass = float(m.body_mass[self._base_body])
        self._nominal_gain = device_constant(m.actuator_gainprm[np.asarray(self._actuator_of_motor), 0])
        root = int(m.body_jntadr[self._base_body])
        self._root_q = int(m.jnt_qposadr[root])
        self._root_v = int(m.jnt_dofadr[root])
        if (
            root < 0
            or m.jnt_type[root] != mujoco.mjtJoint.mjJNT_FREE
            or (self._root_q, self._root_v) != (0, 0)
        ):
            raise ValueError("the base's free joint must come first in qpos/qvel")

    # --- brax Env interface -------------------------------------------------------------------
    @property
    def observation_size(self):
        """The actor's observation size; with asymmetric_critic brax's dictionary of shapes:
        {"state": (actor,), "privileged_state": (critic,)} (PPO's policy_obs_key, value_obs_key)."""
        if self._critic_spec is None:
            return self.obs_spec.size
        return {"state": (self.obs_spec.size,), "privileged_state": (self._critic_spec.size,)}

    @property
    def critic_spec(self) -> obs_spec.Spec | None:
        """The critic's privileged observation (obs_spec.privileged_observation) with
        asymmetric_critic, else None (the critic sees the actor's observation)."""
        return self._critic_spec

    @property
    def restart_info(self) -> tuple[str, ...]:
        """The info entries that restart from the first state when an episode ends."""
        sensor = self.SENSOR_RESTART_INFO if self._sensor_obs else ()
        ema = ("vel_ema",) if self._vel_ema else ()
        return self.RESTART_INFO + sensor + (("yaw_error",) if self._config.yaw_error_tau_s else ()) + ema

    def actor_obs(self, obs):
        """The actor's part of an observation (obs itself unless it is a dictionary)."""
        return obs["state"] if isinstance(obs, dict) else obs

    def with_command(self, obs, command):
        """obs (..., size) or its dictionary with the command entry set to command (..., 3); the
        entry sits at the same place in the actor's and the critic's observations."""
        if not self._config.command_tracking:
            return obs
        where = self.obs_spec.slices()["command"]
        if isinstance(obs, dict):
            return {k: v.at[..., where].set(command) for k, v in obs.items()}
        return obs.at[..., where].set(command)

    @property
    def action_size(self) -> int:
        return self.action_spec.size

    @property
    def obs_spec(self) -> obs_spec.Spec:
        """The observation, entry by entry (quadson_mjx.obs_spec): what `_get_obs` assembles."""
        return self._obs_spec

    @property
    def action_spec(self) -> obs_spec.Spec:
        return self._action_spec

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def max_worlds(self) -> int | None:
        """The most worlds one batch may step (under Warp: env.warp_max_worlds, what the contact
        buffer is sized for); None: no limit (the JAX implementation sizes per world)."""
        return None if self._warp_buffers is None else int(self._config.warp_max_worlds)

    @property
    def warp_buffers(self) -> tuple[int, int] | None:
        """Under Warp (naconmax, njmax) of env_model.warp_buffers; None on the JAX implementation."""
        return self._warp_buffers

    @property
    def config(self):
        return self._config

    @property
    def mj_model(self) -> mujoco.MjModel:
        return self._mj_model

    @property
    def motor_actuators(self) -> jax.Array:
        """(12,) ctrl index of each motor, the robot's motor order."""
        return self._actuator_of_motor

    @property
    def robot(self):
        """The quadson_mjx.robots.Robot of the config's `robot`."""
        return self._robot

    @property
    def gait_params(self) -> gait.GaitParams:
        """The gait the environment runs (env_config.env_gait of its config)."""
        return self._gait

    @property
    def base_body(self) -> int:
        return self._base_body

    @property
    def ctrl_dt(self) -> float:
        return self._ctrl_dt

    def sample_command(self, rng):
        """-> (command (3,) vx [m/s], vy [m/s], yaw rate [rad/s], seconds until the next one):
        commands.sample_command of the config (without command_tracking: the gait's seed-speed walk)."""
        return commands.sample_command(self._config, self._seed_speed, rng)

    def episode_info(self, rng):
        """What is sampled anew for every episode: command and its timer, latency, push timer. rng: key."""
        cfg = self._config
        k_cmd, k_lat, k_push, k_noise = jax.random.split(rng, 4)
        command, command_timer = self.sample_command(k_cmd)
        if cfg.randomize:
            lo_s, hi_s = cfg.randomization.latency_s
            latency = jax.random.uniform(k_lat, (), minval=lo_s, maxval=hi_s)
            latency_steps = jnp.round(latency / self.sys.opt.timestep).astype(jnp.int32)
        else:
            latency_steps = jnp.zeros((), jnp.int32)
        push_timer = jax.random.uniform(
            k_push, (), minval=cfg.push.interval_s[0], maxval=cfg.push.interval_s[1]
        )
        info = {
            "command": command,
            "command_timer": command_timer,  # seconds until the next command [s]
            "latency_steps": latency_steps,
            "push_timer": push_timer,
            "rng": k_noise,
        }
        if self._sensor_obs:  # a key of its own: the other draws stay those of a true_state config
            timestep = float(self._mj_model.opt.timestep)
            info.update(sensors.episode_sensor_errors(cfg, timestep, jax.random.fold_in(rng, 7)))
            if cfg.observe_servo_latency:
                info["servo_latency_reading"] = sensors.servo_latency_reading(
                    cfg, latency_steps * timestep, jax.random.fold_in(rng, 11)
                )
        return info

    @property
    def tiles(self) -> terrain_tiles.TerrainSpec | None:
        """The tiled ground (terrain="tiles"), else None."""
        return self._tiles

    def reset(self, rng) -> State:
        """A new episode at the home pose: at the origin, or on the tiled ground on a random tile
        column (tiles.type_weights) and a level in [tiles.min_init_level, tiles.max_init_level]
        (reset_on_tile)."""
        if self._tiles is None:
            k_info, _ = jax.random.split(rng)
            return self._start(self._home_qpos, k_info)
        k_type, k_level, k = jax.random.split(rng, 3)
        if self._type_shares is None:  # every type alike (the draw of runs before type_weights)
            tile_type = jax.random.randint(k_type, (), 0, len(self._tiles.types))
        else:
            tile_type = terrain_tiles.draw_type(k_type, self._type_shares)
        t = self._config.tiles
        level = jax.random.randint(k_level, (), t.min_init_level, t.max_init_level + 1)
        return self.reset_on_tile(k, tile_type, level)

    def reset_on_tile(self, rng, tile_type, level) -> State:
        """A new episode on tile (tile_type, level) of the tiled ground: the home pose at a uniform
        place on the tile (terrain_tiles.spawn_xy) with a uniform heading, lowered or raised until
        its lowest contact point (a foot sphere or the base box) is SPAWN_CLEARANCE_M above the
        ground under it (terrain_tiles.spawn_lift). The wrappers' auto-reset calls it with the
        curriculum's next level."""
        if self._tiles is None:
            raise ValueError("reset_on_tile needs the tiled ground (env.terrain=tiles)")
        k_xy, k_yaw, k_info = jax.random.split(rng, 3)
        tile_type, level = jnp.asarray(tile_type, jnp.int32), jnp.asarray(level, jnp.int32)
        xy = terrain_tiles.spawn_xy(self._tiles, k_xy, tile_type, level, self._config.tiles.spawn_margin_m)
        yaw = jax.random.uniform(k_yaw, (), minval=-jnp.pi, maxval=jnp.pi)
        p = self._contact_points
        points_xy = terrain.turned(xy, yaw, p)
        home_z = self._home_qpos[2]
        f, b = self._spawn_spheres, self._spawn_points  # spheres on a disc of samples, points once
        lift = jnp.maximum(
            terrain_tiles.spawn_lift(self._field, points_xy[f], home_z + p[f, 2], self._contact_radius[f]),
            terrain_tiles.spawn_lift(self._field, points_xy[b], home_z + p[b, 2], self._contact_radius[b], 1),
        )
        turn = jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        qpos = self._home_qpos.at[:2].set(xy).at[2].set(home_z + lift + SPAWN_CLEARANCE_M)
        qpos = qpos.at[3:7].set(quat_mul(turn, self._home_qpos[3:7]))
        state = self._start(qpos, k_info)
        state.info.update(
            tile_type=tile_type,
            tile_level=level,
            tile_progress_m=jnp.zeros(()),
            tile_commanded_m=jnp.zeros(()),
            tile_result=jnp.full((), -1.0, jnp.float32),
        )
        return state

    def _start(self, qpos, k_info) -> State:
        with hfield_contact.sphere_contacts(self._config.hfield_foot_contacts):
            data = make_env_data(self._mj_model, self.sys, self._warp_buffers)
        data = data.replace(qpos=qpos, qvel=jnp.zeros(self.sys.nv), ctrl=self._home_ctrl)
        # Positions only (body, geom and site frames): a step recomputes everything else from qpos,
        # qvel and ctrl, so its result is the same as after a full mjx.forward (tested bit for bit),
        # and the reset compiles in 1.9 s instead of 5.5 s on one H100 (a forward is most of a step).
        # Forces, accelerations and contacts are zero until the first step.
        data = mjx.kinematics(self.sys, data)
        info = {
            **self.episode_info(k_info),
            "gait_progress": jnp.zeros(()),
            "episode_time": jnp.zeros(()),
            "last_action": jnp.zeros(self.action_size),
            "last_ctrl": self._home_ctrl,
            "foot_targets": self._home_feet,  # (4, 3) last foot targets, shoulder frames [m]
        }
        metrics = {f"reward/{k}": jnp.zeros(()) for k in self._config.reward.weights}
        metrics.update({k: jnp.zeros(()) for k in self.STEP_METRICS})
        if self._sensor_obs:
            info["last_encoders"] = None  # the first reading: motor_vel 0, history filled with it
            info["obs_history"] = None
        if self._config.yaw_error_tau_s:
            info["yaw_error"] = jnp.zeros(1)  # the leaky integral starts at 0 (sensors.sensor_step)
        if self._vel_ema:
            info["vel_ema"] = jnp.zeros(2)  # lin_vel_ema_error's average, from standing [m/s]
        obs, info = self._observe(data, info, None, (data.qpos, data.qvel), jnp.zeros(4, bool))
        return State(data, obs, jnp.zeros(()), jnp.zeros(()), metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        cfg = self._config
        info = dict(state.info)
        action = jnp.clip(action, -1.0, 1.0)
        ctrl, ik_invalid, cycle_s, targets = self._motor_targets(info, action)

        data = state.pipeline_state
        if cfg.pushes:
            data, info = self._maybe_push(data, info)
        data, sensed = self._physics_steps(data, info, ctrl, self._sensor_obs)

        info["gait_progress"] = jnp.mod(info["gait_progress"] + self._ctrl_dt / cycle_s, 1.0)
        info["episode_time"] = info["episode_time"] + self._ctrl_dt
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        sane = finite & (jnp.max(jnp.abs(data.qvel[:6])) < EXPLODED_SPEED)

        rpy, lin_vel, ang_vel = self._base_state(data)
        height = data.qpos[2] - terrain.ground_height(self._field, data.qpos[:2])
        contact = self.foot_contact(data)
        step = self._ctrl_dt / cycle_s  # one control step, as a fraction of the cycle
        stance_near = self.scheduled_stance(info["gait_progress"] + jnp.stack([-step, 0.0, step]))
        stance = stance_near[1]
        term = cfg.termination
        below = self.base_clearance(data.qpos) < term.base_clearance_m
        fallen = (
            (jnp.abs(rpy[0]) > term.max_tilt_rad)
            | (jnp.abs(rpy[1]) > term.max_tilt_rad)
            | (height < term.min_height_m)
        )
        if term.base_below_terrain:
            fallen = fallen | below
        if self._vel_ema:
            info["vel_ema"] = rewards.velocity_ema_step(
                info["vel_ema"], lin_vel, self._ctrl_dt, cfg.reward.velocity_ema_s
            )
        terms = self._get_reward(
            data, action, info, rpy, lin_vel, ang_vel, height, contact, stance_near, fallen
        )
        weights = cfg.reward.weights
        reward = sum(weights[k] * v for k, v in terms.items())
        off_field = ~terrain.on_field(self._field, data.qpos[:2], term.off_field_margin_m)
        done = fallen | off_field | ~sane
        err = jnp.square(jnp.stack([lin_vel[0], lin_vel[1], ang_vel[2]]) - info["command"])
        info["last_action"] = action
        info["last_ctrl"] = ctrl
        info["foot_targets"] = targets
        if self._tiles is not None:  # the curriculum's measure, along the command of this step
            cmd_speed = jnp.linalg.norm(info["command"][:2])
            along = jnp.dot(lin_vel[:2], info["command"][:2]) / jnp.maximum(cmd_speed, 1e-6)
            info["tile_progress_m"] = (
                info["tile_progress_m"] + jnp.clip(along, 0.0, cmd_speed) * self._ctrl_dt
            )
            info["tile_commanded_m"] = info["tile_commanded_m"] + cmd_speed * self._ctrl_dt
        if cfg.command_tracking and cfg.command_resample_s[1] > 0:  # a new command mid-episode
            info["command"], info["command_timer"], info["rng"] = commands.resample(
                cfg, self._seed_speed, info["command"], info["command_timer"] - self._ctrl_dt, info["rng"]
            )
        info["rng"] = jax.random.split(info["rng"])[0]  # fresh sensor noise every step
        obs, info = self._observe(data, info, (rpy, lin_vel, ang_vel), sensed, contact)
        obs = jax.tree.map(lambda o: jnp.where(sane, o, 0.0), obs)
        reward = jnp.where(sane, reward, 0.0)

        metrics = dict(state.metrics)  # keep keys that wrappers added (brax's eval adds "reward")
        metrics.update({f"reward/{k}": jnp.where(sane, weights[k] * v, 0.0) for k, v in terms.items()})
        metrics.update(
            ik_invalid_legs=ik_invalid.astype(jnp.float32),
            nan_reset=(~sane).astype(jnp.float32),
            forward_speed=jnp.where(sane, lin_vel[0], 0.0),
            abs_roll=jnp.where(sane, jnp.abs(rpy[0]), 0.0),
            abs_pitch=jnp.where(sane, jnp.abs(rpy[1]), 0.0),
            vx_sq_err=jnp.where(sane, err[0], 0.0),
            vy_sq_err=jnp.where(sane, err[1], 0.0),
            yaw_rate_sq_err=jnp.where(sane, err[2], 0.0),
            base_height=jnp.where(sane, height, 0.0),
            base_below_terrain=(sane & below).astype(jnp.float32),
            fall=(sane & fallen).astype(jnp.float32),
            off_field=(sane & off_field & ~fallen).astype(jnp.float32),
            contact_match=jnp.where(sane, jnp.mean(contact == stance), 0.0),
        )
        return state.replace(
            pipeline_state=data,
            obs=obs,
            reward=reward,
            done=done.astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    # --- pieces of step ---------------------------------------------------------------------------
    def gait_targets(self, info, params=None, command=None):
        """The gait's foot targets for the coming control step, before any action: (4, 3) in the
        robot's gait frames [m] (Quadson: shoulder frames), blended from the home stance over the
        first gait_ramp_s (smoothstep):
        the gait's first targets are up to 6 cm from the home feet, a jump the servos would slam.
        Controllers that act on the gait (e.g. the PID stabilizer) start from these."""
        params = self._gait if params is None else params
        command = info["command"] if command is None else command
        targets = self._robot.foot_targets(info["gait_progress"] * params.cycle_s, command, params)
        s = jnp.clip((info["episode_time"] + self._ctrl_dt) / self._config.gait_ramp_s, 0.0, 1.0)
        return self._home_feet + (s * s * (3.0 - 2.0 * s)) * (targets - self._home_feet)

    def _motor_targets(self, info, action):
        """Gait + offsets -> (ctrl (nu,), number of legs whose target was clamped, cycle time [s])."""
        cfg = self._config
        params = self._gait
        if cfg.gait_action:
            r = cfg.gait_action_range
            length_scale = 1.0 + r * action[12]
            freq_scale = 1.0 + r * action[13]
            params = params._replace(
                step_length_m=params.step_length_m * length_scale, cycle_s=params.cycle_s / freq_scale
            )
            command = info["command"] * length_scale * freq_scale
        else:
            command = info["command"]
        targets = self.gait_targets(info, params, command)  # (4, 3) gait frames
        targets = targets + cfg.action_scale_m * action[:12].reshape(4, 3)
        angles, valid = self._robot.motor_targets(targets)  # (4, 3), (4,)
        ctrl = self._home_ctrl.at[self._actuator_of_motor].set(angles.reshape(12))
        return ctrl, jnp.sum(~valid), params.cycle_s, targets

    def _physics_steps(self, data, info, ctrl, read_sensors, physics_step=None):
        """-> (data after the control step's physics steps, sensed). The first latency_steps steps
        hold info["last_ctrl"], the rest ctrl. sensed: (qpos, qvel) as the "sensors" observation
        reads them, sensor_latency_steps physics steps before the step's end (None unless
        read_sensors). physics_step(data, ctrl) -> data: one physics step (default mjx.step).
        The reading rides in the scan's carry, not in a stacked per-step output: under Warp,
        stacking the data's fields per step halved the env's rate."""
        physics_step = physics_step or (lambda d, c: mjx.step(self.sys, d.replace(ctrl=c)))
        read = self._n_substeps - jnp.clip(info.get("sensor_latency_steps", 0), 0, self._n_substeps)

        def substep(carry, i):
            data, sensed = carry
            data = physics_step(data, jnp.where(i < info["latency_steps"], info["last_ctrl"], ctrl))
            if sensed is not None:  # physics step `read` of the scan (0: the state before the first)
                sensed = jax.tree.map(
                    lambda new, old: jnp.where(i + 1 == read, new, old), (data.qpos, data.qvel), sensed
                )
            return (data, sensed), None

        sensed = (data.qpos, data.qvel) if read_sensors else None
        with hfield_contact.sphere_contacts(self._config.hfield_foot_contacts):  # traced inside
            (data, sensed), _ = jax.lax.scan(substep, (data, sensed), jnp.arange(self._n_substeps))
        return data, sensed

    def foot_contact(self, data) -> jax.Array:
        """(4,) bool, LEGS order: the foot's collision sphere touches the ground (a contact of that
        geom with negative distance; the model has no contact margin). After mjx.step these are the
        contacts of the last physics substep's start (MuJoCo detects contacts before it integrates),
        one timestep (4 ms) before the control step's end. Under Warp, whose contact list is shared
        by all worlds, at the same point of the step: on the plane, the foot sphere's centre less
        its (possibly randomized) radius below z = 0, MuJoCo's sphere-plane distance
        (env_model.feet_on_plane); elsewhere the feet's contact sensors (foot_contact_sensors)."""
        if self._feet_on_plane:
            feet = self._foot_geoms
            return data.geom_xpos[feet, 2] - self.sys.geom_size[feet, 0] < 0.0
        if self._foot_sensors is not None:
            return data.sensordata[self._foot_sensors] > 0.0
        c = data._impl.contact
        involved = (c.geom1[None, :] == self._foot_geoms[:, None]) | (
            c.geom2[None, :] == self._foot_geoms[:, None]
        )
        return jnp.any(involved & (c.dist[None, :] < 0.0), axis=1)

    def scheduled_stance(self, gait_progress) -> jax.Array:
        """(..., 4) bool: the phase table puts the leg in stance at gait_progress (...) (a fraction
        of the cycle, info["gait_progress"])."""
        return gait.leg_phases(gait_progress * self._gait.cycle_s, self._gait) < self._gait.duty

    def _maybe_push(self, data, info):
        info["push_timer"], kick, info["rng"] = commands.push(
            self._config.push, info["push_timer"] - self._ctrl_dt, info["rng"]
        )
        return data.replace(qvel=data.qvel.at[:2].add(kick)), info

    def ground_height(self, xy):
        """xy (..., 2) world [m] -> (...,) height of the ground there [m] (0 on the flat scene)."""
        return terrain.ground_height(self._field, xy)

    def base_clearance(self, qpos):
        """qpos (nq,) -> lowest height of the base box's bottom face above the ground under it [m]
        (15 points of the face; negative: inside a stone or below the plane)."""
        points = qpos[:3] + quat_rotate(qpos[3:7], self._base_bottom)  # (15, 3) world
        return jnp.min(points[:, 2] - terrain.ground_height(self._field, points[:, :2]))

    def _base_state(self, data):
        return sensors.base_state(data.qpos, data.qvel)

    def observation(self, qpos, qvel, info):
        """The actor's observation of a physics state given as qpos (nq,), qvel (nv,) (e.g. CPU
        MuJoCo's, or a robot's estimate), at info's gait_progress and command (and, for the
        "sensors" observation, its last encoders, action and history); sensor noise as the config says."""
        if self._sensor_obs:
            parts, _ = self._sensor_parts(jnp.asarray(qpos), jnp.asarray(qvel), info)
            return self._obs_spec.assemble(parts)
        return self._get_obs(_PhysicsState(jnp.asarray(qpos), jnp.asarray(qvel)), info)

    def _phase(self, info):
        return 2 * jnp.pi * gait.leg_phases(info["gait_progress"] * self._gait.cycle_s, self._gait)

    def _sensor_parts(self, qpos, qvel, info):
        """-> (entries of the "sensors" observation, info with its encoder and history buffers
        moved on): sensors.sensor_step on the state the sensors read (sensor_latency_steps old)."""
        return sensors.sensor_step(
            self._config, qpos, qvel, qpos[self._motor_qpos], info, self._ctrl_dt, self._phase(info)
        )

    def _observe(self, data, info, base_state, sensed, contact):
        """-> (the observation: the actor's, or with asymmetric_critic {"state": actor,
        "privileged_state": critic}; info with the sensor buffers moved on). sensed: (qpos, qvel)
        the "sensors" observation reads; contact (4,) bool: the feet on the ground."""
        if self._sensor_obs:
            parts, info = self._sensor_parts(sensed[0], sensed[1], info)
            actor = self._obs_spec.assemble(parts)
        else:
            actor = self._get_obs(data, info, base_state)
            parts = self._obs_spec.split(actor)
        if self._critic_spec is None:
            return actor, info
        critic = self._critic_spec.assemble({**parts, **self._privileged_parts(data, info, contact)})
        return {"state": actor, "privileged_state": critic}, info

    def _privileged_parts(self, data, info, contact) -> dict:
        """The simulator-only entries of obs_spec.privileged_observation (the critic's view)."""
        sys = self.sys  # per-env under domain randomization
        physics = jnp.stack(
            [
                sys.geom_friction[self._foot_geoms[0], 0],
                sys.body_mass[self._base_body] / self._nominal_base_mass,
                jnp.mean(sys.actuator_gainprm[self._actuator_of_motor, 0] / self._nominal_gain),
                info["latency_steps"] * sys.opt.timestep,
            ]
        )
        feet = data.geom_xpos[self._foot_geoms]  # (4, 3) world, at the last substep's start
        return sensors.privileged_parts(
            self._field,
            data.qpos,
            data.qvel,
            feet,
            self._foot_radius,
            contact,
            physics,
            info,
            sys.opt.timestep,
            self._scan,
        )

    def _get_obs(self, data, info, base_state=None):
        """The observation of `obs_spec` (seed 000's 29 values; + command when tracking), read by
        sensors.observation_parts. base_state: (rpy, lin_vel, ang_vel) when the caller has it."""
        rpy, lin_vel, ang_vel = self._base_state(data) if base_state is None else base_state
        phase = self._phase(info)
        motor_pos = data.qpos[self._motor_qpos]
        parts = sensors.observation_parts(
            self._config, rpy, lin_vel, ang_vel, motor_pos, phase, info.get("command"), info.get("rng")
        )
        return self._obs_spec.assemble(parts)

    def _get_reward(
        self, data, action, info, rpy, lin_vel, ang_vel, height, contact, stance_near, fallen
    ) -> dict:
        """Unweighted reward terms (rewards.locomotion_terms); height: the base origin above the ground
        under it [m]; contact (4,) bool: the feet on the ground (at the last substep, foot_contact);
        stance_near (3, 4) bool: the phase table's stance legs one control step before, at and after
        the end of the step; fallen () bool: this step ends the episode by a fall."""
        return rewards.locomotion_terms(
            self._config.reward,
            self._forward_target,
            lin_vel=lin_vel,
            ang_vel=ang_vel,
            rpy=rpy,
            height=height,
            action=action,
            last_action=info["last_action"],
            actuator_force=data.actuator_force,
            command=info["command"],
            contact=contact,
            stance=stance_near[1],
            stance_near=stance_near,
            fallen=fallen,
            vel_ema=info.get("vel_ema"),
        )
