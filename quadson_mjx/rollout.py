"""Batched, headless rollouts of a controller in the MJX environment, and the controllers.

A controller acts on one environment; `make_rollout` vmaps it with `env.step` over B environments
and scans T control steps in one jitted function, recording per-step arrays `[T, B, ...]` that the
host then writes (quadson_mjx.foxglove_mcap) or summarises (quadson_mjx.report). A long rollout runs
as consecutive segments of the same compiled scan, so a writer can flush between them.

An environment whose episode ends (fall, the stone field's edge, or non-finite physics) restarts
from its first state with the same command and a fresh controller state; `done` marks the step that
ended the episode, `fall` and `off_field` say why. A given command (3,) or one per environment (B, 3)
holds for the whole trial (the env's mid-episode resampling is switched off); without one the env
samples (and resamples) as in training. With `randomize=True` and an env config that randomizes,
every environment gets its own randomized model (friction, masses, servo strength, centre of mass:
quadson_mjx.randomize), as brax's training wrapper does it.

Controllers (`Controller(name, init, act)`, act: (carry, env_state, key) -> (carry, action)):
  * `gait_only`: the gait open loop (zero action).
  * `pid_stabilizer`: gait + seed 003's roll/pitch PID; its body roll/pitch command becomes foot
    offsets through body kinematics (`pid_action`).
  * `policy_controller`: gait + a trained policy (`quadson_mjx.training.load_policy`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from quadson_mjx.quat import quat_rotate_inverse, quat_to_rpy
from quadson_mjx.robots import get_robot
from quadson_mjx.stabilizer import SEED_003_GAINS, PidGains, pid_init, pid_step

CONTROLLERS = ("gait", "pid")  # named controllers; a policy comes from a run directory


class Controller(NamedTuple):
    name: str
    init: Callable[[], Any]  # () -> carry of one environment
    act: Callable  # (carry, brax State of one env, key) -> (carry, action (action_size,))


def _pad_action(env, offsets12):
    """(12,) normalised foot offsets -> (action_size,), zero for the gait-scaling actions if any."""
    return jnp.concatenate([offsets12, jnp.zeros(env.action_size - 12, offsets12.dtype)])


def gait_only(env) -> Controller:
    """The gait alone: zero foot offsets."""
    return Controller(
        "gait", lambda: jnp.zeros(()), lambda carry, state, key: (carry, jnp.zeros(env.action_size))
    )


def pid_action(gait_targets, u_roll_pitch, action_scale_m, tilt_feet=None):
    """Body roll/pitch command -> normalised foot-offset action (seed 003 through body kinematics).

    gait_targets: (4, 3) the gait's foot targets, gait frames [m]; u_roll_pitch: (2,) body roll,
    pitch command [rad]; tilt_feet: the robot's body kinematics (Robot.tilt_feet; default Quadson's,
    apply_body_offset with pose (0, 0, 0, u_roll, u_pitch, 0)) -> (12,) offsets tilt_feet(targets, u)
    - targets, clipped to +-action_scale_m and divided by it (so in [-1, 1]).
    """
    if tilt_feet is None:
        tilt_feet = get_robot("quadson").tilt_feet
    offsets = tilt_feet(gait_targets, u_roll_pitch) - gait_targets
    return (jnp.clip(offsets, -action_scale_m, action_scale_m) / action_scale_m).reshape(12)


def observed_roll_pitch(obs_spec):
    """-> f(actor observation (size,)) -> (2,) the body roll and pitch [rad] it holds: seed 000's
    base_rpy entries, or for the sensor observation the ZYX roll and pitch of the IMU's gravity
    direction g ((0, 0, -1) level; g = (sin p, -sin r cos p, -cos r cos p)). ValueError for an
    observation with neither."""
    names = obs_spec.names
    if "base_rpy.roll" in names:
        i, j = names.index("base_rpy.roll"), names.index("base_rpy.pitch")
        return lambda obs: jnp.stack([obs[i], obs[j]])
    if "gravity.x" in names:
        k = names.index("gravity.x")

        def from_gravity(obs):
            gx, gy, gz = obs[k], obs[k + 1], obs[k + 2]
            return jnp.stack([jnp.arctan2(-gy, -gz), jnp.arctan2(gx, jnp.sqrt(gy * gy + gz * gz))])

        return from_gravity
    raise ValueError("the observation holds neither base_rpy nor gravity: no roll and pitch to stabilise")


def pid_stabilizer(env, gains: PidGains = SEED_003_GAINS) -> Controller:
    """Gait + seed 003's roll/pitch PID. Measured roll, pitch: from the observation
    (observed_roll_pitch; with sensor noise when the env randomizes), as the robot's IMU gives them."""
    scale = float(env.config.action_scale_m)
    roll_pitch = observed_roll_pitch(env.obs_spec)

    def act(carry, state, key):
        carry, u = pid_step(carry, roll_pitch(env.actor_obs(state.obs)), gains)
        action = pid_action(env.gait_targets(state.info), u, scale, env.robot.tilt_feet)
        return carry, _pad_action(env, action)

    return Controller("pid", pid_init, act)


