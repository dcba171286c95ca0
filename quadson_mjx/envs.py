"""The environment of an env config: its task's class (env.task, quadson_mjx.getup_config.TASKS)."""

from __future__ import annotations

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.getup_env import GetupEnv


def make_env(cfg) -> LocomotionEnv:
    """cfg: an env config (ConfigDict or a run's saved dict) -> LocomotionEnv, or GetupEnv for
    task="getup" (a config saved before the key existed is a locomotion one)."""
    return GetupEnv(cfg) if cfg.get("task", "locomotion") == "getup" else LocomotionEnv(cfg)
