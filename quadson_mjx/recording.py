"""A rollout recorded to an MCAP file that opens in Foxglove: `record` runs quadson_mjx.rollout segment
by segment and writes each into a foxglove_mcap.RolloutWriter, with the run's metadata, the model
and a log line for every fall, edge of the field or non-finite reset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quadson_mjx import rollout
from quadson_mjx.config import to_json
from quadson_mjx.env_model import scene_xml_text
from quadson_mjx.foxglove_mcap import RolloutWriter, step_time_ns
from quadson_mjx.provenance import versions


def record(
    path: str | Path,
    env,
    controller,
    rng,
    n_envs: int,
    n_steps: int,
    command=None,
    segment_steps: int = 250,
    metadata: dict | None = None,
    overwrite: bool = False,
    viz_envs: int | None = 16,
    randomize: bool = False,
    on_segment=None,
) -> dict:
    """Runs `rollout.run` and writes it to `path`. Flushes after the static scene, at
    every step where an episode ends and after every segment. The first `viz_envs` environments (None:
    all) are drawn; /rollout/step has every one. command: None (sampled), (3,) or one per env (B, 3).
    on_segment(first step index, host Trajectory [t, B]) is called after each segment is written
    (e.g. a video renderer). -> {"steps", "falls", "off_field", "nan_resets"}."""
    if n_envs < 1 or n_steps < 1:
        raise ValueError(f"a rollout needs n_envs >= 1 and n_steps >= 1, got {n_envs} and {n_steps}")
    ctrl_dt = env.ctrl_dt
    falls = nan_resets = off_field = 0
    # command: (3,) for all envs or (n_envs, 3), one per env
    command_text = "sampled per env" if command is None else json.dumps(np.asarray(command, float).tolist())
    with RolloutWriter(
        path, env.mj_model, n_envs, ctrl_dt, env.robot.legs, overwrite=overwrite, viz_envs=viz_envs
    ) as w:
        info = {
            "controller": controller.name,
            "n_envs": n_envs,
            "viz_envs": w.viz_envs,
            "n_steps": n_steps,
            "ctrl_dt_s": ctrl_dt,
            "terrain": env.config.terrain,
            "command": command_text,
            "randomize": randomize,
            **(metadata or {}),
        }
        w.write_metadata("rollout", info)
        w.write_metadata("env_config", {"json": to_json(env.config)})
        w.write_metadata("versions", versions())
        robot = env.robot
        w.attach(
            f"{robot.name}.xml",
            scene_xml_text(robot, env.config).encode(),
            "application/xml",
        )
        w.log(0, "info", f"start: {controller.name}, {n_envs} env(s), {n_steps} steps of {ctrl_dt} s")
        w.write_scene(0)
        runs = rollout.run(env, controller, rng, n_envs, n_steps, segment_steps, command, randomize)
        for start, traj in runs:
            for k in range(traj.done.shape[0]):
                t_ns = step_time_ns(start + k, ctrl_dt)
                w.write_step(t_ns, traj, k)
                ended = np.flatnonzero(traj.done[k])
                for i in ended:
                    r, p, _ = np.degrees(traj.rpy[k, i])
                    if traj.nan_reset[k, i]:
                        nan_resets += 1
                        w.log(
                            t_ns,
                            "error",
                            f"env{i}: non-finite physics at episode step {traj.episode_step[k, i]}; reset",
                        )
                    elif traj.off_field[k, i]:
                        off_field += 1
                        w.log(t_ns, "info", f"env{i}: reached the field's edge; reset (not a fall)")
                    else:
                        falls += 1
                        w.log(
                            t_ns,
                            "warning",
                            f"env{i}: fell at {traj.episode_step[k, i] * ctrl_dt:.2f} s (roll {r:.0f} deg, pitch "
                            f"{p:.0f} deg, height {traj.qpos[k, i, 2]:.3f} m); reset",
                        )
                if len(ended):
                    w.flush()
            w.flush()
            if on_segment is not None:
                on_segment(start, traj)
        w.log(
            step_time_ns(n_steps - 1, ctrl_dt),
            "info",
            f"end: {falls} fall(s), {off_field} at the field's edge, {nan_resets} non-finite reset(s)",
        )
    return {"steps": n_steps, "falls": falls, "off_field": off_field, "nan_resets": nan_resets}