def policy_controller(policy, name: str = "policy") -> Controller:
    """policy(obs, key) -> (action, extras), e.g. from `training.load_policy`."""
    return Controller(
        name, lambda: jnp.zeros(()), lambda carry, state, key: (carry, policy(state.obs, key)[0])
    )


def named_controller(env, name: str) -> Controller:
    if name == "gait":
        return gait_only(env)
    if name == "pid":
        return pid_stabilizer(env)
    raise ValueError(f"unknown controller {name!r}; choose from {CONTROLLERS} or pass a run directory")


# --- what the robot's sensors would read, from the physics state ---------------------------------------
# The env switches MuJoCo's sensors off for speed, so the IMU and foot contacts are computed here.


def imu_acceleration(quat, lin_acc_world, gravity):
    """Accelerometer at the base origin: base-frame (acceleration - gravity) [m/s^2].
    quat (4,) wxyz, lin_acc_world (3,) (free joint qacc[0:3]), gravity (3,) (model.opt.gravity)."""
    return quat_rotate_inverse(quat, lin_acc_world - gravity)


def foot_geom_ids(mj_model, legs) -> np.ndarray:
    """(4,) collision geom of each foot, `legs` order."""
    import mujoco

    return np.array(
        [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, f"{leg}_foot_collision") for leg in legs]
    )


def foot_forces(sys, data, foot_geoms):
    """(4,) normal contact force on each foot [N] from MJX's constraint forces (one data, not batched)."""
    from mujoco.mjx._src import support  # contact_force is not exported by mjx's public API

    contact = data._impl.contact
    n = contact.dist.shape[0]
    normal = jnp.stack([support.contact_force(sys, data, i)[0] for i in range(n)]) if n else jnp.zeros(0)
    involved = (contact.geom1[None, :] == foot_geoms[:, None]) | (
        contact.geom2[None, :] == foot_geoms[:, None]
    )
    return jnp.sum(jnp.where(involved, normal[None, :], 0.0), axis=1)


# --- the batched rollout ----------------------------------------------------------------------------


class Carry(NamedTuple):
    state: Any  # brax State, batched [B]
    first: Any  # the episode's first State, batched [B]
    ctrl: Any  # controller carry, batched [B]
    episode_step: jax.Array  # (B,) int32 control steps into the current episode
    key: jax.Array


