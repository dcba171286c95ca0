"""Time to a walking policy: runs the main job as a user does and prints, from one run, the time to
the first evaluation, the time until the evaluated forward speed first reaches a target, and the
total wall-clock, start of the process to its end.

    python benchmarks/time_to_policy.py --name default --out results.json
    python benchmarks/time_to_policy.py --name fast --out results.json -- --ppo.num_minibatches=8

Everything after `--` goes to the train command (`quadson-train`, run as `python -m
quadson_mjx.cli.train`). The clock starts before the training process is launched (imports, compilation and evaluations included) and the evaluation times are the
log times of `/train/metrics` in the run's train.mcap. `--compile-cache DIR` is passed through,
so two invocations with the same DIR measure a first and a second run. Results are appended to
--out (JSON list), so one file collects the configurations of one session. `--keep-run DIR` trains
into DIR (a new directory) and keeps it, with its log beside it as DIR.log: the timed run's policy
can then be evaluated like any other (docs/results.md, "The main job").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from quadson_mjx.mcap_check import recover_messages

ROOT = Path(__file__).resolve().parents[1]


def evaluations(run_dir: Path) -> list[dict]:
    """(log time [ns], step, forward speed, reward) of every logged evaluation, in order."""
    out = []
    for topic, log_time, msg in recover_messages(run_dir / "train.mcap"):
        if topic == "/train/metrics":
            ev = msg.get("eval", {})
            out.append(
                {
                    "t_ns": log_time,
                    "step": msg.get("progress", {}).get("step"),
                    "speed": ev.get("mean_forward_speed"),
                    "reward": ev.get("episode_reward"),
                    "sps": msg.get("progress", {}).get("env_steps_per_s"),  # wall clock, evaluations included
                    "train_sps": msg.get("training", {}).get("sps"),  # brax's: the training epoch alone
                    "eval_s": ev.get("epoch_eval_time"),  # this evaluation's wall time [s]
                }
            )
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    train_args = argv[argv.index("--") + 1 :] if "--" in argv else []
    own = argv[: argv.index("--")] if "--" in argv else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--name", required=True, help="label of this configuration in --out")
    p.add_argument("--target-speed", type=float, default=0.45, help="m/s")
    p.add_argument("--out", default=None, help="JSON list to append the result to")
    p.add_argument("--log", default=None, help="file for the training process's output")
    p.add_argument(
        "--keep-run",
        default=None,
        help="run directory to train into and keep (its checkpoint for an evaluation); must not exist",
    )
    args = p.parse_args(own)

    if args.keep_run is not None and Path(args.keep_run).exists():
        p.error(f"--keep-run {args.keep_run} exists: give a new directory")
    run_dir = Path(args.keep_run or Path(tempfile.mkdtemp(prefix="time_to_policy_")) / "run")
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "quadson_mjx.cli.train", "--run-dir", str(run_dir), *train_args]
    t0_ns = time.time_ns()
    log_path = args.log or (f"{run_dir}.log" if args.keep_run else run_dir.parent / "train.log")
    with open(log_path, "w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    total_s = (time.time_ns() - t0_ns) / 1e9
    evals = evaluations(run_dir) if (run_dir / "train.mcap").exists() else []
    for e in evals:
        e["t_s"] = round((e.pop("t_ns") - t0_ns) / 1e9, 1)
    reached = next((e for e in evals if (e["speed"] or 0.0) >= args.target_speed), None)
    result = {
        "name": args.name,
        "train_args": train_args,
        "returncode": rc,
        "total_s": round(total_s, 1),
        "first_eval_s": evals[0]["t_s"] if evals else None,
        f"time_to_{args.target_speed}_mps_s": reached["t_s"] if reached else None,
        "steps_to_target": reached["step"] if reached else None,
        "final_speed": evals[-1]["speed"] if evals else None,
        "final_reward": evals[-1]["reward"] if evals else None,
        "evaluations": evals,
    }
    print(json.dumps({k: v for k, v in result.items() if k != "evaluations"}), flush=True)
    for e in evals:
        print(f"  {e['t_s']:7.1f} s  step {e['step']:>11,}  speed {e['speed']}  reward {e['reward']}")
    if args.out:
        path = Path(args.out)
        done = json.loads(path.read_text()) if path.exists() else []
        path.write_text(json.dumps([*done, result], indent=1))
    return rc


if __name__ == "__main__":
    sys.exit(main())
