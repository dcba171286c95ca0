"""Compare controllers from rollout MCAP files: markdown tables (seed 000 and seed 003 metrics) and PNGs.

    quadson-report runs/compare/*.mcap --out-dir runs/compare
(`python eval/report.py ...` runs the same command.)

Writes OUT_DIR/report.md (seed 000 and seed 003 tables, command tracking: RMS error per axis, falls,
time the base spent in the ground; per commanded value for the command sweep), OUT_DIR/report.json and, when matplotlib is installed (the `report` extra),
OUT_DIR/<terrain>_<task>.png: base velocity (vx, or yaw rate when turning), roll and pitch over time of
environment 0 of every controller. Metrics: quadson_mjx.report. Files come from eval/rollout.py
(`--suite` writes the whole comparison set).

A bad input (a missing file or a folder, a file that is not a rollout MCAP, a window that is not a
positive finite number of seconds) exits with status 2 and one line on stderr, before anything is
written; the tables and plots are written whole or not at all (errors.atomic_write).
"""

from __future__ import annotations

import sys
from pathlib import Path

from quadson_mjx import errors
from quadson_mjx import report as R


def plot(trials, out_dir: Path) -> list[Path]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install -e '.[report]'): PNG plots skipped")
        return []
    written = []
    groups: dict[tuple[str, str], list] = {}
    for t in trials:
        if t.task != "sweep":  # one command per env: its tables are in report.md
            groups.setdefault((t.ground, t.task), []).append(t)
    for (terrain, task), group in sorted(groups.items()):
        fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
        speed_key, speed_label = ("wz", "yaw rate [rad/s]") if task == "turn" else ("vx", "vx [m/s]")
        for t in sorted(group, key=lambda t: t.controller):
            n = R.first_episode_lengths(t.done)[0]
            time_s = (1 + R.np.arange(n)) * t.ctrl_dt
            for ax, key in zip(axes, (speed_key, "roll", "pitch"), strict=True):
                ax.plot(time_s, t.base[key][0, :n], label=t.controller)
        target = group[0].command[2] if task == "turn" else group[0].command[0]
        axes[0].axhline(target, color="k", lw=0.8, ls="--", label="command")
        for ax, label in zip(axes, (speed_label, "roll [rad]", "pitch [rad]"), strict=True):
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        axes[0].legend(loc="best", fontsize=8)
        axes[-1].set_xlabel("time [s] (env 0, until its first fall)")
        fig.suptitle(f"{terrain} ground, {task}")
        fig.tight_layout()
        path = out_dir / f"{terrain.replace(', ', '_')}_{task}.png"
        with errors.atomic_write(path, "wb") as f:
            fig.savefig(f, format="png", dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def check_args(args) -> None:
    """UsageError for a window that is not a positive finite number of seconds (a negative one gave
    tables of NaN), a settle time below 0, and an input that is missing or a folder."""
    errors.check_number("--window-s", args.window_s, 0.0, above=True)
    errors.check_number("--settle-s", args.settle_s, 0.0)
    errors.check_number("--avg-s", args.avg_s, 0.0, above=True)
    for f in args.files:
        errors.check_readable(f, "rollout file")


def make_out_dir(out_dir: Path) -> None:
    """Create --out-dir (and its parents); UsageError where it cannot be made or written."""
    errors.make_folder(out_dir, "--out-dir")
    errors.check_writable(out_dir / "report.md", "--out-dir")


@errors.one_line_errors
def main(argv=None) -> int:
    p = errors.ArgumentParser(prog="quadson-report", description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+")
    p.add_argument("--out-dir", default="runs/compare")
    p.add_argument("--window-s", type=float, default=3.0, help="seed 000 trial length [s]")
    p.add_argument(
        "--settle-s", type=float, default=1.0, help="tracking errors skip each episode's start [s]"
    )
    p.add_argument("--avg-s", type=float, default=0.8, help="moving mean of the averaged tracking error [s]")
    args = p.parse_args(argv)
    check_args(args)
    out_dir = Path(args.out_dir)
    trials = [R.load_trial(f) for f in args.files]  # every file read before anything is written
    make_out_dir(out_dir)
    md = R.markdown(trials, args.window_s, args.settle_s, args.avg_s)
    errors.write_text_atomic(out_dir / "report.md", md)
    errors.write_text_atomic(out_dir / "report.json", R.summary_json(trials, args.window_s))
    pngs = plot(trials, out_dir)
    print(md)
    print(f"wrote {out_dir / 'report.md'}, {out_dir / 'report.json'}" + "".join(f", {p}" for p in pngs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
