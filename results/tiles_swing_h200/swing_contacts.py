"""Where the tiles policy loses speed on stairs up: the feet's contacts against the gait's phase
table. The tiles trial (quadson_mjx.tiles_eval.run_trials: vx 0.3 m/s for 3 s from the tile's
centre, standing start) with 128 robots per tile on flat tiles, stairs up at levels 6 and 7 (2.8 /
3.2 cm) and slopes up at level 7 (16 deg), on the nominal model without pushes and in the
evaluation's condition (the run's randomization and pushes). Over the steps after the first second,
per tile:

* swing touches: the share of foot-steps that the phase table has in swing at the step before, at
  and after this one, with the foot on the ground (rewards.swing_touch's count);
* stance lifts: the share of foot-steps in stance at all three with the foot off the ground
  (rewards.stance_lift's count);
* the base's speed along the command on steps with no swing touch and on steps with one or more;
* the feet's backward slip: the horizontal speed, against the heading, of a foot on the ground at
  both ends of a step (mean over such foot-steps; positive: the foot slides back) [m/s].

    python results/tiles_swing_h200/swing_contacts.py [RUN] > results/tiles_swing_h200/swing_contacts.log

(RUN defaults to results/tiles_swing_h200; a few minutes on the 2-core CPU machine.)
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.tiles_eval import SETTLE_S, run_trials, tiles_env_config
from quadson_mjx.training import load_policy

ENVS, SECONDS, SPEED = 128, 3.0, 0.3
TILES = [("flat", 0), ("stairs_up", 6), ("stairs_up", 7), ("slope_up", 7)]


def main(run: str) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    print(
        f"run {run}; {ENVS} robots per tile, {SECONDS:.0f} s at vx {SPEED} m/s from standing; after {SETTLE_S} s"
    )
    print(
        f"{'condition':11s} {'tile':12s} {'swing touch':>11s} {'stance lift':>11s} "
        f"{'vx, no touch':>12s} {'vx, touch':>9s} {'steps w/ touch':>14s} {'back slip':>9s}"
    )
    for name, nominal in (("nominal", True), ("randomized", False)):
        cfg = tiles_env_config(env_cfg, nominal)
        env = LocomotionEnv(cfg)
        feet = env._foot_geoms
        types = [env.tiles.types.index(t) for t, _ in TILES]
        type_idx = np.repeat(types, ENVS)
        level_idx = np.repeat([lv for _, lv in TILES], ENVS)
        step = env.ctrl_dt / env._gait.cycle_s

        def record(before, after, alive, env=env, feet=feet, step=step):
            d0, d = before.pipeline_state, after.pipeline_state
            contact = jax.vmap(env.foot_contact)(d)
            near = after.info["gait_progress"][:, None] + jnp.array([-step, 0.0, step])
            stance_near = env.scheduled_stance(near)  # (n, 3, 4)
            swing = ~jnp.any(stance_near, axis=1)
            stance = jnp.all(stance_near, axis=1)
            yaw = jax.vmap(quat_to_rpy)(d.qpos[:, 3:7])[:, 2]
            heading = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], -1)  # (n, 2)
            dxy = (d.geom_xpos[:, feet] - d0.geom_xpos[:, feet])[..., :2] / env.ctrl_dt  # (n, 4, 2)
            back = -jnp.einsum("nfk,nk->nf", dxy, heading)
            both = contact & jax.vmap(env.foot_contact)(d0)
            return {
                "alive": alive,
                "vx": after.metrics["forward_speed"],
                "touch": contact & swing,
                "swing": swing,
                "lift": ~contact & stance,
                "stance": stance,
                "back": jnp.where(both, back, jnp.nan),
            }

        n_steps = int(round(SECONDS / env.ctrl_dt))
        out = run_trials(env, cfg, policy, type_idx, level_idx, (SPEED, 0.0, 0.0), n_steps, 0, record=record)
        tr = out["record"]
        late = (np.arange(n_steps)[:, None] * env.ctrl_dt >= SETTLE_S) & tr["alive"]  # (T, n)
        for k, (t, lv) in enumerate(TILES):
            i = slice(k * ENVS, (k + 1) * ENVS)
            keep = late[:, i]
            touch, swing = tr["touch"][:, i][keep], tr["swing"][:, i][keep]
            lift, stance = tr["lift"][:, i][keep], tr["stance"][:, i][keep]
            vx = tr["vx"][:, i][keep]
            any_touch = touch.any(axis=-1)
            back = tr["back"][:, i][keep]
            print(
                f"{name:11s} {f'{t} {lv}':12s} {100 * touch.sum() / swing.sum():10.1f}% "
                f"{100 * lift.sum() / stance.sum():10.1f}% {vx[~any_touch].mean():12.3f} "
                f"{vx[any_touch].mean() if any_touch.any() else float('nan'):9.3f} {100 * any_touch.mean():13.1f}% "
                f"{np.nanmean(back):9.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "results/tiles_swing_h200")
