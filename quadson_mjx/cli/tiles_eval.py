"""A trained policy on the tiled ground, per tile type and level (quadson_mjx.tiles_eval).

    quadson-tiles-eval --run runs/tiles --levels 0 4 6 7 9 --envs 64 --seconds 3 --vx 0.3 \\
        --json results/tiles/eval.json

Every robot starts at its tile's centre with a random heading and holds the forward command vx for
the trial: up the `_up` pyramids, down the `_down` ones. Success: no fall and at least 80 % of the
commanded distance. Prints one row per tile, its success rate with the rate's 95 % interval (Wilson:
with 32 robots, 50 % is anything from 34 to 66 %); --json writes them with the command line.

The trials run in the policy's own env config (its sensor errors, randomization and pushes);
`--env.KEY=VALUE` changes the conditions of the evaluation, and only those (cli.conditions: the
sensor model, noise, randomization ranges, pushes, the MJX implementation, the physics timestep),
e.g. `--env.sensor.imu_tilt_rad=0.01`: the robot's IMU calibrated on a level floor (deploy_imu)
instead of mounted within 2 degrees. Keys that would change what the policy observes or does are refused.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadson_mjx.cli.conditions import condition_overrides, conditions_config
from quadson_mjx.errors import UsageError, check_run_dir, check_writable, one_line_errors, write_text_atomic

MAX_SECONDS = 60.0


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, help="training run directory")
    p.add_argument("--levels", type=int, nargs="+", default=[0, 4, 6, 7, 9])
    p.add_argument("--types", default=None, help="comma-separated tile types (default: all)")
    p.add_argument("--envs", type=int, default=64, help="robots per tile")
    p.add_argument(
        "--seconds", type=float, default=3.0, help="trial length [s] (a 2 m tile: <= 3 s at 0.3 m/s)"
    )
    p.add_argument("--vx", type=float, default=0.3, help="forward command [m/s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--nominal",
        action="store_true",
        help="the nominal model without pushes (default: the run's randomization and pushes)",
    )
    p.add_argument("--json", default=None)
    args, rest = p.parse_known_args(argv)
    args.env_overrides = condition_overrides(rest)
    return args


@one_line_errors
def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse(argv)
    check_run_dir(args.run)
    if not 1.0 < args.seconds <= MAX_SECONDS:
        raise UsageError(f"--seconds {args.seconds}: give a trial length in (1, {MAX_SECONDS:g}] s")
    if args.envs < 1:
        raise UsageError(f"--envs {args.envs}: need at least 1")
    if not 0.0 <= args.vx <= 1.0:
        raise UsageError(f"--vx {args.vx}: a forward command in [0, 1] m/s")
    if args.json:
        check_writable(args.json, "--json")
    from quadson_mjx.tiles_eval import evaluate_tiles
    from quadson_mjx.training import load_policy

    policy, env_cfg, _, _ = load_policy(Path(args.run))
    if args.env_overrides:
        env_cfg = conditions_config(env_cfg, args.env_overrides)
    types = None if args.types is None else [t.strip() for t in args.types.split(",")]
    try:
        rows = evaluate_tiles(
            env_cfg, policy, args.levels, args.envs, args.seconds, (args.vx, 0.0, 0.0), args.seed, types,
            nominal=args.nominal,
        )  # fmt: skip
    except ValueError as e:
        raise UsageError(str(e)) from None
    print(
        f"{'type':12s} {'level':>5s} {'size':>9s} {'success':>8s} {'95 %':>9s} {'falls':>9s} {'dist':>5s} {'vx':>6s} {'vy':>6s} {'yaw':>6s}"
    )
    for r in rows:
        size = (
            f"{r['slope_deg']:.0f} deg" if "slope_deg" in r
            else f"{100 * r['step_m']:.1f} cm" if "step_m" in r
            else f"{100 * r['height_m']:.1f} cm" if "height_m" in r
            else "-"
        )  # fmt: skip
        print(
            f"{r['type']:12s} {r['level']:5d} {size:>9s} {100 * r['success']:7.1f}%"
            f" {100 * r['success_95'][0]:3.0f}-{100 * r['success_95'][1]:3.0f}% {r['falls']:4d}/{r['robots']:<4d}"
            f" {r['distance_share']:5.2f} {r['rms_vx']:6.3f} {r['rms_vy']:6.3f} {r['rms_yaw_rate']:6.3f}"
        )
    if args.json:
        write_text_atomic(args.json, json.dumps({"argv": argv, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
