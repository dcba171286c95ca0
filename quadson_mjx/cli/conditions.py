"""An evaluation's conditions on the command line: `--env.KEY=VALUE` for the keys of the env config
that set the world a trained policy is evaluated in (CONDITION_KEYS: the sensor model, noise, the
randomization ranges, pushes, the MJX implementation, the physics timestep, the feet's contacts on a
height field, the five-bar model, the tiled ground's number of levels), never what the policy
observes or does (the policy still acts every ctrl_dt; both five-bar models give the same
observation and action, entry by entry).
Used by quadson-tiles-eval and quadson-policy-eval, e.g. `--env.sensor.imu_tilt_rad=0.01`: the
IMU's mounting as a calibrated robot keeps it (deploy_imu) instead of within 2 degrees;
`--env.tiles.levels=8 --levels 5`: the tiles at 6/8 of their largest size (15 degrees, 3 cm steps)
instead of the 7/10 and 8/10 of the run's ten levels."""

from __future__ import annotations

from quadson_mjx.errors import UsageError

# the env config keys (and key prefixes) that set an evaluation's conditions, not the policy's task
CONDITION_KEYS = (
    "sensor.",
    "noise.",
    "randomization.",
    "randomize",
    "push.",
    "pushes",
    "impl",
    "sim_dt",
    "hfield_foot_contacts",
    "fivebar_model",  # the plant's five-bar: a policy trained on the light model, evaluated on the full one
    "tiles.levels",  # the rows of the tiled ground: level L of N is (L + 1) / N of each type's largest size
)


def condition_overrides(rest: list[str]) -> list[str]:
    """The arguments argparse left over -> the overrides "KEY=VALUE" of their `--env.KEY=VALUE`;
    UsageError for any other argument and for a key outside CONDITION_KEYS."""
    bad = [r for r in rest if not r.startswith("--env.")]
    if bad:
        raise UsageError(f"unrecognized arguments: {' '.join(bad)}")
    overrides = [r[len("--env.") :] for r in rest]
    for o in overrides:
        key = o.split("=", 1)[0]
        if not any(key == c or (c.endswith(".") and key.startswith(c)) for c in CONDITION_KEYS):
            raise UsageError(
                f"--env.{key}: only the evaluation's conditions may change ({', '.join(CONDITION_KEYS)}); "
                "what the policy observes and does comes from its run"
            )
    return overrides


def conditions_config(env_cfg, overrides: list[str]):
    """A run's env config with the evaluation's overrides, checked; UsageError naming the key.
    With fewer tile levels than the run's curriculum started its robots at, the start levels
    (tiles.min_init_level, max_init_level: training's only; an evaluation puts each robot on its
    tile) come down to the top level."""
    from quadson_mjx.config import apply_overrides
    from quadson_mjx.env_config import check_env_config, with_added_keys
    from quadson_mjx.terrain_tiles import relaid

    try:
        cfg = apply_overrides(with_added_keys(env_cfg), overrides, prefix="env.")
        levels = cfg.tiles.levels if "tiles" in cfg else None
        if (
            any(o.split("=", 1)[0] == "tiles.levels" for o in overrides)
            and isinstance(levels, int)
            and levels >= 1
        ):
            cfg.tiles.update(relaid(cfg.tiles, levels))
        check_env_config(cfg)
    except ValueError as e:
        raise UsageError(str(e)) from None
    return cfg
