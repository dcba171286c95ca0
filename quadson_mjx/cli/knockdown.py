"""Knocked down while walking: the supervisor over a walking and a get-up policy in sim2sim's MuJoCo C
plant, over many randomized knock-downs (quadson_mjx.knockdown).

    quadson-knockdown --walk results/policy_h100_sensors --getup results/getup_h100 --trials 50 \\
        --seed 0 --terrain flat --json results/getup_h100/knockdown/flat.json
(`python eval/knockdown.py ...` runs the same command.)

--walk and --getup take a training run directory (its newest checkpoint is exported to a temporary
folder) or an exported file (*.onnx, *.npz). Each trial: walk 2 s at 0.25 m/s, a knock (--knock kick:
a random velocity kick of the base, another 1 s later while the robot still walks, 3 at most; --knock
shove: a push on the top of the base, 15 N for 0.16 s, then harder ones 1.5 s apart up to 96 N until
it falls; --knock none: no knock, walking throughout, to count false alarms, with --pushes under
the walking run's random pushes), then up to --seconds for the supervisor to get the robot up and walking, and 2 s of
walking that must stay upright (true tilt below 30 deg). Trial i is seeded by (seed, i): --first i
--trials 1 replays one. Prints one line per trial and a summary; --json writes them with the command
line, --mcap records the first trial for Foxglove and --video renders it. Bad input: one line, exit
status 2.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

from quadson_mjx.errors import (
    ArgumentParser,
    UsageError,
    check_number,
    check_readable,
    check_run_dir,
    check_writable,
    one_line_errors,
    write_text_atomic,
)
from quadson_mjx.robots.quadson.mirror import parse_mirror_to

TERRAINS = ("flat", "stones")
KNOCKS = ("kick", "shove", "none")  # quadson_mjx.knockdown.KNOCKS, without importing mujoco for --help


def parse(argv):
    p = ArgumentParser(prog="quadson-knockdown", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--walk", required=True, help="walking policy: a training run directory or an exported file"
    )
    p.add_argument(
        "--getup", required=True, help="get-up policy: a training run directory or an exported file"
    )
    p.add_argument("--trials", type=int, default=50, help="knock-downs")
    p.add_argument("--seed", type=int, default=0, help="trial i is seeded by (seed, i)")
    p.add_argument("--terrain", default="flat", help="flat or stones")
    p.add_argument("--seconds", type=float, default=10.0, help="from the kick, to be walking again [s]")
    p.add_argument("--json", default=None, help="write the summary and the trials here")
    p.add_argument("--mcap", default=None, help="record the first trial here (.mcap)")
    p.add_argument("--video", default=None, help="render the first trial here (.mp4 or .gif)")
    p.add_argument(
        "--knock", default="kick", help="kick (velocity kicks), shove (rising pushes) or none (false alarms)"
    )
    p.add_argument(
        "--pushes", action="store_true", help="the walking run's random pushes on the plant as well"
    )
    p.add_argument(
        "--mirror-to",
        default="trained",
        help="left or right: the get-up policy runs mirrored when the other side is lower; none; "
        "trained (default): as the policy was trained (env.getup.mirror_to)",
    )
    p.add_argument(
        "--supervisor",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a SupervisorConfig field other than its default, SI (rad, s); repeatable",
    )
    p.add_argument(
        "--first", type=int, default=0, help="the first trial's index (trial i is seeded by (seed, i))"
    )
    a = p.parse_args(argv)
    if a.trials < 1:
        raise UsageError(f"--trials {a.trials}: need at least 1")
    if a.first < 0:
        raise UsageError(f"--first {a.first}: a trial index is 0 or more")
    if a.knock not in KNOCKS:
        raise UsageError(f"--knock {a.knock}: choose from {', '.join(KNOCKS)}")
    if a.terrain not in TERRAINS:
        raise UsageError(f"--terrain {a.terrain}: choose from {', '.join(TERRAINS)}")
    check_number("--seconds", a.seconds, 0.5, 600.0)
    for flag in ("walk", "getup"):
        path = Path(getattr(a, flag))
        if path.is_dir():
            check_run_dir(path, f"--{flag}")
        else:
            check_readable(path, f"--{flag}")
            if path.suffix.lower() not in (".onnx", ".npz"):
                raise UsageError(
                    f"--{flag} {path}: a policy file is *.onnx or *.npz, or give a run directory"
                )
    a.supervisor_config = supervisor_config(a.supervisor)
    try:
        a.mirror_to = parse_mirror_to(a.mirror_to)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if a.json:
        check_writable(a.json, "--json")
    if a.mcap:
        check_writable(a.mcap, "--mcap")
    if a.video:
        check_writable(a.video, "--video")
        if Path(a.video).suffix.lower() not in (".mp4", ".gif"):
            raise UsageError(f"--video {a.video}: a video is *.mp4 or *.gif")
    return a


def supervisor_config(items):
    """["fall_tilt_rad=0.87", ...] -> a SupervisorConfig with those fields, or UsageError."""
    from quadson_mjx.deploy_supervisor import SupervisorConfig

    names = [f.name for f in dataclasses.fields(SupervisorConfig)]
    changes = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in names:
            raise UsageError(f"--supervisor {item}: KEY=VALUE with KEY one of {', '.join(names)}")
        try:
            changes[key] = float(value)
        except ValueError:
            raise UsageError(f"--supervisor {item}: {value!r} is not a number") from None
    try:
        return SupervisorConfig(**changes)
    except ValueError as e:
        raise UsageError(f"--supervisor: {e}") from None


def policy_file(path, flag: str, want_getup: bool, folder: Path) -> Path:
    """A run directory exported into folder (its task checked), or the file itself."""
    path = Path(path)
    if not path.is_dir():
        return path
    from quadson_mjx import export, training

    env_cfg, _ = training.load_run_config(path)
    task = env_cfg.get("task", "locomotion")
    if (task == "getup") != want_getup:
        raise UsageError(
            f"--{flag} {path}: trained env.task={task!r}, not {'getup' if want_getup else 'walking'}"
        )
    try:
        return export.export_run(path, folder / f"{flag}.onnx")
    except (ValueError, FileNotFoundError) as e:
        raise UsageError(f"--{flag} {path}: cannot export it: {e}") from e


def _line(r: dict) -> str:
    f = lambda v: "   -  " if v is None else f"{v:6.2f}"  # noqa: E731
    if not r["kicks"]:  # --knock none
        return (
            f"{r['trial']:3d} no knock | detected {'yes' if r['detected'] else ' no'} {f(r['t_detect_s'])}"
            f" | largest tilt {r['max_tilt_deg']:5.1f} deg | {'OK' if r['success'] else 'failed'}"
        )
    k = r["kicks"][-1]
    size = (
        f"{k['force_n']:5.1f} N {k['duration_s']:.2f} s"
        if "force_n" in k
        else f"{k['speed_mps']:.2f} m/s {k['rate_rps']:4.1f} rad/s"
    )
    return (
        f"{r['trial']:3d} knocks {len(r['kicks'])}, last {k['dir_deg']:5.0f} deg {size}"
        f" | detected {'yes' if r['detected'] else ' no'} {f(r['t_detect_s'])} | hold {f(r['t_standing_hold_s'])}"
        f" | walking {f(r['t_walking_s'])} | attempts {r['attempts']} | tilt at get-up"
        f" {f(r['tilt_at_getup_deg'])} final {r['final_tilt_deg']:5.1f} deg | {'OK' if r['success'] else 'failed'}"
    )


@one_line_errors
def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    a = parse(argv)
    from quadson_mjx import knockdown

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        walk = policy_file(a.walk, "walk", False, Path(tmp))
        getup = policy_file(a.getup, "getup", True, Path(tmp))
        try:
            sup, _, _ = knockdown.build(
                walk, getup, a.terrain, supervisor=a.supervisor_config, mirror_to=a.mirror_to
            )
        except (ValueError, KeyError) as e:
            raise UsageError(f"--walk {a.walk} / --getup {a.getup}: the supervisor refuses them: {e}") from e
        origin = "the start" if a.knock == "none" else "the last knock"
        trials = f"{a.trials} trials from trial {a.first}" if a.first else f"{a.trials} trials"
        side = sup.getup.mirror_to  # --mirror-to trained resolved: the side the get-up policy runs on
        print(
            f"{trials} ({a.knock}) on {a.terrain}, seed {a.seed}; get-up mirrored to {side or 'neither side'};"
            f" times [s] from {origin}",
            flush=True,
        )
        summary, rows = knockdown.run_knockdowns(
            walk, getup, a.trials, a.seed, a.terrain, a.seconds, record=a.mcap,
            progress=lambda i, r: print(_line(r), flush=True), knock=a.knock, first=a.first,
            video=a.video, pushes=a.pushes, supervisor=a.supervisor_config, mirror_to=a.mirror_to,
        )  # fmt: skip
    wall = time.perf_counter() - t0
    s = summary
    lo, hi = s["success_rate_95"]
    print(
        f"success {s['successes']}/{s['trials']} ({100 * s['success_rate']:.1f} %, 95 % interval"
        f" {100 * lo:.1f}-{100 * hi:.1f} %); falls detected {s['detected']}/{s['trials']} after {s['kicks']} knocks; walking again"
        f" {s['walking_resumed']}; median time to standing_hold {s['median_t_standing_hold_s']} s, to walking"
        f" {s['median_t_walking_s']} s; on the back when the get-up started {s['on_back_at_getup']}"
        f" ({s['successes_on_back']} stood); trials with a timeout {s['trials_with_timeout']}; targets"
        f" outside the limits or non-finite {s['bad_target_ticks']} ticks; {wall:.0f} s wall"
    )
    if a.json:
        out = {"command": "python eval/knockdown.py " + shlex.join(argv), "summary": s, "wall_s": wall}
        out |= {"settings": knockdown.settings(a.seconds, knock=a.knock, pushes=a.pushes), "trials": rows}
        out["settings"]["supervisor"] = dataclasses.asdict(a.supervisor_config)
        out["settings"]["getup_mirror_to"] = side
        write_text_atomic(a.json, json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
