"""Compare trained policies on the joystick command sweep in MJX: RMS tracking errors and falls.

    quadson-policy-eval --policy results/policy_h100_joystick:true --policy runs/new \\
        --terrain flat rough --seconds 20 --replicas 4 --out results/joystick_eval.json

Each --policy is RUN_DIR[:VELOCITY_SOURCE] or RUN_DIR/checkpoints/step_N.msgpack[:VELOCITY_SOURCE]
(that checkpoint instead of the newest: the curve of a run trained with --ppo.run_evals=false); the
source (true, zero, command) replaces a true_state policy's base-velocity input
(quadson_mjx.policy_eval). Every policy sees the same commands (the
sweep of quadson-rollout, 75 commands, each `--replicas` times), seeds and randomized models, in
each run's own env config; `--env.KEY=VALUE` changes the evaluation's conditions for all of them,
and only those (quadson_mjx.cli.conditions: sensor model, noise, randomization, pushes, the MJX
implementation, the physics timestep), e.g. `--env.sensor.imu_tilt_rad=0.01` for a calibrated IMU.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadson_mjx.cli.conditions import condition_overrides, conditions_config
from quadson_mjx.errors import UsageError, check_writable, one_line_errors, write_text_atomic

MAX_SECONDS = 600.0  # a trial longer than this is a typo, not an evaluation


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--policy",
        action="append",
        required=True,
        help="RUN_DIR or RUN_DIR/checkpoints/step_N.msgpack, then [:true|zero|command]",
    )
    p.add_argument("--terrain", nargs="+", default=["flat", "rough"], choices=["flat", "rough"])
    p.add_argument("--seconds", type=float, default=20.0, help="trial length [s]")
    p.add_argument("--replicas", type=int, default=4, help="environments per command of the sweep")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="JSON file of the rows")
    args, rest = p.parse_known_args(argv)
    args.env_overrides = condition_overrides(rest)
    return args


def policies(args) -> list[tuple[str, str]]:
    from quadson_mjx.policy_eval import VELOCITY_SOURCES

    out = []
    for spec in args.policy:
        run, _, source = spec.partition(":")
        source = source or "true"
        if source not in VELOCITY_SOURCES:
            raise UsageError(
                f"--policy {spec}: velocity source {source!r}; choose from {', '.join(VELOCITY_SOURCES)}"
            )
        run_dir = Path(run)
        if run_dir.is_file():  # one of a run's checkpoints
            from quadson_mjx.training import init_point

            try:
                run_dir = init_point(run_dir)[0]
            except (ValueError, OSError) as e:
                raise UsageError(f"--policy {spec}: {e}") from None
        if not (run_dir / "config.json").is_file():
            raise UsageError(f"--policy {spec}: {run_dir} is not a training run directory (no config.json)")
        if args.env_overrides:  # refused before any evaluation starts
            from quadson_mjx.training import load_run_config

            conditions_config(load_run_config(run_dir)[0], args.env_overrides)
        out.append((run, source))
    return out


@one_line_errors
def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    if not 1.0 < args.seconds <= MAX_SECONDS:
        raise UsageError(f"--seconds {args.seconds}: give a trial length in (1, {MAX_SECONDS:g}] s")
    if args.replicas < 1:
        raise UsageError(f"--replicas {args.replicas}: need at least 1")
    runs = policies(args)
    if args.out:
        check_writable(args.out, "--out")
    from quadson_mjx.commands import sweep_commands
    from quadson_mjx.policy_eval import evaluate

    rows = evaluate(
        runs, sweep_commands(), args.terrain, args.seconds, args.replicas, args.seed, args.env_overrides
    )
    print(f"{'policy':48s} {'terrain':7s} {'vx':>6s} {'vy':>6s} {'yaw':>6s} {'falls':>9s} {'edge':>5s}")
    for r in rows:
        name = f"{r['run']} ({r['observation']}, velocity {r['velocity_source']})"
        print(
            f"{name:48s} {r['terrain']:7s} {r['rms_vx']:6.3f} {r['rms_vy']:6.3f} {r['rms_yaw_rate']:6.3f}"
            f" {r['falls']:4d}/{r['envs']:<4d} {r['off_field']:5d}"
        )
    if args.out:
        write_text_atomic(
            args.out, json.dumps({"argv": sys.argv[1:] if argv is None else argv, "rows": rows}, indent=1)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
