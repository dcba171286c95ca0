"""A trained get-up policy over many drops, per start class (quadson_mjx.getup_eval).

    quadson-getup-eval --run results/getup_h100 --ground flat stones --drops 512 \\
        --json results/getup_h100/eval.json

Each drop is a fresh start (on the back, a side, the belly, or tilted; motor angles uniform in the
real limits; 0.2-0.5 m up) on its own randomized model. Success: upright within 10 deg and the base
within 2 cm of the standing height, held 1 s, begun within 5 s of the drop. Prints one row per
start class and ground; --topples N adds N knock-overs from the home stance (a tipping rate about
a random horizontal axis, the run's env.getup.topple_rate_rps) as a row "toppled". The column
on_back counts the failures that end the episode on the back (tilted over 150 deg), the start the
legs cannot turn over; the share of all drops comes with its 95 % interval (Wilson's: 350 of 512,
64.2-72.2 %). --servo-speed-limit on/off evaluates with or without the servos' torque-speed
limit in the physics, whatever the run trained with. --json writes them with the command line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from quadson_mjx.config import apply_overrides
from quadson_mjx.errors import UsageError, check_run_dir, check_writable, one_line_errors, write_text_atomic
from quadson_mjx.robots.quadson.mirror import parse_mirror_to, resolve_mirror_to, trained_mirror_to

GROUND_NAMES = ("flat", "stones")
SERVO_SPEED_LIMIT = {"trained": None, "on": "true", "off": "false"}  # --servo-speed-limit -> the config value


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", required=True, help="training run directory of a get-up task")
    p.add_argument("--ground", nargs="+", default=["flat", "stones"], help="flat and/or stones")
    p.add_argument("--drops", type=int, default=512, help="drops per ground")
    p.add_argument(
        "--topples", type=int, default=0, help="also this many knock-overs from the home stance per ground"
    )
    p.add_argument(
        "--mirror-to",
        default="trained",
        help="left or right: run the policy mirrored where a start has the other side lower; none; "
        "trained (default): as the run was trained (env.getup.mirror_to)",
    )
    p.add_argument(
        "--servo-speed-limit",
        default="trained",
        help="on or off: the servos' torque-speed limit in the physics (env.getup.servo_speed_limit); "
        "trained (default): as the run was trained",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None)
    return p.parse_args(argv)


def servo_speed_limit_overrides(choice: str) -> list[str]:
    """--servo-speed-limit's env config overrides ([] for "trained"); an unknown choice is a usage error."""
    if choice not in SERVO_SPEED_LIMIT:
        raise UsageError(f"--servo-speed-limit {choice}: choose from {', '.join(SERVO_SPEED_LIMIT)}")
    value = SERVO_SPEED_LIMIT[choice]
    return [] if value is None else [f"getup.servo_speed_limit={value}"]


def with_servo_speed_limit(env_cfg, choice: str):
    """The run's env config with env.getup.servo_speed_limit as --servo-speed-limit chooses it
    ("trained": as it is)."""
    over = servo_speed_limit_overrides(choice)
    return apply_overrides(env_cfg, over, prefix="env.") if over else env_cfg


def _line(name: str, r: dict) -> str:
    return (
        f"{name:12s} {r['successes']:5d}/{r['drops']:<5d} {100 * r['success']:6.1f}%"
        f" {r['time_to_stand_median_s']:6.2f} {r['time_to_stand_p90_s']:6.2f}"
        f" {100 * r['overlap_step_share']:7.2f}% {100 * r['guarded_step_share']:7.2f}% {r['max_motor_speed_rps']:6.1f}"
        f" {r['failures_on_back']:7d}"
    )


@one_line_errors
def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse(argv)
    check_run_dir(args.run)
    bad = [g for g in args.ground if g not in GROUND_NAMES]
    if bad:
        raise UsageError(f"--ground {' '.join(bad)}: choose from {', '.join(GROUND_NAMES)}")
    if args.drops < 1:
        raise UsageError(f"--drops {args.drops}: need at least 1")
    try:
        mirror_to = parse_mirror_to(args.mirror_to)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if args.topples < 0:
        raise UsageError(f"--topples {args.topples}: 0 or more")
    servo_speed_limit_overrides(args.servo_speed_limit)  # refused before the run loads (seconds)
    if args.json:
        check_writable(args.json, "--json")
    from quadson_mjx.training import load_policy, load_run_config

    env_cfg, _ = load_run_config(Path(args.run))
    if env_cfg.get("task", "locomotion") != "getup":
        raise UsageError(
            f"--run {args.run}: trained env.task={env_cfg.get('task', 'locomotion')!r}, not getup"
        )
    try:
        resolve_mirror_to(mirror_to, trained_mirror_to(env_cfg))
    except ValueError as e:
        raise UsageError(f"--run {args.run}: {e}") from None
    from quadson_mjx.getup_eval import evaluate_getup

    policy, env_cfg, _, _ = load_policy(Path(args.run))
    env_cfg = with_servo_speed_limit(env_cfg, args.servo_speed_limit)
    out = {"argv": argv, "grounds": {}}
    for ground in args.ground:
        rows, total = evaluate_getup(env_cfg, policy, ground, args.drops, args.seed, mirror_to=mirror_to)
        out["grounds"][ground] = {"classes": rows, "total": total}
        print(f"\n{ground}: {args.drops} drops, seed {args.seed}")
        print(
            f"{'start':12s} {'stood':>11s} {'share':>7s} {'t_med':>6s} {'t_p90':>6s} {'overlap':>8s} {'guarded':>8s} {'w_max':>6s} {'on_back':>7s}"
        )
        for r in rows:
            print(_line(r["start_class"], r))
        print(_line("all", total))
        lo, hi = total["success_95"]
        print(f"all drops: {100 * total['success']:.1f} %, 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %")
        print(
            "by tilt at the drop: "
            + ", ".join(
                f"{b['start_tilt_deg'][0]:.0f}-{b['start_tilt_deg'][1]:.0f} deg {b['successes']}/{b['drops']}"
                f" ({b['failures_on_back']} on back)"
                for b in total["by_start_tilt"]
            )
        )
        if total["non_finite_resets"] or total["starts_without_valid_pose"]:
            print(
                f"non-finite resets {total['non_finite_resets']}, starts without a valid pose {total['starts_without_valid_pose']}"
            )
        if args.topples:
            rows, total = evaluate_getup(
                env_cfg, policy, ground, args.topples, args.seed, "topples", mirror_to
            )
            out["grounds"][ground]["topples"] = {"classes": rows, "total": total}
            print(_line("toppled", total))
    if args.json:
        write_text_atomic(args.json, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