class Trajectory(NamedTuple):
    """Per-step arrays [T, B, ...] of a rollout (SI; quaternions wxyz as MuJoCo writes them)."""

    episode_step: jax.Array  # (T, B) control step within the episode after this step (1 = first)
    obs: jax.Array  # (T, B, obs) the observation the controller acted on
    action: jax.Array  # (T, B, act) in [-1, 1]
    foot_targets: jax.Array  # (T, B, 4, 3) shoulder frames [m], gait + offsets
    command: jax.Array  # (T, B, 3) vx [m/s], vy [m/s], yaw rate [rad/s]
    qpos: jax.Array  # (T, B, nq) after the step
    qvel: jax.Array  # (T, B, nv)
    xpos: jax.Array  # (T, B, nbody, 3) world [m]
    xquat: jax.Array  # (T, B, nbody, 4) world, wxyz
    rpy: jax.Array  # (T, B, 3) base roll, pitch, yaw [rad]
    lin_vel: jax.Array  # (T, B, 3) base linear velocity, body frame [m/s]
    ang_vel: jax.Array  # (T, B, 3) base angular velocity, body frame [rad/s]
    imu_acc: jax.Array  # (T, B, 3) what an accelerometer at the base origin reads, base frame [m/s^2]
    foot_force: jax.Array  # (T, B, 4) normal contact force on each foot [N] (0: no contact)
    actuator_force: jax.Array  # (T, B, nu) [N m]
    closure_residual: jax.Array  # (T, B, 4) [m]; 0 for a robot without closed chains (Caramel)
    reward: jax.Array  # (T, B)
    reward_terms: dict  # name -> (T, B), weighted as the env sums them
    done: jax.Array  # (T, B) bool: this step ended the episode (then the env restarts)
    nan_reset: jax.Array  # (T, B) bool: it ended because the physics went non-finite
    fall: jax.Array  # (T, B) bool: it ended by tilt, height or the base box in the ground
    off_field: jax.Array  # (T, B) bool: it ended at the stone field's edge (not a fall)
    base_height: jax.Array  # (T, B) base origin above the ground under it [m]
    base_below_terrain: jax.Array  # (T, B) bool: the base box's bottom face is below the ground
    # (T, B, 12) the position targets the step sent to the motors [rad], LEGS x MOTORS (the
    # reference a deployment loop's output is checked against); None where not recorded
    motor_targets: jax.Array | None = None
    # (T, B, 4) bool: the phase table's stance legs at the end of the step; None where not recorded
    scheduled_stance: jax.Array | None = None


def _set_command(env, state, command):
    if command is None:
        return state
    info = dict(state.info)
    info["command"] = jnp.broadcast_to(jnp.asarray(command, jnp.float32), info["command"].shape)
    info["command_timer"] = jnp.full_like(info["command_timer"], jnp.inf)  # fixed for the trial
    return state.replace(info=info, obs=env.with_command(state.obs, info["command"]))


def init_carry(env, controller: Controller, rng, n_envs: int, command=None) -> Carry:
    """First states of n_envs environments (command (3,) or (n_envs, 3) overrides the sampled one)."""
    if command is not None and np.ndim(command) == 2 and np.shape(command)[0] != n_envs:
        raise ValueError(f"{np.shape(command)[0]} commands for {n_envs} environments: give one per env")
    k_reset, k_run = jax.random.split(rng)
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(k_reset, n_envs))
    state = _set_command(env, state, command)
    ctrl = jax.vmap(lambda _: controller.init())(jnp.arange(n_envs))
    return Carry(state, state, ctrl, jnp.zeros(n_envs, jnp.int32), k_run)


def randomized_step(env, n_envs: int, rng):
    """-> step(states [B], actions [B]) with one randomized model per environment (the env config's
    `randomization` ranges; quadson_mjx.randomize), like brax's DomainRandomizationVmapWrapper."""
    from quadson_mjx.randomize import randomize

    sys_v, in_axes = randomize(
        env.sys, jax.random.split(rng, n_envs), env.config.randomization, env.base_body
    )

    def one(sys, state, action):
        e = copy.copy(env)  # a shallow copy carrying this environment's model; env stays untouched
        e.sys = sys
        return e.step(state, action)

    return lambda states, actions: jax.vmap(one, in_axes=(in_axes, 0, 0))(sys_v, states, actions)


