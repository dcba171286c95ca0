"""How a policy trained with env.gait_action uses its two gait actions on the tiled ground: the
step-length and cycle-frequency scales (1 + gait_action_range x action) it sets, averaged over the
steps after the first second and over robots, per tile, beside the share of the commanded distance
covered. The tiles evaluation's trial (tiles_eval.run_trials: randomized, pushed, 0.3 m/s forward),
at the 2 ms step with the calibrated IMU's mounting range, 32 robots a tile.

    python results/tiles_ga_h200/gait_scales.py results/tiles_ga_more_h200
"""

import sys
from pathlib import Path

import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.tiles_eval import run_trials, tiles_env_config
from quadson_mjx.training import load_policy

TILES = [("stairs_up", 7), ("stairs_up", 6), ("flat", 6), ("slope_up", 7), ("stairs_down", 7)]
ROBOTS, STEPS, SETTLE = 32, 150, 50


def main(run: str) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    if not env_cfg.gait_action:
        raise SystemExit(f"{run}: not trained with env.gait_action")
    cfg = tiles_env_config(apply_overrides(env_cfg, ["sensor.imu_tilt_rad=0.01", "sim_dt=0.002"]))
    env = LocomotionEnv(cfg)
    types = list(env.tiles.types)
    type_idx = np.repeat([types.index(t) for t, _ in TILES], ROBOTS)
    level_idx = np.repeat([level for _, level in TILES], ROBOTS)
    out = run_trials(
        env, cfg, policy, type_idx, level_idx, (0.3, 0.0, 0.0), STEPS, 0,
        record=lambda before, after, alive: after.info["last_action"][:, 12:14],
    )  # fmt: skip
    scales = 1.0 + cfg.gait_action_range * out["record"][SETTLE:]  # (steps, robots, 2)
    share = out["progress"] / (0.3 * STEPS * env.ctrl_dt)
    print(f"{run}: step-length and frequency scales (mean; sd of the robots' means), distance share")
    for k, (kind, level) in enumerate(TILES):
        s = slice(k * ROBOTS, (k + 1) * ROBOTS)
        per_robot = scales[:, s].mean(0)
        print(
            f"{kind:12s} level {level}: length {per_robot[:, 0].mean():.3f} ({per_robot[:, 0].std():.3f}), "
            f"frequency {per_robot[:, 1].mean():.3f} ({per_robot[:, 1].std():.3f}), share {share[s].mean():.3f}"
        )


if __name__ == "__main__":
    main(sys.argv[1])
