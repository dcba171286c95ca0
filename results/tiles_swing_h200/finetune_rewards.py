"""Why a fine-tune of the tiles policy at the hard levels walks slower uphill: the reward each
policy earns in the tiles trial, term by term.

The tiles trial (quadson_mjx.tiles_eval.run_trials: vx 0.3 m/s for 3 s from the tile's centre,
standing start, the run's randomization and pushes, the IMU's mounting within 0.01 rad as after a
calibration) with ENVS robots per tile, for tiles_swing_h200 and its fine-tune of 75M steps at
levels 6-9 (comparison/tiles_min6_cal_h200). Per tile and policy: the share of the commanded
distance covered, the success share, and each reward term's mean per control step over the steps
the robots were up (weighted as the env sums them), then the total.

    python results/tiles_swing_h200/finetune_rewards.py > results/tiles_swing_h200/finetune_rewards.log

(A few minutes on the 2-core CPU machine.)
"""

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.tiles_eval import run_trials, tiles_env_config
from quadson_mjx.training import load_policy
from quadson_mjx.wrappers import SUCCESS_SHARE

ENVS, SECONDS, SPEED = 64, 3.0, 0.3
RUNS = ["results/tiles_swing_h200", "results/tiles_swing_h200/comparison/tiles_min6_cal_h200"]
TILES = [("flat", 0), ("slope_up", 6), ("stairs_up", 6)]
CALIBRATED = ["sensor.imu_tilt_rad=0.01"]


def per_term(run: str):
    """-> ({tile: (distance share, success share, {term: mean per step})}, term names)."""
    policy, env_cfg, _, _ = load_policy(Path(run))
    cfg = apply_overrides(tiles_env_config(env_cfg), CALIBRATED, prefix="env.")
    env = LocomotionEnv(cfg)
    spec = env.tiles
    type_idx = np.repeat([spec.types.index(t) for t, _ in TILES], ENVS)
    level_idx = np.repeat([lv for _, lv in TILES], ENVS)
    terms = sorted(f"reward/{k}" for k in cfg.reward.weights)  # the env's metrics name them so

    def record(before, after, alive):
        return {k: jnp.where(alive, after.metrics[k], 0.0) for k in terms}, alive

    n_steps = int(round(SECONDS / env.ctrl_dt))
    out = run_trials(env, cfg, policy, type_idx, level_idx, (SPEED, 0.0, 0.0), n_steps, 0, record)
    rewards, alive = out["record"]
    steps_up = alive.sum(axis=0)  # (n,)
    success = ~out["fell"] & (out["progress"] >= SUCCESS_SHARE * SPEED * SECONDS)
    rows = {}
    for i, tile in enumerate(TILES):
        sel = slice(i * ENVS, (i + 1) * ENVS)
        per_step = {k: float(rewards[k][:, sel].sum() / steps_up[sel].sum()) for k in terms}
        share = float(out["progress"][sel].mean() / (SPEED * SECONDS))
        rows[tile] = (share, float(success[sel].mean()), per_step)
    return rows, terms


def main() -> None:
    results = {run: per_term(run) for run in RUNS}
    terms = results[RUNS[0]][1]
    print(
        f"{ENVS} robots per tile, vx {SPEED} m/s for {SECONDS:.0f} s, randomized, pushed, IMU within 0.01 rad"
    )
    print("reward: each term's mean per control step while up, weighted as the env sums it")
    names = [Path(r).name for r in RUNS]
    for tile in TILES:
        print(f"\n{tile[0]} level {tile[1]}")
        print(f"{'':28s}" + "".join(f"{n[:24]:>26s}" for n in names))
        print(f"{'distance share':28s}" + "".join(f"{results[r][0][tile][0]:26.3f}" for r in RUNS))
        print(f"{'success':28s}" + "".join(f"{results[r][0][tile][1]:26.3f}" for r in RUNS))
        for k in terms:
            vals = [results[r][0][tile][2][k] for r in RUNS]
            if max(abs(v) for v in vals) < 5e-4:
                continue
            print(f"{k[len('reward/') :]:28s}" + "".join(f"{v:26.4f}" for v in vals))
        totals = [sum(results[r][0][tile][2].values()) for r in RUNS]
        print(f"{'total':28s}" + "".join(f"{v:26.4f}" for v in totals))


if __name__ == "__main__":
    main()