def make_rollout(env, controller: Controller, n_steps: int, step_b=None):
    """-> jitted rollout(carry) -> (carry, Trajectory [n_steps, B]) of consecutive control steps.
    step_b: batched env step (default: vmap of env.step on the nominal model; randomized_step)."""
    robot = env.robot
    motor_actuator = env.motor_actuators
    foot_geoms = jnp.asarray(foot_geom_ids(env.mj_model, robot.legs))
    gravity = jnp.asarray(env.mj_model.opt.gravity, jnp.float32)
    act_b = jax.vmap(controller.act)
    step_b = jax.vmap(env.step) if step_b is None else step_b
    init_b = jax.vmap(lambda _: controller.init())

    def one(carry: Carry, _):
        key, k_act = jax.random.split(carry.key)
        n = carry.episode_step.shape[0]
        ctrl, action = act_b(carry.ctrl, carry.state, jax.random.split(k_act, n))
        nxt = step_b(carry.state, action)
        d = nxt.pipeline_state
        # mjx.step leaves xpos/xquat/site_xpos at the last substep's start: recompute them for the
        # final qpos so that frames, joint states and base pose describe the same instant
        kin = jax.vmap(mjx.kinematics, in_axes=(None, 0))(env.sys, d)
        quat = d.qpos[:, 3:7]
        done = nxt.done.astype(bool)
        rec = Trajectory(
            episode_step=carry.episode_step + 1,
            obs=env.actor_obs(carry.state.obs),
            action=action,
            foot_targets=nxt.info["foot_targets"],
            command=nxt.info["command"],
            qpos=d.qpos,
            qvel=d.qvel,
            xpos=kin.xpos,
            xquat=kin.xquat,
            rpy=quat_to_rpy(quat),
            lin_vel=quat_rotate_inverse(quat, d.qvel[:, 0:3]),
            ang_vel=d.qvel[:, 3:6],
            imu_acc=jax.vmap(imu_acceleration, in_axes=(0, 0, None))(quat, d.qacc[:, 0:3], gravity),
            foot_force=jax.vmap(lambda data: foot_forces(env.sys, data, foot_geoms))(d),
            actuator_force=d.actuator_force,
            closure_residual=(
                robot.closure_residual(env.mj_model, kin.site_xpos)
                if robot.closure_residual is not None
                else jnp.zeros(d.qpos.shape[:1] + (len(robot.legs),))
            ),
            reward=nxt.reward,
            reward_terms={k[len("reward/") :]: v for k, v in nxt.metrics.items() if k.startswith("reward/")},
            done=done,
            nan_reset=nxt.metrics["nan_reset"] > 0,
            fall=nxt.metrics["fall"] > 0,
            off_field=nxt.metrics["off_field"] > 0,
            base_height=nxt.metrics["base_height"],
            base_below_terrain=nxt.metrics["base_below_terrain"] > 0,
            motor_targets=nxt.info["last_ctrl"][:, motor_actuator],
            scheduled_stance=jax.vmap(env.scheduled_stance)(nxt.info["gait_progress"]),
        )

        def restart(first, current):
            mask = jnp.reshape(done, done.shape + (1,) * (current.ndim - 1))
            return jnp.where(mask, first, current)

        state = jax.tree.map(restart, carry.first, nxt.replace(done=jnp.zeros_like(nxt.done)))
        ctrl = jax.tree.map(restart, init_b(jnp.arange(n)), ctrl)
        episode_step = jnp.where(done, 0, carry.episode_step + 1)
        return Carry(state, carry.first, ctrl, episode_step, key), rec

    @jax.jit
    def rollout(carry: Carry):
        return jax.lax.scan(one, carry, None, length=n_steps)

    return rollout


def to_host(traj: Trajectory) -> Trajectory:
    return jax.tree.map(np.asarray, jax.device_get(traj))


def run(
    env,
    controller: Controller,
    rng,
    n_envs: int,
    n_steps: int,
    segment_steps: int = 250,
    command=None,
    randomize: bool = False,
) -> Iterator[tuple[int, Trajectory]]:
    """Yields (first step index, host Trajectory [t, B]) segment by segment until n_steps are done.
    Every segment but the last has segment_steps steps (one compile for all of them). randomize: one
    randomized model per environment (needs an env config with randomize on)."""
    if randomize and not env.config.randomize:
        raise ValueError("randomize=True needs an env config with randomize on (--env.randomize=true)")
    carry = init_carry(env, controller, rng, n_envs, command)
    seg = max(1, min(segment_steps, n_steps))
    step_b = randomized_step(env, n_envs, jax.random.fold_in(rng, 7)) if randomize else None
    full = make_rollout(env, controller, seg, step_b)
    done_steps = 0
    while done_steps < n_steps:
        carry, traj = full(carry)
        traj = to_host(traj)
        take = min(seg, n_steps - done_steps)
        if take < seg:
            traj = jax.tree.map(lambda a, n=take: a[:n], traj)
        yield done_steps, traj
        done_steps += take
