"""A sim2sim run written as it goes: an MCAP file that opens in Foxglove (quadson_mjx.foxglove_mcap's
RolloutWriter: the same topics as an MJX rollout, one environment) and, on request, a video
(quadson_mjx.video). /rollout/step also carries what the robot's sensors read (`sensors`), the
deploy loop's per-leg IK validity (`valid`) and the servo torques (`servo_torque_nm`)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

from quadson_mjx.foxglove_mcap import RolloutWriter, step_time_ns


class Recorder:
    def __init__(self, mcap_path, video_path, plant, adapter, job: dict):
        self.plant, self.dt = plant, adapter.ctrl_dt
        robot = plant.robot
        self.writer = self.video = self.renderer = None
        self.t_ns = 0
        if mcap_path:
            w = RolloutWriter(mcap_path, plant.m, 1, self.dt, robot.legs, overwrite=True, viz_envs=1)
            meta = {k: v for k, v in job.items() if k not in ("mcap", "video", "sensors")}
            w.write_metadata(
                "sim2sim", {k: json.dumps(v) if not isinstance(v, str) else v for k, v in meta.items()}
            )
            w.write_metadata("env_config", {"json": json.dumps(adapter.env_config)})
            w.write_metadata(
                "plant",
                {
                    "servo": repr(plant.servo),
                    "sensors": repr(plant.sensors),
                    "timestep_s": str(plant.m.opt.timestep),
                },
            )
            w.attach(f"{robot.name}.xml", robot.model_xml_text("flat").encode(), "application/xml")
            w.write_scene(0)
            w.log(
                0,
                "info",
                f"sim2sim: {job['policy_name']} on {job['terrain']}, {job['label']}, seed {job['seed']}",
            )
            self.writer = w
        if video_path:
            from quadson_mjx.video import Renderer, VideoWriter

            self.video = VideoWriter(video_path, 640, 480, 1.0 / self.dt, overwrite=True)
            self.renderer = Renderer(
                plant.m, 640, 480, shadows=False
            )  # software GL: the field is 0.7 M triangles

    def step(self, k: int, plant, readings, out, command, truth, done: bool) -> None:
        if self.video is not None:
            self.video.write(self.renderer.render(plant.d.qpos))
        if self.writer is None:
            return
        d, robot = plant.d, plant.robot
        one = lambda x: np.asarray(x)[None, None]  # noqa: E731  (T = 1, B = 1)
        closure = plant.closure_gaps()
        fell = done and truth["on_field"]
        traj = SimpleNamespace(
            episode_step=one(k + 1),
            obs=one(out.obs),
            action=one(out.action),
            foot_targets=one(out.foot_targets),
            command=one(command),
            qpos=one(d.qpos),
            qvel=one(d.qvel),
            xpos=one(d.xpos),
            xquat=one(d.xquat),
            rpy=one(truth["rpy"]),
            lin_vel=one(truth["lin_vel"]),
            ang_vel=one(truth["ang_vel"]),
            imu_acc=one(plant.imu_acc()),
            foot_force=one(plant.foot_forces()),
            actuator_force=one(d.actuator_force),
            closure_residual=one(closure),
            reward=one(0.0),
            reward_terms={},
            done=one(done),
            nan_reset=one(False),
            fall=one(fell),
            off_field=one(done and not fell),
            base_height=one(truth["height"]),
            base_below_terrain=one(truth["clearance"] < 0.0),
            motor_targets=one(out.motor_targets),
        )
        t_ns = self.t_ns = step_time_ns(k, self.dt)
        extra = {
            "sensors": {
                "imu_quat_wxyz": readings.imu_quat_wxyz,
                "gyro": readings.gyro,
                "motor_pos": readings.motor_pos,
            },
            "valid": {leg: bool(v) for leg, v in zip(robot.legs, out.valid, strict=True)},
            "servo_torque_nm": d.ctrl[plant.act].copy(),
        }
        self.writer.write_step(t_ns, traj, 0, extra)
        if done:
            r, p, _ = np.degrees(truth["rpy"])
            what = "fell" if fell else "left the field"
            self.writer.log(
                t_ns, "warning", f"{what} at {(k + 1) * self.dt:.2f} s (roll {r:.0f}, pitch {p:.0f} deg)"
            )
        if k % 250 == 249 or done:
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.log(self.t_ns, "info", "end")
            self.writer.close()
        if self.video is not None:
            self.video.close()
            self.renderer.close()
