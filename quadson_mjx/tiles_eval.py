"""A policy on the tiled ground, per tile type and level: success and tracking, as the terrain
curriculum states them.

Every robot starts at the centre of its tile (within 2 cm) with a uniform heading and holds one
command for the whole trial, so on a pyramid tile it walks out from the centre: up the `slope_up`
and `stairs_up` tiles (their centre is the low point), down the `_down` ones. A trial succeeds when
the robot does not fall and covers at least SUCCESS_SHARE of the commanded distance (the distance
along the command, capped at the command's speed, as the curriculum measures it); tracking is the
RMS of the vx, vy and yaw-rate errors over every control step after the first second, until the
episode ends. The environments run through the training wrappers with the run's randomization
(one randomized model per robot) and pushes; the curriculum is off and a robot's first episode is
the only one counted.

    rows = evaluate_tiles(env_cfg, policy, levels=[0, 6, 9], envs_per_tile=32, seconds=3.0)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.stats import success_interval
from quadson_mjx.wrappers import SUCCESS_SHARE, wrap_for_evaluation

SETTLE_S = 1.0  # the first second of a trial is left out of the RMS
CENTRE_M = 0.02  # robots start this close to their tile's centre


def tiles_env_config(env_cfg, nominal: bool = False):
    """The run's env config on the tiled ground for the evaluation: its own `tiles` keys when it
    trained there (else the defaults), starts at the tile centres, the curriculum off, one command
    per trial (no resampling). nominal: no randomization (model and sensor errors) and no pushes,
    so that only the ground differs from flat ground."""
    cfg = with_added_keys(env_cfg)
    over = [
        "terrain=tiles",
        f"tiles.spawn_margin_m={cfg.tiles.tile_m / 2 - CENTRE_M}",
        "tiles.curriculum=false",
        "command_resample_s=(0.0, 0.0)",
        *(["randomize=false", "pushes=false"] if nominal else []),
    ]
    return apply_overrides(cfg, over, prefix="env.")


def evaluate_tiles(
    env_cfg,
    policy,
    levels,
    envs_per_tile: int = 32,
    seconds: float = 3.0,
    command=(0.3, 0.0, 0.0),
    seed: int = 0,
    types=None,
    nominal: bool = False,
) -> list[dict]:
    """policy(obs, key) -> (action, extras) (training.load_policy) of a run whose env config is
    env_cfg, on every tile (type, level) of `types` (default all) x `levels`, envs_per_tile robots
    each, for `seconds`, holding `command` (vx [m/s], vy [m/s], yaw rate [rad/s]) -> one row per
    tile: robots, falls, success share, mean share of the commanded distance covered, RMS vx, vy,
    yaw rate, and the tile's slope [deg] or step [m] or bump height [m] at that level. nominal: see
    tiles_env_config (default: the run's randomization and pushes)."""
    if command[1] != 0.0 or command[2] != 0.0:
        raise ValueError(f"tiles evaluation: command {tuple(command)}: forward commands (vx, 0, 0) only")
    cfg = tiles_env_config(env_cfg, nominal)
    env = LocomotionEnv(cfg)
    spec = env.tiles
    types = list(spec.types) if types is None else list(types)
    unknown = [t for t in types if t not in spec.types]
    bad_levels = [lv for lv in levels if not 0 <= lv < spec.levels]
    if unknown or bad_levels or envs_per_tile < 1 or not seconds > SETTLE_S:
        raise ValueError(
            f"tiles evaluation: types {unknown or 'ok'} (from {list(spec.types)}), levels {bad_levels or 'ok'} "
            f"(0..{spec.levels - 1}), envs_per_tile {envs_per_tile} (>= 1), seconds {seconds} (> {SETTLE_S})"
        )
    type_idx = np.repeat([spec.types.index(t) for t in types], len(levels) * envs_per_tile)
    level_idx = np.tile(np.repeat(np.asarray(levels), envs_per_tile), len(types))
    n_steps = int(round(seconds / env.ctrl_dt))
    speed = float(np.linalg.norm(np.asarray(command, float)[:2]))
    out = run_trials(env, cfg, policy, type_idx, level_idx, command, n_steps, seed)
    fell, progress, sq, kept = (out[k] for k in ("fell", "progress", "sq", "kept"))
    commanded = speed * seconds
    success = ~fell & ((progress >= SUCCESS_SHARE * commanded) | (commanded <= 0))
    rows = []
    for t in types:
        for lv in levels:
            i = (type_idx == spec.types.index(t)) & (level_idx == lv)
            rms = np.sqrt(sq[i].sum(axis=0) / max(kept[i].sum(), 1))
            rows.append(
                {
                    "type": t,
                    "level": int(lv),
                    **difficulty(spec, t, int(lv)),
                    "robots": int(i.sum()),
                    "falls": int(fell[i].sum()),
                    "success": float(success[i].mean()),
                    "success_95": success_interval(int(success[i].sum()), int(i.sum())),
                    "distance_share": float(np.mean(progress[i]) / commanded) if commanded > 0 else 1.0,
                    "rms_vx": float(rms[0]),
                    "rms_vy": float(rms[1]),
                    "rms_yaw_rate": float(rms[2]),
                }
            )
    return rows


def run_trials(env, cfg, policy, type_idx, level_idx, command, n_steps: int, seed: int, record=None) -> dict:
    """The trials of `evaluate_tiles`, jitted: robot i on tile (type_idx[i], level_idx[i]) of env
    (built from cfg = tiles_env_config(...)), holding `command` for n_steps steps, in the training
    wrappers (wrappers.wrap_for_evaluation, keys from seed). -> arrays: "fell" (n,), "progress"
    (n,) the distance along the command [m] (the body-frame vx capped at the command's speed, until
    the first episode ends), "sq" (n, 3) the summed squared vx, vy, yaw-rate errors and "kept" (n,)
    the steps summed (after SETTLE_S, before the end), and with `record(before, after, alive)` (the
    wrapped states around a step, (n,) bool) its outputs stacked over the steps as "record"."""
    n = len(type_idx)
    w = wrap_for_evaluation(env, cfg, n, seed, n_steps)
    cmd = jnp.broadcast_to(jnp.asarray(command, jnp.float32), (n, 3))
    speed = float(np.linalg.norm(np.asarray(command, float)[:2]))

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        state = w.reset_on_tiles(jax.random.split(k_reset, n), jnp.asarray(type_idx), jnp.asarray(level_idx))
        state = state.replace(info={**state.info, "command": cmd}, obs=env.with_command(state.obs, cmd))

        def one(carry, k):
            s, alive, fell, progress, sq, kept, t = carry
            action, _ = policy(s.obs, k)
            before, s = s, w.step(s, action)
            m = s.metrics
            # along the command (vx, 0, 0): the body-frame vx, capped at the command's speed
            vx_along = jnp.clip(m["forward_speed"], 0.0, speed)
            progress = progress + jnp.where(alive, vx_along * env.ctrl_dt, 0.0)
            keep = alive & (t * env.ctrl_dt >= SETTLE_S)
            err = jnp.stack([m["vx_sq_err"], m["vy_sq_err"], m["yaw_rate_sq_err"]], -1)
            sq = sq + jnp.where(keep[:, None], err, 0.0)
            kept = kept + keep
            fell = fell | (alive & (m["fall"] > 0))
            out = None if record is None else record(before, s, alive)
            alive = alive & (s.done == 0)
            s = s.replace(info={**s.info, "command": cmd}, obs=env.with_command(s.obs, cmd))
            return (s, alive, fell, progress, sq, kept, t + 1), out

        init = (
            state,
            jnp.ones(n, bool),
            jnp.zeros(n, bool),
            jnp.zeros(n),
            jnp.zeros((n, 3)),
            jnp.zeros(n),
            0,
        )
        (_, _, fell, progress, sq, kept, _), rec = jax.lax.scan(one, init, jax.random.split(k_run, n_steps))
        out = {"fell": fell, "progress": progress, "sq": sq, "kept": kept}
        return out if record is None else {**out, "record": rec}

    return jax.tree.map(np.asarray, run(jax.random.PRNGKey(seed)))


def difficulty(spec, kind: str, level: int) -> dict:
    """The tile's defining size at `level` (terrain_tiles's rules): slope [deg], step rise [m] or
    the largest bump [m]."""
    d = spec.difficulty(level)
    if kind.startswith("slope"):
        return {"slope_deg": spec.max_slope_deg * d}
    if kind.startswith("stairs"):
        return {"step_m": spec.max_step_m * d}
    top = {"stones": spec.max_stone_m, "waves": spec.max_wave_m, "obstacles": spec.max_obstacle_m}
    return {"height_m": top[kind] * d} if kind in top else {}
