"""Why the tiled-ground policy (results/tiles_h100) makes no headway up slopes and stairs: the
evaluation's trial (quadson_mjx.tiles_eval: 32 robots per tile from its centre, a random heading,
vx 0.3 m/s for 3 s) on a few tiles, here on the nominal model without pushes so that only the
ground differs, recording per tile:

* success and the distance share as the evaluation counts them, and the mean forward speed after
  the gait's start ramp (t >= 1 s) [m/s];
* legs whose foot target the inverse kinematics clamped (share of leg-steps after 1 s);
* a motor at 98 % of its torque limit (share of motor-steps after 1 s, per motor 0, 1, 2);
* foot slip: the horizontal speed of a foot that touches the ground at both ends of a control step
  (median and 90th percentile [m/s]);
* the base's pitch (mean [deg], positive nose down).

    python results/tiles_h100/uphill_diagnosis.py > results/tiles_h100/uphill_diagnosis.log
    python results/tiles_h100/uphill_diagnosis.py results/tiles_pitch_h100 > results/tiles_pitch_h100/uphill_diagnosis.log
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import training
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.tiles_eval import SETTLE_S, difficulty, run_trials, tiles_env_config
from quadson_mjx.wrappers import SUCCESS_SHARE

TILES = [  # (type, level)
    ("flat", 0),
    ("slope_up", 3),
    ("slope_up", 5),
    ("stairs_up", 3),
    ("stairs_up", 5),
    ("slope_down", 5),
    ("stairs_down", 5),
]
PER_TILE, SECONDS, COMMAND, SEED = 32, 3.0, (0.3, 0.0, 0.0), 0
SATURATED = 0.98

RUN = sys.argv[1] if len(sys.argv) > 1 else "results/tiles_h100"
policy, env_cfg, _, _ = training.load_policy(Path(RUN))
cfg = tiles_env_config(env_cfg, nominal=True)
env = LocomotionEnv(cfg)
spec = env.tiles
type_idx = np.repeat([spec.types.index(t) for t, _ in TILES], PER_TILE)
level_idx = np.repeat([lv for _, lv in TILES], PER_TILE)
n_steps = int(round(SECONDS / env.ctrl_dt))
speed = float(np.hypot(*COMMAND[:2]))
feet = env._foot_geoms
force_max = jnp.asarray(env.sys.actuator_forcerange[:, 1])


def record(before, after, alive):
    """Per step: what the table below reports, for each robot."""
    d0, d = before.pipeline_state, after.pipeline_state
    touch = jax.vmap(env.foot_contact)(d) & jax.vmap(env.foot_contact)(d0)
    slip = jnp.linalg.norm((d.geom_xpos[:, feet] - d0.geom_xpos[:, feet])[..., :2], axis=-1) / env.ctrl_dt
    return {
        "alive": alive,
        "vx": after.metrics["forward_speed"],
        "ik_invalid": after.metrics["ik_invalid_legs"],
        "sat": jnp.abs(d.actuator_force) >= SATURATED * force_max,
        "slip": jnp.where(touch, slip, jnp.nan),
        "pitch": jax.vmap(quat_to_rpy)(d.qpos[:, 3:7])[:, 1],
    }


out = run_trials(env, cfg, policy, type_idx, level_idx, COMMAND, n_steps, SEED, record)
fell, progress, trace = out["fell"], out["progress"], out["record"]
late = (np.arange(n_steps)[:, None] * env.ctrl_dt >= SETTLE_S) & trace["alive"]  # (T, n)
commanded = speed * SECONDS
print(
    f"{RUN} on the nominal model without pushes, {PER_TILE} robots per tile, vx "
    f"{COMMAND[0]} m/s for {SECONDS} s; statistics over t >= {SETTLE_S} s"
)
print(
    "| tile | size | success | distance | vx after 1 s [m/s] | IK-clamped legs | motor at limit "
    "(0 / 1 / 2) | foot slip median / p90 [m/s] | pitch [deg] |"
)
print("|---|---|---|---|---|---|---|---|---|")
for t, lv in TILES:
    i = (type_idx == spec.types.index(t)) & (level_idx == lv)
    keep = late[:, i]
    size = difficulty(spec, t, lv)
    size_txt = next((f"{v:.3g} {k.split('_')[-1]}" for k, v in size.items()), "-")
    success = ~fell[i] & (progress[i] >= SUCCESS_SHARE * commanded)
    sat = trace["sat"][:, i].reshape(n_steps, i.sum(), 4, 3)[keep]  # (K, 4, 3)
    slip = trace["slip"][:, i][keep]
    slip = slip[np.isfinite(slip)]
    print(
        f"| {t} {lv} | {size_txt} | {100 * success.mean():.0f} % | {np.mean(progress[i]) / commanded:.2f} "
        f"| {trace['vx'][:, i][keep].mean():.3f} | {100 * trace['ik_invalid'][:, i][keep].mean() / 4:.1f} % "
        f"| {' / '.join(f'{100 * v:.0f} %' for v in sat.mean(axis=(0, 1)))} "
        f"| {np.median(slip):.3f} / {np.quantile(slip, 0.9):.3f} "
        f"| {np.degrees(trace['pitch'][:, i][keep].mean()):.1f} |"
    )
