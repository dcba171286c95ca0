"""Seed 003's experiments (Tables I, II, III) on the Caramel model in CPU MuJoCo, next to the paper.

    quadson-seed003                       # 30 / 10 / 10 samples, as the paper
    quadson-seed003 --samples-1 5 --samples-23 2 --json runs/caramel_seed003.json
    quadson-seed003 --run results/caramel/policy   # + rows of a trained policy
(`python eval/caramel_seed003.py ...` runs the same command.)

Writes a JSON of the measured and published numbers and prints markdown tables (mean +- sample std).
The experiments themselves are quadson_mjx.seed003. A bad input (fewer than one sample, a time limit
that is not a positive finite number of seconds or above MAX_TIME_S, a --json path in a missing or
read-only folder, a run directory that does not load) exits with status 2 and one line on stderr,
before any sample runs; --json is written whole or not at all.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from quadson_mjx import errors
from quadson_mjx import seed003 as E

MAX_TIME_S = 3600.0  # one walk's time limit at most [s] (the paper's walks take under 90 s)


def _cell(pair, scale=1.0, digits=3) -> str:
    m, s = pair
    return f"{m * scale:.{digits}f} ± {s * scale:.{digits}f}"


def _paper(row, key, scale, digits) -> str:
    return _cell(row[key], scale, digits) if row else "—"


def _walk_table(label: str, speed, rows: dict, policy_rows: dict, paper_rows: dict) -> list[str]:
    """Lines of Table II or III: speed = (key, scale, digits of ours, digits of the paper's)."""
    key, scale, digits, paper_digits = speed
    lines = [f"| test | {label} sim | paper | Δroll [deg] sim | paper | Δpitch [deg] sim | paper | fell |"]
    lines += ["|---|---|---|---|---|---|---|---|"]
    for name, r in {**rows, **policy_rows}.items():
        paper = paper_rows.get(name)
        lines.append(
            f"| {name} | {_cell(r[key], scale, digits)} | {_paper(paper, key, scale, paper_digits)} "
            f"| {_cell(r['roll_deg'], 1, 2)} | {_paper(paper, 'roll_deg', 1, 2)} "
            f"| {_cell(r['pitch_deg'], 1, 2)} | {_paper(paper, 'pitch_deg', 1, 2)} | {r['fell']}/{r['n']} |"
        )
    return lines


def markdown(result: dict) -> str:
    """Markdown tables of a result dict (see main), measured next to published."""
    lines = ["Table I (single leg in the air, cycloid H 5 cm, T 0.5 s, 25 points, P_T = P_N = 1)", ""]
    lines += ["| quantity | Test 1 sim | Test 1 paper | Test 2 sim | Test 2 paper |", "|---|---|---|---|---|"]
    t1 = result["table_1"]
    rows = [("time [s]", "time_s", 1.0, 3), ("apex [cm]", "apex_m", 100, 3)]
    rows += [("final x [cm]", "final_x_m", 100, 3), ("final y [cm]", "final_y_m", 100, 3)]
    for label, key, sc, dg in rows:
        cells = []
        for test in ("test1", "test2"):
            cells += [_cell(t1[test][key], sc, dg), _cell(E.PAPER_TABLE_1[test][key], sc, dg)]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    policy = result.get("policy") or {"table_2": {}, "table_3": {}}
    lines += ["", "Table II (trot forward 0.05 m/s; H 5 cm, T 0.5 s, P_T 0.66, P_N 0.33)", ""]
    lines += _walk_table(
        "velocity [cm/s]", ("velocity_mps", 100, 2, 3), result["table_2"], policy["table_2"], E.PAPER_TABLE_2
    )
    lines += ["", "Table III (turn in place 0.25 rad/s, rough ground)", ""]
    lines += _walk_table(
        "yaw rate [rad/s]", ("yaw_rate_radps", 1, 3, 3), result["table_3"], policy["table_3"], E.PAPER_TABLE_3
    )
    return "\n".join(lines)


def run(argv=None) -> dict:
    """The command line `argv` run: -> the result dict that --json writes."""
    ap = errors.ArgumentParser(
        prog="quadson-seed003", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--samples-1", type=int, default=30, help="samples per test of Table I")
    ap.add_argument("--samples-23", type=int, default=10, help="samples per test of Tables II and III")
    ap.add_argument("--max-time-s", type=float, default=90.0, help="time limit of one walk [s]")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--run", type=Path, default=None, help="a Caramel training run: add its policy's rows")
    args = ap.parse_args(argv)
    for flag, n in (("--samples-1", args.samples_1), ("--samples-23", args.samples_23)):
        if n < 1:  # 0 samples gave tables of NaN
            raise errors.UsageError(f"{flag} {n}: need at least 1 sample (the paper: 30 and 10)")
    errors.check_number("--max-time-s", args.max_time_s, 0.0, MAX_TIME_S, above=True)
    if args.json is not None:
        errors.check_writable(args.json, "--json")
    t0 = time.time()
    policy = None
    if args.run is not None:
        try:
            policy = E.policy_driver(args.run)
        except (ValueError, OSError) as e:
            ap.error(f"--run {args.run}: {e}")
    result = {
        "table_1": E.table_1(args.samples_1),
        "table_2": E.table_2(args.samples_23, max_time_s=args.max_time_s),
        "table_3": E.table_3(args.samples_23, max_time_s=args.max_time_s),
        "policy": E.policy_rows(policy, args.samples_23, max_time_s=args.max_time_s) if policy else None,
        "run": str(args.run) if args.run else None,
        "paper": {"table_1": E.PAPER_TABLE_1, "table_2": E.PAPER_TABLE_2, "table_3": E.PAPER_TABLE_3},
        "command": "python eval/caramel_seed003.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    result["wall_s"] = time.time() - t0
    print(markdown(result))
    print(f"\n{result['wall_s']:.0f} s")
    if args.json is not None:
        errors.write_text_atomic(args.json, json.dumps(result, indent=2))
    return result


@errors.one_line_errors
def main(argv=None) -> int:
    run(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
