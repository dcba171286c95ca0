"""The metadata an export writes beside the policy (export format 3): what the robot's side needs to
run the file without the training code, the identity of the model the run trained on, the sensor
ranges it trained with and the run's provenance. Imported by quadson_mjx.export on the training
machine (it needs mujoco and the environment); the robot only reads the JSON.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quadson_mjx.policy_file import FORMAT_VERSION


def model_identity(robot, env_cfg) -> dict:
    """The identity of the model a run trained on: sha256 of the MJCF that MuJoCo writes back for
    env_model.training_model (the robot's scene with the config's physics options) and of its height
    field, the physics timestep, and each motor's actuator gains (kp, kv, force range)."""
    import hashlib
    import tempfile

    import mujoco

    from quadson_mjx.env_model import name_ids, training_model

    m = training_model(robot, env_cfg)
    # the XML of the model just loaded, with m's values; the tiled ground is built in memory from the
    # stone-field scene (env_model.tiles_model): the XML is that scene's with the same options, and
    # hfield_sha256 is the tiled field's
    scene = m if env_cfg.terrain != "tiles" else training_model(robot, _with_terrain(env_cfg, "rough"))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.xml"
        mujoco.mj_saveLastXML(str(path), scene)
        xml = path.read_bytes()
    ids = name_ids(m, mujoco.mjtObj.mjOBJ_ACTUATOR, robot.actuators)
    return {
        "mjcf_sha256": hashlib.sha256(xml).hexdigest(),
        "hfield_sha256": hashlib.sha256(np.asarray(m.hfield_data, np.float32).tobytes()).hexdigest(),
        "timestep_s": float(m.opt.timestep),
        "actuator_gains": {
            name: {
                "kp": float(m.actuator_gainprm[i, 0]),
                "kv": float(-m.actuator_biasprm[i, 2]),
                "forcerange": [float(v) for v in m.actuator_forcerange[i]],
            }
            for name, i in zip(robot.actuators, ids, strict=True)
        },
    }


def _with_terrain(env_cfg, terrain: str):
    """A copy of env_cfg (frozen or not) on another ground."""
    from quadson_mjx.env_config import with_added_keys

    cfg = with_added_keys(env_cfg).unlock()
    cfg.terrain = terrain
    return cfg


def robot_meta(env) -> dict:
    """What the robot's side needs to know of the robot: motor and actuator names and order, home
    pose and limits (deploy_robots, from the numpy kinematics the loop runs), and for Caramel the
    geometry and gait of its numpy IK and trot (robots/caramel/gait_np.py)."""
    from quadson_mjx.deploy_robots import robot_kinematics
    from quadson_mjx.robots.caramel import gait_np as caramel_np

    cfg = json.loads(_config_json(env.config))
    extra = {}
    if env.robot.name == "caramel":
        gait = {k: (np.asarray(v).tolist()) for k, v in env.gait_params._asdict().items()}
        extra["caramel"] = {"geometry": caramel_np.geometry().to_dict(), "gait": gait}
    r = robot_kinematics(cfg, extra)
    if tuple(r.motor_names) != tuple(env.robot.motor_joints):
        raise ValueError(f"{env.robot.name}: the deploy loop's motor order differs from the model's")
    return {
        "robot": r.name,
        "motors": list(r.motor_names),
        "actuators": list(r.actuator_names),
        "home_motor_pos_rad": r.home_motor.tolist(),
        "motor_limits_rad": r.motor_limits.tolist(),
        "servo_speed_rps": r.servo_speed_rps,
        **extra,
    }


def _config_json(cfg) -> str:
    from quadson_mjx.config import to_json

    return to_json(cfg)


def run_meta(env, ppo_cfg, run_dir: Path, checkpoint: Path) -> dict:
    """The export's meta_json for the LocomotionEnv `env` of a run directory and its checkpoint."""
    from quadson_mjx.provenance import versions

    cfg = env.config
    spec = env.obs_spec
    run_config = json.loads((Path(run_dir) / "config.json").read_text())
    return {
        "format_version": FORMAT_VERSION,
        "checkpoint": str(Path(checkpoint).name),
        "env_config": json.loads(_config_json(cfg)),
        "ppo_config": json.loads(_config_json(ppo_cfg)),
        "ctrl_dt_s": env.ctrl_dt,
        "action_scale_m": float(cfg.action_scale_m),
        "obs_spec": spec.to_json(),
        "obs_names": list(spec.names),
        "action_spec": env.action_spec.to_json(),
        **robot_meta(env),
        # the ranges the policy was trained with (env_config: sensor, noise, randomization)
        "trained_sensor_model": {
            "observation": cfg.observation,
            "randomize": bool(cfg.randomize),
            "sensor": json.loads(_config_json(cfg.sensor)) if "sensor" in cfg else {},
            "noise": json.loads(_config_json(cfg.noise)),
            "actuation_latency_s": list(cfg.randomization.latency_s),
        },
        "model": model_identity(env.robot, cfg),
        # env_config and model are the run's on MJX's JAX implementation (load_run_config's
        # for_evaluation); the implementation it trained on:
        "trained_impl": run_config.get("env", {}).get("impl", "jax"),
        # the training run's versions and commit (config.json), not this machine's
        "provenance": run_config.get("versions", {}),
        "exported_with": versions(),
    }
