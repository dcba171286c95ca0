"""The training physics at coarser steps: is a policy's closed chain still closed, and does it walk?

    python benchmarks/physics_step_check.py [--run RUN] [--dt 0.002 0.004 0.005] [--every 5]
        [--seconds 6]

Runs a committed policy in its own training environment (MJX, the stones, one randomized model per
environment, sensor errors and pushes as its config has them) at each physics step given, under
every `--every`-th command of the joystick sweep (15 of its 75 by default), one environment each.
Prints one JSON line per step:
- the five-bar closure gap over every leg and control step: median, 99th percentile and largest [mm];
- control steps with the base below the ground, non-finite resets, environments that fell;
- RMS tracking error vx / vy [m/s] and yaw rate [rad/s] after the first second.
A first stage trained at a coarser step is only worth its speed if the chain stays closed there; the
tracking tells how far the policy's own step is from the tried one. Runs on the CPU in minutes.
"""

from __future__ import annotations

import json
import sys

import jax
import numpy as np

from quadson_mjx import rollout as R
from quadson_mjx.commands import sweep_commands
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.errors import ArgumentParser, UsageError, one_line_errors
from quadson_mjx.policy_eval import eval_config, load_source, tracking_sums


def check(policy, env_cfg, sim_dt: float, commands: np.ndarray, seconds: float, seed: int) -> dict:
    try:
        env = LocomotionEnv(eval_config(env_cfg, "rough", [f"sim_dt={sim_dt}"]))
    except ValueError as e:  # a step that does not divide the control step, or out of range
        raise UsageError(f"--dt {sim_dt}: {e}") from None
    gaps, below, nan = [], 0, 0
    fell = np.zeros(len(commands), bool)
    sq, kept = np.zeros(3), 0
    for _, traj in R.run(
        env,
        R.policy_controller(policy),
        jax.random.PRNGKey(seed),
        len(commands),
        int(round(seconds / env.ctrl_dt)),
        segment_steps=150,
        command=commands,
        randomize=bool(env.config.randomize),
    ):
        gaps.append(traj.closure_residual.reshape(-1))
        below += int(traj.base_below_terrain.sum())
        nan += int(traj.nan_reset.sum())
        fell |= traj.fall.any(axis=0)
        sq_seg, kept_seg = tracking_sums(traj, env.ctrl_dt)
        sq += sq_seg.sum(axis=0)
        kept += int(kept_seg.sum())
    gap_mm = np.concatenate(gaps) * 1e3
    rms = np.sqrt(sq / max(kept, 1))
    return {
        "sim_dt": sim_dt,
        "substeps": int(round(env.ctrl_dt / sim_dt)),
        "closure_gap_mm": {
            "median": round(float(np.median(gap_mm)), 3),
            "p99": round(float(np.percentile(gap_mm, 99)), 3),
            "max": round(float(gap_mm.max()), 3),
        },
        "base_below_ground_steps": below,
        "nonfinite_resets": nan,
        "fell": int(fell.sum()),
        "envs": len(commands),
        "rms_vx_vy_yaw": [round(float(v), 4) for v in rms],
    }


@one_line_errors
def main(argv=None) -> int:
    p = ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default="results/policy_h200_sensors_e16u10", help="a committed run directory")
    p.add_argument(
        "--dt", type=float, nargs="+", default=[0.002, 0.004, 0.005, 0.02 / 3], help="physics steps [s]"
    )
    p.add_argument("--every", type=int, default=5, help="every Nth of the sweep's 75 commands")
    p.add_argument("--seconds", type=float, default=6.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.every < 1:
        raise UsageError(f"--every is {args.every}; it must be 1 or more")
    policy, env_cfg, _, _ = load_source(args.run)
    commands = sweep_commands()[:: args.every].astype(np.float32)
    print(
        json.dumps(
            {
                "run": args.run,
                "envs": len(commands),
                "seconds": args.seconds,
                "device": jax.devices()[0].device_kind,
            }
        )
    )
    for dt in args.dt:
        print(json.dumps(check(policy, env_cfg, dt, commands, args.seconds, args.seed)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
