"""How far short of the success line a tiles policy's failures end: each robot's share of the
commanded distance (success: >= 0.8 and no fall), sorted, per tile. The tiles evaluation's trial
(tiles_eval.run_trials: randomized, pushed, 0.3 m/s forward for 3 s) at the 2 ms step with the
calibrated IMU's mounting range, 64 robots a tile, on the CPU; KEY=VALUE: env overrides on top
(e.g. gait_scale.step_length_m=1.15: the gait's stride longer than the policy trained with).

    python results/tiles_ga_more_h200/comparison/ema/distance_shares.py RUN [KEY=VALUE ...]
"""

import sys
from pathlib import Path

import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.tiles_eval import run_trials, tiles_env_config
from quadson_mjx.training import load_policy

TILES = [("stairs_up", 7), ("stairs_up", 6), ("flat", 6), ("slope_up", 7)]
ROBOTS, STEPS = 64, 150


def main(run: str, overrides: list[str]) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    cfg = tiles_env_config(apply_overrides(env_cfg, ["sensor.imu_tilt_rad=0.01", "sim_dt=0.002", *overrides]))
    env = LocomotionEnv(cfg)
    types = list(env.tiles.types)
    type_idx = np.repeat([types.index(t) for t, _ in TILES], ROBOTS)
    level_idx = np.repeat([level for _, level in TILES], ROBOTS)
    out = run_trials(env, cfg, policy, type_idx, level_idx, (0.3, 0.0, 0.0), STEPS, 0)
    share = np.asarray(out["progress"]) / (0.3 * STEPS * env.ctrl_dt)
    fell = np.asarray(out["fell"])
    print(
        f"{' '.join([run, *overrides])}: share of the commanded 0.9 m per robot, sorted; success = share >= 0.8 and no fall"
    )
    for k, (kind, level) in enumerate(TILES):
        s = slice(k * ROBOTS, (k + 1) * ROBOTS)
        ok = (share[s] >= 0.8) & ~fell[s]
        print(
            f"{kind} level {level}: success {ok.mean():.3f}, falls {int(fell[s].sum())}, mean share "
            f"{share[s].mean():.3f}; " + " ".join(f"{x:.2f}" for x in np.sort(share[s]))
        )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
