"""Named training tasks, as MuJoCo Playground registers its environments: a name -> a locked env config.

    from quadson_mjx import tasks
    tasks.task_names()                          # QuadsonFlat, ..., QuadsonJoystickRough, QuadsonGaitBound, ...
    cfg = tasks.make_task_config("QuadsonJoystickRough")    # == quadson-train --env-preset robust --terrain rough

A task is one point of the training script's flags (robot x env preset x terrain, plus Quadson's gait
recipes), built by `config_from_flags`, the one function that turns those flags into an env config:
`quadson-train --task NAME` and the flag spelling give identical configs (tests/test_tasks.py).
Names: <Robot>[Command|Joystick]<Terrain> for the env presets seed, command and robust, and
Quadson<Gait><Name> for the gait recipes (env_recipes.GAIT_RECIPES, seed preset, flat ground, as the
committed results/gaits runs were trained).
"""

from __future__ import annotations

import difflib
import functools
import json
from collections.abc import Callable

import ml_collections

from quadson_mjx.env_config import check_env_config, env_config, with_added_keys
from quadson_mjx.env_recipes import GAIT_RECIPES
from quadson_mjx.robots import ROBOT_NAMES, TERRAINS

# Training physics of every preset: feet-only ground contact and no joint-limit rows (the episode
# ends before the base reaches the ground; the IK keeps targets in range): 28 constraint rows
# instead of 56, +18 % environment steps/s at 8192 worlds on one H100
# (benchmarks/physics_vs_go1.py; the box-heightfield collision on rough ground costs far more).
FAST_PHYSICS = {"base_terrain_contact": False, "joint_limits": False}
ENV_PRESETS = {
    "seed": {**FAST_PHYSICS},
    "command": {**FAST_PHYSICS, "command_tracking": True},
    # the joystick recipe (commands resampled every 4-8 s, 10 % zero, the sweep's range, base-in-ground
    # termination) with randomization and pushes; the actor observes the robot's own sensors, the
    # critic the simulator's state (asymmetric actor-critic)
    "robust": {
        **FAST_PHYSICS,
        "joystick": True,
        "randomize": True,
        "pushes": True,
        "observation": "sensors",
        "asymmetric_critic": True,
    },
    # the same recipe with seed 000's observation (the simulator's base velocity and yaw), kept to
    # compare with: results/policy_h100_joystick was trained with it
    "robust_true_state": {**FAST_PHYSICS, "joystick": True, "randomize": True, "pushes": True},
    # getting up after a fall (quadson_mjx.getup_env; Quadson on flat or rough ground): the robot's
    # legs and base touch the ground, the actor observes the robot's own sensors, randomized
    "getup": {"joint_limits": False, "randomize": True, "task": "getup"},
}
# On a height field (the stone field, the tiles) the walking presets collide each foot sphere into
# one contact, the nearest point of the surface (env.hfield_foot_contacts=1, quadson_mjx.hfield_contact):
# MuJoCo C's deepest contact, where MJX's own collider keeps up to four and errs beside slopes and
# steps; the stone field's physics 1.43x and the tiles' environment 1.68x faster on one H200
# (docs/benchmarks.md). Runs trained before it used MJX's collider (their configs say 4).
HFIELD_PHYSICS = {"hfield_foot_contacts": 1}
# the presets that only some robots and terrains have (else every robot x terrain is a task)
PRESET_ROBOTS = {"getup": ("quadson",)}
PRESET_TERRAINS = {"getup": ("flat", "rough")}

# the word of each env preset in a task's name (the robust preset is the joystick recipe)
PRESET_WORDS = {
    "seed": "",
    "command": "Command",
    "robust": "Joystick",
    "robust_true_state": "JoystickTrueState",
    "getup": "Getup",
}


