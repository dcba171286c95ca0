"""How the tiles policy misses on stairs up: each robot's share of the commanded distance, not only
the success rate. The tiles trial (quadson_mjx.tiles_eval.run_trials: vx 0.3 m/s for 3 s from the
tile's centre, standing start; success = no fall and >= 80 % of the 0.9 m commanded) with 128
robots per tile on flat tiles and stairs up at levels 6 and 7 (2.8 / 3.2 cm), on the nominal model
without pushes and in the evaluation's condition (the run's randomization and pushes). Per tile:
falls, success, the shares' quartiles, how many robots end within 0.10 below the bar (0.70-0.80),
and the mean speed along the command after the first second (the start from standing left out).

    python results/tiles_swing_h200/stairs_shares.py [RUN] > results/tiles_swing_h200/stairs_shares.log

(RUN defaults to results/tiles_swing_h200; about 2 minutes on the 2-core CPU machine, idle.)
"""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.tiles_eval import run_trials, tiles_env_config
from quadson_mjx.training import load_policy
from quadson_mjx.wrappers import SUCCESS_SHARE

ENVS, SECONDS, SPEED = 128, 3.0, 0.3
TILES = [("flat", 0), ("stairs_up", 6), ("stairs_up", 7)]


def main(run: str) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    print(f"run {run}; {ENVS} robots per tile, {SECONDS:.0f} s at vx {SPEED} m/s from standing")
    print(
        f"{'condition':14s} {'tile':14s} {'falls':>5s} {'success':>10s} {'share q25 / q50 / q75':>22s} "
        f"{'0.70-0.80':>9s} {'speed after 1 s':>15s}"
    )
    for name, nominal in (("nominal", True), ("randomized", False)):
        cfg = tiles_env_config(env_cfg, nominal)
        env = LocomotionEnv(cfg)
        types = [env.tiles.types.index(t) for t, _ in TILES]
        type_idx = np.repeat(types, ENVS)
        level_idx = np.repeat([lv for _, lv in TILES], ENVS)
        n_settle = int(round(1.0 / env.ctrl_dt))

        def along(
            before, after, alive, dt=env.ctrl_dt
        ):  # a step's distance along the command, as run_trials sums it
            return jnp.where(alive, jnp.clip(after.metrics["forward_speed"], 0.0, SPEED) * dt, 0.0)

        steps = int(round(SECONDS / env.ctrl_dt))
        full = run_trials(env, cfg, policy, type_idx, level_idx, (SPEED, 0.0, 0.0), steps, 0, record=along)
        share = full["progress"] / (SPEED * SECONDS)
        later = full["record"][n_settle:].sum(axis=0) / (SECONDS - 1.0)  # the speed after the first second
        for k, (t, lv) in enumerate(TILES):
            i = slice(k * ENVS, (k + 1) * ENVS)
            ok = ~full["fell"][i] & (share[i] >= SUCCESS_SHARE)
            q = np.quantile(share[i], [0.25, 0.5, 0.75])
            near = np.sum((share[i] >= SUCCESS_SHARE - 0.1) & (share[i] < SUCCESS_SHARE) & ~full["fell"][i])
            print(
                f"{name:14s} {f'{t} {lv}':14s} {int(full['fell'][i].sum()):5d} {int(ok.sum()):3d} ({100 * ok.mean():3.0f}%) "
                f"{f'{q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}':>22s} {int(near):9d} {later[i].mean():12.3f} m/s",
                flush=True,
            )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "results/tiles_swing_h200")
