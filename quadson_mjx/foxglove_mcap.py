"""Rollouts to MCAP files that open in Foxglove: typed Foxglove schemas where one exists, JSON elsewhere.

Topics (t = simulation time of the step's end; the static scene at t = 0):

    /tf              foxglove.FrameTransforms  one per step: every body of every env, parent = parent
                                               body's frame or "world" (closed-chain links included)
    /scene           foxglove.SceneUpdate      once: an entity per drawn geom (capsule = cylinder + 2
                                               spheres, box = cube, sphere, plane = thin cube, height
                                               field = triangle list), frame = the geom's body frame
    /joint_states    foxglove.JointStates      one per step: every hinge of every env (effort = motor
                                               torque [N m], absent for passive joints)
    /odom            foxglove.Odometry         one per env per step: base pose in "world", velocities
                                               in the base frame
    /imu             JSON                      one per env per step: orientation (xyzw), angular
                                               velocity [rad/s], linear acceleration [m/s^2] of an IMU
                                               at the base origin, from the physics state (the env
                                               switches MuJoCo's sensors off)
    /rollout/step    JSON                      one per env per step: observation, action, foot targets,
                                               motor targets sent (t0, t1, t5 per leg [rad]), reward
                                               terms, contacts, closure residual, base state
    /log             foxglove.Log              episode starts, falls, non-finite resets, the end

Frames of environment i are prefixed `env{i}/` (`env0/base`, `env0/FL_link2`); the floor is drawn
in "world". Per-env JSON and Odometry messages carry `env` (JSON) / `body_frame_id`, so a Foxglove
message path such as `/rollout/step{env==0}.base.vx` picks one environment. Only the first
`viz_envs` environments are drawn (/tf, /scene, /joint_states, /odom, /imu; `recording.record` defaults to 16,
about 0.3 ms of host time per env and step); /rollout/step and /log cover every environment.

Quaternions: MuJoCo writes wxyz, Foxglove reads xyzw; converted here. JSON cannot carry NaN: non-finite
numbers become null. Every file gets its own `foxglove.Context` (channels never leak between files)
and every message an explicit log_time. `flush()` ends the current chunk, so a killed writer leaves
a file whose messages up to the last flush are readable (`python -m quadson_mjx.mcap_check`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import foxglove
import mujoco
import numpy as np
from foxglove import channels as fch
from foxglove import messages as fm
from foxglove.mcap import MCAPWriteOptions

from quadson_mjx.foxglove_scene import (
    body_frames,
    drawn_geoms,
    geom_entity,
    local_transforms,
    pose,
    quaternion_xyzw,
    timestamp,
    vector3,
)
from quadson_mjx.mcap_check import ROLLOUT_TOPICS  # noqa: F401 (one list for the writer and the checker)

PROFILE = "quadson_mjx.rollout"


def json_safe(x):
    """Nested numbers/arrays -> JSON-ready lists with non-finite values as None."""
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    a = np.asarray(x)
    if a.dtype == bool:
        return a.tolist()
    if a.dtype.kind in "iu":
        return a.tolist()
    a = a.astype(np.float64)
    if np.all(np.isfinite(a)):
        return a.tolist()
    return np.where(np.isfinite(a), a, None).tolist() if a.ndim else None


class RolloutWriter:
    """One rollout MCAP file. Use as a context manager or call close(). `legs`: the robot's leg names in
    the order of every per-leg array (Robot.legs); /rollout/step keys its per-leg fields by them."""

    def __init__(
        self,
        path: str | Path,
        model: mujoco.MjModel,
        n_envs: int,
        ctrl_dt: float,
        legs: Sequence[str],
        overwrite: bool = False,
        viz_envs: int | None = None,
    ):
        self.path = Path(path)
        self._ctrl_dt = float(ctrl_dt)
        self.model = model
        self.n_envs = n_envs
        self.legs = tuple(legs)
        # envs drawn (/tf, /scene, /joint_states, /odom, /imu); /rollout/step carries all of them
        self.viz_envs = n_envs if viz_envs is None else max(0, min(viz_envs, n_envs))
        self._ctx = foxglove.Context()
        opts = MCAPWriteOptions(profile=PROFILE)
        self._writer = foxglove.open_mcap(
            str(self.path), allow_overwrite=overwrite, context=self._ctx, writer_options=opts
        )
        ctx = self._ctx
        self._tf = fch.FrameTransformsChannel("/tf", context=ctx)
        self._scene = fch.SceneUpdateChannel("/scene", context=ctx)
        self._joints = fch.JointStatesChannel("/joint_states", context=ctx)
        self._odom = fch.OdometryChannel("/odom", context=ctx)
        self._log = fch.LogChannel("/log", context=ctx)
        self._imu = foxglove.Channel("/imu", schema=_IMU_SCHEMA, message_encoding="json", context=ctx)
        self._step = foxglove.Channel(
            "/rollout/step", schema=_step_schema(self.legs), message_encoding="json", context=ctx
        )
        self._frames = [body_frames(model, i) for i in range(n_envs)]
        self._parent = model.body_parentid
        hinge = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
        self._hinges = np.array(hinge)
        self._hinge_names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in hinge]
        act_of_joint = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu)}
        self._hinge_actuator = [act_of_joint.get(j) for j in hinge]
        self.closed = False

    # --- static content --------------------------------------------------------------------------
    def write_metadata(self, name: str, data: dict) -> None:
        self._writer.write_metadata(name, {k: str(v) for k, v in data.items()})

    def attach(self, name: str, data: bytes, media_type: str) -> None:
        self._writer.attach(log_time=0, create_time=0, name=name, media_type=media_type, data=data)

    def write_scene(self, t_ns: int = 0) -> None:
        """The static scene: robot geoms per env in body frames, the floor once in "world"; flushed."""
        entities = []
        for g in drawn_geoms(self.model):
            b = int(self.model.geom_bodyid[g])
            envs = [0] if b == 0 else range(self.viz_envs)
            for i in envs:
                frame = self._frames[i][b]
                eid = f"geom{g}" if b == 0 else f"env{i}/geom{g}"
                e = geom_entity(self.model, g, frame, eid)
                if e is not None:
                    entities.append(e)
        self._scene.log(fm.SceneUpdate(entities=entities), log_time=t_ns)
        self.flush()

    # --- per step ----------------------------------------------------------------------------------
    def log(self, t_ns: int, level: str, message: str) -> None:
        lvl = {"info": fm.LogLevel.Info, "warning": fm.LogLevel.Warning, "error": fm.LogLevel.Error}[level]
        self._log.log(
            fm.Log(timestamp=timestamp(t_ns), level=lvl, message=message, name="rollout"), log_time=t_ns
        )

    def write_step(self, t_ns: int, traj, k: int, extra: dict | None = None) -> None:
        """Writes step k of a host Trajectory [T, B, ...] (quadson_mjx.rollout) at time t_ns."""
        ts = timestamp(t_ns)
        rel_pos, rel_quat = local_transforms(self.model, traj.xpos[k], traj.xquat[k])  # (B, nbody, .)
        tfs = []
        for i in range(self.viz_envs):
            frames = self._frames[i]
            for b in range(1, self.model.nbody):
                tfs.append(
                    fm.FrameTransform(
                        timestamp=ts,
                        parent_frame_id=frames[self._parent[b]],
                        child_frame_id=frames[b],
                        translation=vector3(rel_pos[i, b]),
                        rotation=quaternion_xyzw(rel_quat[i, b]),
                    )
                )
        self._tf.log(fm.FrameTransforms(transforms=tfs), log_time=t_ns)

        qpos, qvel = traj.qpos[k], traj.qvel[k]
        joints = []
        for i in range(self.viz_envs):
            for j, name, act in zip(self._hinges, self._hinge_names, self._hinge_actuator, strict=True):
                joints.append(
                    fm.JointState(
                        name=f"env{i}/{name}",
                        position=float(qpos[i, self.model.jnt_qposadr[j]]),
                        velocity=float(qvel[i, self.model.jnt_dofadr[j]]),
                        effort=None if act is None else float(traj.actuator_force[k, i, act]),
                    )
                )
        self._joints.log(fm.JointStates(timestamp=ts, joints=joints), log_time=t_ns)

        for i in range(self.n_envs):
            base_frame = self._frames[i][1]
            if i < self.viz_envs:
                self._odom.log(
                    fm.Odometry(
                        timestamp=ts,
                        frame_id="world",
                        body_frame_id=base_frame,
                        pose=pose(qpos[i, 0:3], qpos[i, 3:7]),
                        linear_velocity=vector3(traj.lin_vel[k, i]),
                        angular_velocity=vector3(traj.ang_vel[k, i]),
                    ),
                    log_time=t_ns,
                )
                q = qpos[i, 3:7]  # the IMU sits at the base origin, axes aligned with the base
                imu = {
                    "env": i,
                    "frame_id": base_frame,
                    "orientation": {"x": q[1], "y": q[2], "z": q[3], "w": q[0]},
                    "angular_velocity": dict(zip("xyz", traj.ang_vel[k, i], strict=True)),
                    "linear_acceleration": dict(zip("xyz", traj.imu_acc[k, i], strict=True)),
                }
                self._imu.log(_dumps(imu), log_time=t_ns)
            touch = traj.foot_force[k, i]
            rpy, v, w = traj.rpy[k, i], traj.lin_vel[k, i], traj.ang_vel[k, i]
            motor = {}
            if traj.motor_targets is not None:
                m = traj.motor_targets[k, i].reshape(len(self.legs), -1)
                motor["motor_targets"] = {leg: m[n] for n, leg in enumerate(self.legs)}
            step = {
                "env": i,
                "episode_step": int(traj.episode_step[k, i]),
                "episode_time_s": float(traj.episode_step[k, i]) * self._ctrl_dt,
                "command": dict(zip(("vx", "vy", "yaw_rate"), traj.command[k, i], strict=True)),
                "base": {
                    "x": qpos[i, 0],
                    "y": qpos[i, 1],
                    "z": qpos[i, 2],
                    "roll": rpy[0],
                    "pitch": rpy[1],
                    "yaw": rpy[2],
                    "vx": v[0],
                    "vy": v[1],
                    "vz": v[2],
                    "wx": w[0],
                    "wy": w[1],
                    "wz": w[2],
                },
                "observation": traj.obs[k, i],
                "action": traj.action[k, i],
                "foot_targets": {leg: traj.foot_targets[k, i, n] for n, leg in enumerate(self.legs)},
                **motor,
                "reward": {"total": traj.reward[k, i], **{n: v[k, i] for n, v in traj.reward_terms.items()}},
                "contacts": {leg: bool(touch[n] > 0) for n, leg in enumerate(self.legs)},
                "foot_force_n": {leg: touch[n] for n, leg in enumerate(self.legs)},
                "closure_residual_m": {
                    leg: traj.closure_residual[k, i, n] for n, leg in enumerate(self.legs)
                },
                "base_height_m": traj.base_height[k, i],
                "base_below_terrain": bool(traj.base_below_terrain[k, i]),
                "done": bool(traj.done[k, i]),
                "fall": bool(traj.fall[k, i]),
                "off_field": bool(traj.off_field[k, i]),
                "nan_reset": bool(traj.nan_reset[k, i]),
                **(extra or {}),
            }
            self._step.log(_dumps(step), log_time=t_ns)

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        if not self.closed:
            self._writer.close()
            self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _dumps(message: dict) -> bytes:
    return json.dumps(_to_json(message), allow_nan=False).encode()


def _to_json(x):
    if isinstance(x, dict):
        return {k: _to_json(v) for k, v in x.items()}
    if isinstance(x, bool | str | int) or x is None:
        return x
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return json_safe(x)


_NUM = {"type": ["number", "null"]}
_XYZ = {"type": "object", "properties": {k: _NUM for k in "xyz"}}
_IMU_SCHEMA = {
    "title": "quadson.Imu",
    "type": "object",
    "properties": {
        "env": {"type": "integer"},
        "frame_id": {"type": "string"},
        "orientation": {"type": "object", "properties": {k: _NUM for k in "xyzw"}},
        "angular_velocity": _XYZ,
        "linear_acceleration": _XYZ,
    },
}


def _step_schema(legs: Sequence[str]) -> dict:
    """The JSON schema of /rollout/step for a robot with these legs."""
    per_leg_vec = {"type": "object", "properties": {leg: {"type": "array", "items": _NUM} for leg in legs}}
    per_leg_num = {"type": "object", "properties": {leg: _NUM for leg in legs}}
    return {
        "title": "quadson.RolloutStep",
        "type": "object",
        "properties": {
            "env": {"type": "integer"},
            "episode_step": {"type": "integer"},
            "episode_time_s": _NUM,
            "command": {"type": "object", "properties": {k: _NUM for k in ("vx", "vy", "yaw_rate")}},
            "base": {
                "type": "object",
                "properties": {
                    k: _NUM
                    for k in ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "wx", "wy", "wz")
                },
            },
            "observation": {"type": "array", "items": _NUM},
            "action": {"type": "array", "items": _NUM},
            "foot_targets": per_leg_vec,
            "motor_targets": per_leg_vec,
            "reward": {"type": "object", "additionalProperties": _NUM},
            "contacts": {"type": "object", "properties": {leg: {"type": "boolean"} for leg in legs}},
            "foot_force_n": per_leg_num,
            "closure_residual_m": per_leg_num,
            "base_height_m": _NUM,
            "base_below_terrain": {"type": "boolean"},
            "done": {"type": "boolean"},
            "fall": {"type": "boolean"},
            "off_field": {"type": "boolean"},
            "nan_reset": {"type": "boolean"},
        },
    }


def step_time_ns(step_index: int, ctrl_dt: float) -> int:
    """Simulation time [ns] at the end of control step `step_index` (0-based) of a rollout."""
    return int(round((step_index + 1) * ctrl_dt * 1e9))