def config_from_flags(
    robot: str = "quadson",
    env_preset: str = "seed",
    terrain: str = "flat",
    gait: str | None = None,
    gait_action: bool = False,
) -> ml_collections.ConfigDict:
    """The env config of the training script's flags (--robot, --env-preset, --terrain, --gait,
    --gait-action), locked and checked (env_config.check_env_config); off the plane the walking
    presets add HFIELD_PHYSICS. `gait` trains that gait with
    its recipe (env_recipes.GAIT_RECIPES). Raises ValueError for an unknown preset, terrain, robot or
    gait, a gait without a recipe, or gait_action for a robot whose gait cannot be scaled."""
    if env_preset not in ENV_PRESETS:
        raise ValueError(f"unknown env preset {env_preset!r}; choose from {sorted(ENV_PRESETS)}")
    recipe = {"gait": gait, "gait_recipe": True} if gait else {}
    preset = ENV_PRESETS[env_preset]
    cfg = env_config(terrain=terrain, robot=robot, **preset, **recipe)
    if terrain != "flat" and preset.get("task", "locomotion") == "locomotion":
        cfg.update(HFIELD_PHYSICS)
    cfg.gait_action = gait_action
    check_env_config(cfg)
    return cfg


def task_name(robot: str, env_preset: str, terrain: str, gait: str | None = None) -> str:
    """The registry name of a flag combination, e.g. ("quadson", "robust", "rough") ->
    "QuadsonJoystickRough", ("quadson", "seed", "flat", "bound") -> "QuadsonGaitBound"."""
    if gait is not None:
        return f"{robot.capitalize()}Gait{gait.capitalize()}"
    return f"{robot.capitalize()}{PRESET_WORDS[env_preset]}{terrain.capitalize()}"


def _flag_sets() -> dict[str, dict]:
    """name -> the flags of every registered task: robot x env preset x terrain (the robots' scenes),
    Quadson's joystick on the tiled ground, then the gait recipes."""
    out = {}
    for robot in ROBOT_NAMES:
        for preset in ENV_PRESETS:
            if robot not in PRESET_ROBOTS.get(preset, ROBOT_NAMES):
                continue
            for terrain in PRESET_TERRAINS.get(preset, TERRAINS):
                flags = {"robot": robot, "env_preset": preset, "terrain": terrain}
                out[task_name(**flags)] = flags
    # the tiled ground with its curriculum (env_config.TILES), for the sensor-only joystick policy
    flags = {"robot": "quadson", "env_preset": "robust", "terrain": "tiles"}
    out[task_name(**flags)] = flags
    for gait in GAIT_RECIPES:  # Quadson's; env_config refuses a recipe for another robot
        flags = {"robot": "quadson", "env_preset": "seed", "terrain": "flat", "gait": gait}
        out[task_name(**flags)] = flags
    return out


# name -> the training script's flags of the task (keyword arguments of config_from_flags)
TASK_FLAGS: dict[str, dict] = _flag_sets()
# name -> factory of the task's locked env config
TASKS: dict[str, Callable[[], ml_collections.ConfigDict]] = {
    name: functools.partial(config_from_flags, **flags) for name, flags in TASK_FLAGS.items()
}


def task_names() -> list[str]:
    """Every registered task name, in registry order (robot, preset, terrain; then the gaits)."""
    return list(TASKS)


def make_task_config(name: str) -> ml_collections.ConfigDict:
    """The locked env config of task `name`. Raises ValueError naming the closest names for an
    unknown one."""
    if name not in TASKS:
        close = difflib.get_close_matches(name, TASKS, n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(close)}?" if close else f"; choose from {', '.join(TASKS)}"
        raise ValueError(f"unknown task {name!r}{hint}")
    return TASKS[name]()


def find_task(env_cfg) -> str | None:
    """The name of the task whose config `env_cfg` is (a ConfigDict or a dict, e.g. a run's saved
    "env" section; keys added since it was written get their old values, env_config.with_added_keys;
    gait_action is ignored: a flag of its own), or None."""
    data = _comparable(with_added_keys(env_cfg))
    for name, make in TASKS.items():
        if _comparable(make()) == data:
            return name
    return None


def _comparable(cfg) -> dict:
    """cfg as plain JSON data (tuples as lists), gait_action dropped."""
    data = json.loads(json.dumps(cfg.to_dict(), default=list))
    data.pop("gait_action", None)
    return data
