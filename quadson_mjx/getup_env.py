"""The get-up task: Quadson dropped in a random orientation, a policy that stands it up again.

    from quadson_mjx.env_config import env_config
    env = GetupEnv(env_config(task="getup", randomize=True))            # or terrain="rough"
    state = jax.jit(env.reset)(key); state = jax.jit(env.step)(state, action)   # action (12,)

The seed's future work lists self-righting; MuJoCo Playground's Go1 getup task is the field's
anchor. This environment is LocomotionEnv's model loading, randomization, sensors, privileged critic
and wrappers with its own reset, action, reward and success measure:

* reset: a start of quadson_mjx.robots.quadson.getup_start (class back, left/right side, belly or
  tilted; motor angles uniform in the real limits, every check of that module passed; the lowest
  point 0.2-0.5 m above the ground, env.getup.drop_height_m), or, with env.getup.stand_start_prob
  (training: 40 %, as Playground's Go1 getup; evaluations: 0), the home stance on the ground
  (info["start_class"] STANDING_CLASS), so that holding the stance is trained; env.getup.topple_prob
  of those standing starts are knocked over at once (TOPPLED_CLASS: a tipping rate about a random
  horizontal axis, env.getup.topple_rate_rps), so that catching a fall is trained. The episode starts at the drop: the
  fall and the landing are part of it, as on the robot. On the stone field the robot is dropped at
  a uniform place at least FIELD_MARGIN_M inside the field's edge, above the highest ground within
  SPAWN_RADIUS_M of it. The motors start holding the sampled angles.
* action (obs_spec.getup_action): 12 values in [-1, 1]; 0 the home stance, -1 and +1 each motor's
  lower and upper limit, linear in between; then the toe-in guard and the chain guard (a hip pair
  the five-bar cannot assemble moved back toward home; counted in metrics["chain_guarded_legs"]):
  chain_guard.getup_targets, exactly what deploy_supervisor sends on the robot.
* observation: the actor's is obs_spec.getup_observation (IMU gravity direction and gyro, encoders,
  last action) read through the joystick task's sensor model (noise, bias, IMU tilt, quantisation,
  latency; sensors.read_sensors); the critic's adds the simulator's state
  (obs_spec.privileged_observation).
* model: every leg geom touches the ground (env_model.legs_touch_ground); legs do not touch each
  other, and a step on which two legs' collision geometry overlaps is penalised and counted
  (metrics["legs_overlap"], getup_start.self_clearance of the measured motor angles).
* success (env.getup.success_*): tilt below 10 deg and the base within 2 cm of the home stance's
  height above the ground under it, held 1 s without a break, begun within 5 s of the drop.
  metrics["success"] is 1 on the step the hold completes (an episode's sum: 1 or 0),
  metrics["time_to_stand"] the time the hold began [s] on that step; info["success_s"] keeps it
  (-1 until then) and info["start_class"] the start's class (getup_start.CLASSES).
* mirroring (env.getup.mirror_to "left" or "right"): an episode whose start has the other side
  lower runs on the robot's mirror image: the actor's observation is mirrored in and its action
  mirrored out (robots.quadson.mirror), as deploy_supervisor.GetupPolicy does on the robot; the
  side is decided once, at reset, from the gravity direction the IMU reads (a knock-over: the side
  it tips toward) and kept in info["mirrored"]. The critic's observation, the reward, the metrics
  and info["last_action"] stay the real robot's.
* episodes: 6 s (the 5 s and the 1 s hold); no termination but a non-finite or exploded state
  (metrics["nan_reset"], as LocomotionEnv).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from brax.envs.base import State
from mujoco import mjx

from quadson_mjx import obs_spec, rewards, sensors, terrain
from quadson_mjx.env import EXPLODED_SPEED, LocomotionEnv
from quadson_mjx.env_model import check_warp_ground, make_env_data, motoring_forcerange, name_ids
from quadson_mjx.quat import quat_rotate_inverse
from quadson_mjx.robots.quadson import chain_guard, getup_start
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson.mirror import mirror_getup_observation, mirror_motors, wants_mirror

FIELD_MARGIN_M = 1.0  # a drop on the stone field lands at least this far inside its edge
SPAWN_RADIUS_M = 0.3  # ... above the highest ground within this radius (the robot is 0.34 m long)
_SPAWN_GRID = 9  # samples per side of the square over which that highest ground is taken
STANDING_CLASS = len(getup_start.CLASSES)  # info["start_class"] of a start standing at home
TOPPLED_CLASS = STANDING_CLASS + 1  # ... of a standing start knocked over (env.getup.topple_prob)


class GetupEnv(LocomotionEnv):
    """The get-up task of an env config with task="getup" (env_config); immutable after __init__."""

    RESTART_INFO = ("episode_time", "last_ctrl", "stand_s", "success_s")
    SENSOR_RESTART_INFO = ()
    STEP_METRICS = (
        "nan_reset",
        "tilt",  # angle between the body z axis and the vertical [rad]
        "base_height",  # base origin above the ground under it [m]
        "standing",  # 1 on a step inside the success tilt and height
        "success",  # 1 on the step a 1 s stand begun within 5 s completes
        "time_to_stand",  # on that step: when the stand began [s]
        "legs_overlap",  # 1 on a step where two legs (or a leg and the base) overlap
        "chain_guarded_legs",  # legs whose target the five-bar could not assemble (moved to home)
        "max_motor_speed",  # [rad/s]
    )

    def __init__(self, config):
        if config.get("task", "locomotion") != "getup":
            raise ValueError("GetupEnv needs an env config with task='getup' (env_config(task='getup'))")
        check_warp_ground(config)
        super().__init__(config)
        cfg, robot, m = self._config, self._robot, self._mj_model
        self._obs_spec = obs_spec.getup_observation(robot.motor_joints)
        self._action_spec = obs_spec.getup_action(robot.motor_joints)
        self._critic_spec = obs_spec.privileged_observation(robot.legs, self._obs_spec)
        motor_joints = name_ids(m, mujoco.mjtObj.mjOBJ_JOINT, robot.motor_joints)
        self._motor_dof = jnp.asarray(m.jnt_dofadr[motor_joints])
        self._home_motor = self._home_qpos[self._motor_qpos].reshape(4, 3)
        home_xy = self._home_qpos[:2]
        self._stand_height = float(self._home_qpos[2] - terrain.ground_height(self._field, home_xy))
        g = cfg.getup
        self._sampler = getup_start.start_sampler(
            m, getup_start.StartConfig(drop_height_m=tuple(g.drop_height_m))
        )
        self._success_hold_s = float(g.success_hold_s)
        self._success_within_s = float(g.success_within_s)
        self._mirror_to = None if g.mirror_to == "none" else g.mirror_to

    @property
    def stand_height(self) -> float:
        """The home stance's base height above the ground [m]: the success measure's."""
        return self._stand_height

    @property
    def restart_info(self) -> tuple[str, ...]:
        return self.RESTART_INFO + (("mirrored",) if self._mirror_to else ())

    def _mirrored_obs(self, obs, mirrored):
        """The actor's observation mirrored where mirrored (); the critic's left as it is."""
        state = jnp.where(mirrored, mirror_getup_observation(obs["state"]), obs["state"])
        return {**obs, "state": state}

    # --- reset -------------------------------------------------------------------------------------
    def _topple(self, key, standing):
        """(toppled (), qvel (nv,)): a standing start knocked over with probability topple_prob: the
        base tips toward a random horizontal direction u at a rate w (env.getup.topple_rate_rps)
        about z x u, its centre moving at w h u (h the standing height: a pivot on the feet). The
        standing start's heading is 0, so the body and world frames agree."""
        g = self._config.getup
        k_p, k_dir, k_rate = jax.random.split(key, 3)
        toppled = standing & jax.random.bernoulli(k_p, g.topple_prob)
        phi = jax.random.uniform(k_dir, (), minval=-jnp.pi, maxval=jnp.pi)
        rate = jax.random.uniform(k_rate, (), minval=g.topple_rate_rps[0], maxval=g.topple_rate_rps[1])
        u = jnp.array([jnp.cos(phi), jnp.sin(phi), 0.0])
        w = jnp.where(toppled, rate, 0.0)
        qvel = jnp.zeros(self.sys.nv).at[0:3].set(w * self._stand_height * u)
        return toppled, qvel.at[3:6].set(w * jnp.array([-u[1], u[0], 0.0]))

    def reset(self, rng) -> State:
        """A drop: getup_start's start state (on the stone field at a random place, above the
        highest ground near it), the motors holding the sampled angles."""
        k_start, k_xy, k_info, k_stand = jax.random.split(rng, 4)
        start = self._sampler(k_start)
        g = self._config.getup
        standing = jax.random.bernoulli(k_stand, g.stand_start_prob)
        qvel = jnp.zeros(self.sys.nv)
        if g.topple_prob > 0:  # static; a key of its own: configs without topples draw as before
            toppled, qvel = self._topple(jax.random.fold_in(rng, 5), standing)
        else:
            toppled = jnp.zeros((), bool)
        qpos = jnp.where(standing, self._home_qpos.at[:2].set(0.0), start.qpos)
        angles = jnp.where(standing, self._home_motor, start.motor_angles)
        if self._field is not None:
            half = self._field.half_size - FIELD_MARGIN_M
            xy = self._field.origin[:2] + jax.random.uniform(k_xy, (2,), minval=-half, maxval=half)
            offsets = jnp.linspace(-SPAWN_RADIUS_M, SPAWN_RADIUS_M, _SPAWN_GRID)
            grid = jnp.stack(jnp.meshgrid(offsets, offsets), -1).reshape(-1, 2)
            top = jnp.max(terrain.ground_height(self._field, xy + grid))
            qpos = qpos.at[:2].set(xy).at[2].add(top)
        ctrl = self._home_ctrl.at[self._actuator_of_motor].set(angles.reshape(12))
        data = make_env_data(self._mj_model, self.sys, self._warp_buffers)
        data = data.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)
        data = mjx.kinematics(self.sys, data)  # as LocomotionEnv._start: a step recomputes the rest
        info = {
            **self.episode_info(k_info),
            "episode_time": jnp.zeros(()),
            "last_action": jnp.zeros(self.action_size),
            "last_ctrl": ctrl,
            "stand_s": jnp.zeros(()),  # how long the success condition has held without a break [s]
            "success_s": jnp.full((), -1.0, jnp.float32),  # when the successful stand began [s]; -1: not yet
            "start_class": jnp.where(
                toppled, TOPPLED_CLASS, jnp.where(standing, STANDING_CLASS, start.label)
            ),
            "start_valid": start.valid | standing,
        }
        metrics = {f"reward/{k}": jnp.zeros(()) for k in self._config.getup.weights}
        metrics.update({k: jnp.zeros(()) for k in self.STEP_METRICS})
        obs = self._observe(data, info, (data.qpos, data.qvel), jnp.zeros(4, bool))
        if self._mirror_to:  # static
            # the side that is lower: the IMU's gravity y now; a knock-over's: where it tips (the
            # base's y velocity, heading 0), which the IMU reads once it has tipped
            side_y = jnp.where(toppled, qvel[1], obs["state"][1])
            info["mirrored"] = wants_mirror(side_y, self._mirror_to)
            obs = self._mirrored_obs(obs, info["mirrored"])
        return State(data, obs, jnp.zeros(()), jnp.zeros(()), metrics, info)

    # --- step --------------------------------------------------------------------------------------
    def motor_targets(self, action):
        """action (12,) in [-1, 1] -> (motor targets (12,) [rad], (4,) bool legs moved by the chain
        guard): chain_guard.getup_targets."""
        return chain_guard.getup_targets(action, self._home_motor.reshape(12), jnp)

    def step(self, state: State, action: jax.Array) -> State:
        cfg = self._config
        info = dict(state.info)
        action = jnp.clip(action, -1.0, 1.0)
        if self._mirror_to:  # static: the policy acted on the mirror image; the robot's action
            action = jnp.where(info["mirrored"], mirror_motors(action), action)
        angles, guarded = self.motor_targets(action)
        ctrl = self._home_ctrl.at[self._actuator_of_motor].set(angles)

        def physics_step(data, c):
            sys = self.sys
            if cfg.getup.servo_speed_limit:  # static: the servos' torque-speed line at this step's speed
                act = self._actuator_of_motor
                fr = motoring_forcerange(
                    sys.actuator_forcerange[act], data.qvel[self._motor_dof], C.MOTOR_VELOCITY_LIMIT
                )
                sys = sys.replace(actuator_forcerange=sys.actuator_forcerange.at[act].set(fr))
            return mjx.step(sys, data.replace(ctrl=c))

        data, sensed = self._physics_steps(state.pipeline_state, info, ctrl, True, physics_step)

        t = info["episode_time"] + self._ctrl_dt
        info["episode_time"] = t
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        sane = finite & (jnp.max(jnp.abs(data.qvel[:6])) < EXPLODED_SPEED)

        up = -quat_rotate_inverse(data.qpos[3:7], jnp.asarray([0.0, 0.0, -1.0]))[2]  # cos(tilt)
        tilt = jnp.arccos(jnp.clip(up, -1.0, 1.0))
        height = data.qpos[2] - terrain.ground_height(self._field, data.qpos[:2])
        motor_pos = data.qpos[self._motor_qpos]
        motor_vel = data.qvel[self._motor_dof]
        overlap = getup_start.self_clearance(motor_pos.reshape(4, 3)) < 0.0
        g = cfg.getup
        standing = (tilt < g.success_tilt_rad) & (jnp.abs(height - self._stand_height) < g.success_height_m)
        stand_s = jnp.where(standing, info["stand_s"] + self._ctrl_dt, 0.0)
        began = t - stand_s  # when the current stand began [s]
        succeeded = (
            (info["success_s"] < 0)
            & (stand_s >= self._success_hold_s - 1e-6)
            & (began <= self._success_within_s + 1e-6)
        )
        info["stand_s"] = stand_s
        info["success_s"] = jnp.where(succeeded, began, info["success_s"])

        terms = rewards.getup_terms(
            g,
            up=up,
            height=height,
            stand_height=self._stand_height,
            motor_pos=motor_pos,
            home_motor=self._home_motor.reshape(12),
            motor_vel=motor_vel,
            speed_limit=C.MOTOR_VELOCITY_LIMIT,
            action=action,
            last_action=info["last_action"],
            actuator_force=data.actuator_force,
            legs_overlap=overlap,
        )
        reward = sum(g.weights[k] * v for k, v in terms.items())
        info["last_action"] = action
        info["last_ctrl"] = ctrl
        info["rng"] = jax.random.split(info["rng"])[0]  # fresh sensor noise every step
        obs = self._observe(data, info, sensed, self.foot_contact(data))
        if self._mirror_to:
            obs = self._mirrored_obs(obs, info["mirrored"])
        obs = jax.tree.map(lambda o: jnp.where(sane, o, 0.0), obs)
        reward = jnp.where(sane, reward, 0.0)

        metrics = dict(state.metrics)
        metrics.update({f"reward/{k}": jnp.where(sane, g.weights[k] * v, 0.0) for k, v in terms.items()})
        metrics.update(
            nan_reset=(~sane).astype(jnp.float32),
            tilt=jnp.where(sane, tilt, 0.0),
            base_height=jnp.where(sane, height, 0.0),
            standing=(sane & standing).astype(jnp.float32),
            success=(sane & succeeded).astype(jnp.float32),
            time_to_stand=jnp.where(sane & succeeded, began, 0.0),
            legs_overlap=(sane & overlap).astype(jnp.float32),
            chain_guarded_legs=jnp.sum(guarded).astype(jnp.float32),
            max_motor_speed=jnp.where(sane, jnp.max(jnp.abs(motor_vel)), 0.0),
        )
        return state.replace(
            pipeline_state=data,
            obs=obs,
            reward=reward,
            done=(~sane).astype(jnp.float32),
            metrics=metrics,
            info=info,
        )

    # --- observation -------------------------------------------------------------------------------
    def observation(self, qpos, qvel, info):
        """The actor's observation (obs_spec.getup_observation) of a physics state qpos (nq,), qvel
        (nv,) with info's sensor errors, noise key and last action."""
        return self._obs_spec.assemble(self._actor_parts(jnp.asarray(qpos), jnp.asarray(qvel), info))

    def _actor_parts(self, qpos, qvel, info) -> dict:
        readings = sensors.read_sensors(
            self._config, qpos, qvel, qpos[self._motor_qpos], info, jax.random.fold_in(info["rng"], 3)
        )
        return {**readings, "last_action": info["last_action"]}

    def _observe(self, data, info, sensed, contact):
        """{"state": the actor's observation of the sensed (qpos, qvel), "privileged_state": the
        critic's of the physics state data}."""
        parts = self._actor_parts(sensed[0], sensed[1], info)
        actor = self._obs_spec.assemble(parts)
        critic = self._critic_spec.assemble({**parts, **self._privileged_parts(data, info, contact)})
        return {"state": actor, "privileged_state": critic}
