"""Weak motors uphill: the 7 cm tiles policy (results/tiles_swing_h200) on the evaluation's trial
(quadson_mjx.tiles_eval: 32 robots per tile from its centre, a random heading, vx 0.3 m/s for 3 s)
with every servo's strength (its kp and force range, randomization.motor_strength) fixed at one
value, the other model ranges nominal, the sensor errors on and no pushes: uphill_factors.py's
"motors" row, one strength at a time. Per tile and strength:

* success and the distance share as the evaluation counts them;
* the mean forward speed after the gait's start ramp (t >= 1 s) [m/s];
* a motor at 98 % of its force range, as scaled by the strength (share of motor-steps after 1 s,
  per motor 0, 1, 2: the abduction and the two hip motors of the five-bar);
* the servos' position error, target minus angle, RMS over the motors and the steps after 1 s
  [mrad] (the strength scales the servo's kp: a weak servo lags its target);
* legs whose foot target the inverse kinematics clamped (share of leg-steps after 1 s).

    python results/tiles_swing_h200/motor_strength.py > results/tiles_swing_h200/motor_strength.log

(About 3 minutes on the 2-core CPU machine.)
"""

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.randomize import nominal_range_overrides
from quadson_mjx.tiles_eval import SETTLE_S, run_trials, tiles_env_config
from quadson_mjx.training import load_policy
from quadson_mjx.wrappers import SUCCESS_SHARE

TILES = [("flat", 0), ("slope_up", 7), ("stairs_up", 6), ("stairs_up", 7)]  # 16 deg, 2.8 / 3.2 cm
STRENGTHS = (0.8, 0.9, 1.0, 1.2)
PER_TILE, SECONDS, COMMAND, SEED, SATURATED = 32, 3.0, (0.3, 0.0, 0.0), 0, 0.98
OTHER_RANGES_NOMINAL = [  # with the sensor errors, no pushes
    "randomize=true",
    "pushes=false",
    *nominal_range_overrides(keep=("motor_strength",)),
]


def main(run: str) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    print(
        f"run {run}; {PER_TILE} robots per tile, vx {COMMAND[0]} m/s for {SECONDS} s, no pushes, every "
        f"servo's strength fixed, the other ranges nominal; statistics over t >= {SETTLE_S} s"
    )
    print(
        "| tile | strength | success | distance | vx after 1 s [m/s] | motor at its limit (0 / 1 / 2) "
        "| servo error RMS [mrad] | IK-clamped legs |"
    )
    print("|---|---:|---:|---:|---:|---|---:|---:|")
    for s in STRENGTHS:
        t0 = time.monotonic()
        over = [*OTHER_RANGES_NOMINAL, f"randomization.motor_strength={s},{s}"]
        cfg = tiles_env_config(apply_overrides(with_added_keys(env_cfg), over, prefix="env."))
        env = LocomotionEnv(cfg)
        spec = env.tiles
        limit = s * jnp.asarray(env.sys.actuator_forcerange[:, 1])  # the strength scales the force range
        motor_qpos = jnp.asarray(env._motor_qpos)

        def record(before, after, alive, limit=limit, motor_qpos=motor_qpos):
            d = after.pipeline_state
            return {
                "alive": alive,
                "vx": after.metrics["forward_speed"],
                "ik": after.metrics["ik_invalid_legs"],
                "sat": jnp.abs(d.actuator_force) >= SATURATED * limit,
                "lag": d.ctrl - d.qpos[:, motor_qpos],
            }

        type_idx = np.repeat([spec.types.index(t) for t, _ in TILES], PER_TILE)
        level_idx = np.repeat([lv for _, lv in TILES], PER_TILE)
        n_steps = int(round(SECONDS / env.ctrl_dt))
        out = run_trials(env, cfg, policy, type_idx, level_idx, COMMAND, n_steps, SEED, record)
        fell, progress, trace = out["fell"], out["progress"], out["record"]
        late = (np.arange(n_steps)[:, None] * env.ctrl_dt >= SETTLE_S) & trace["alive"]
        commanded = COMMAND[0] * SECONDS
        for t, lv in TILES:
            i = (type_idx == spec.types.index(t)) & (level_idx == lv)
            keep = late[:, i]
            success = ~fell[i] & (progress[i] >= SUCCESS_SHARE * commanded)
            sat = trace["sat"][:, i].reshape(n_steps, i.sum(), 4, 3)[keep]  # (K, 4 legs, 3 motors)
            print(
                f"| {t} {lv} | {s:.1f} | {100 * success.mean():.0f} % | {progress[i].mean() / commanded:.2f} "
                f"| {trace['vx'][:, i][keep].mean():.3f} "
                f"| {' / '.join(f'{100 * v:.1f} %' for v in sat.mean(axis=(0, 1)))} "
                f"| {1e3 * np.sqrt(np.mean(trace['lag'][:, i][keep] ** 2)):.0f} "
                f"| {100 * trace['ik'][:, i][keep].mean() / 4:.1f} % |",
                flush=True,
            )
        print(f"[strength {s}: {time.monotonic() - t0:.0f} s]", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "results/tiles_swing_h200")
