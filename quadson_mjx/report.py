"""Controller comparison from rollout MCAP files (quadson_mjx.foxglove_mcap): the seeds' metrics.

Each file is one trial set: a controller on a terrain under one command, B environments = B
episodes. Only each environment's first episode counts (up to its first fall, which is reported).

  * seed 000 (section 8 evaluation): over the first `window_s` (3 s) of the trial, mean and standard
    deviation of the base's forward velocity vx and vertical velocity vz [m/s] (base frame) and of
    roll and pitch [rad], pooled over every step of every environment.
  * seed 003 (Tables II and III): per episode the mean speed (world displacement along the start
    heading / time) [m/s] or mean yaw rate (unwrapped yaw change / time) [rad/s] against the command,
    and roll and pitch oscillation as max - min [rad]; then mean and standard deviation over episodes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quadson_mjx import mcap_check

BASE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "wx", "wy", "wz")


@dataclass
class Trial:
    """The /rollout/step base states of one file: arrays (n_envs, n_steps)."""

    path: str
    controller: str
    terrain: str
    command: tuple[float, float, float]
    ctrl_dt: float
    base: dict[str, np.ndarray] = field(default_factory=dict)
    done: np.ndarray | None = None
    complete: bool = True

    @property
    def task(self) -> str:
        vx, vy, wz = self.command
        return "turn" if abs(wz) > 0 and math.hypot(vx, vy) < 1e-9 else "forward"

    @property
    def label(self) -> str:
        return f"{self.controller} / {self.terrain} / {self.task}"


def load_trial(path: str | Path) -> Trial:
    """Reads a rollout file (a truncated one up to its last flush) into a Trial."""
    rollout = _metadata(path).get("rollout", {})
    steps: dict[int, list] = {}

    def sink(schema, channel, message):
        if channel.topic == "/rollout/step":
            m = json.loads(message.data)
            steps.setdefault(int(m["env"]), []).append(m)

    report = mcap_check.check(path, sink)
    if not steps:
        raise ValueError(f"{path}: no /rollout/step messages")
    n = min(len(v) for v in steps.values())
    envs = sorted(steps)
    base = {k: np.array([[_num(s["base"][k]) for s in steps[e][:n]] for e in envs]) for k in BASE_KEYS}
    done = np.array([[bool(s["done"]) for s in steps[e][:n]] for e in envs])
    first = steps[envs[0]][0]["command"]
    command = (float(first["vx"]), float(first["vy"]), float(first["yaw_rate"]))
    controller = rollout.get("controller", "?")
    if controller == "policy" and rollout.get("run_dir"):  # several policies: name each by its run
        controller = f"policy ({Path(rollout['run_dir']).name})"
    return Trial(
        path=str(path),
        controller=controller,
        terrain=rollout.get("terrain", "?"),
        command=command,
        ctrl_dt=float(rollout.get("ctrl_dt_s", 0.02)),
        base=base,
        done=done,
        complete=report.complete,
    )


def _metadata(path) -> dict[str, dict]:
    """Metadata records by name, read front to back (works for a truncated file too)."""
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    out = {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Metadata):
                    out[record.name] = dict(record.metadata)
        except Exception:  # noqa: BLE001 - a truncated file ends in a damaged record
            pass
    return out


def _num(v) -> float:
    return float("nan") if v is None else float(v)


def first_episode_lengths(done: np.ndarray) -> np.ndarray:
    """(B, T) done flags -> (B,) steps of each env's first episode (T when it never ended)."""
    T = done.shape[1]
    return np.array([int(np.argmax(d)) + 1 if d.any() else T for d in done])


def seed000_stats(trial: Trial, window_s: float = 3.0) -> dict:
    """Mean and std over the first window_s of vx, vz [m/s], roll, pitch [rad]; falls in the window."""
    n_win = max(1, int(round(window_s / trial.ctrl_dt)))
    lengths = np.minimum(first_episode_lengths(trial.done), n_win)
    out = {"window_s": min(window_s, trial.done.shape[1] * trial.ctrl_dt)}
    for k in ("vx", "vz", "roll", "pitch"):
        vals = np.concatenate([trial.base[k][i, : lengths[i]] for i in range(len(lengths))])
        out[k] = (float(np.nanmean(vals)), float(np.nanstd(vals)))
    fell = trial.done.any(axis=1) & (first_episode_lengths(trial.done) <= n_win)
    out["falls"] = int(np.sum(fell))
    out["episodes"] = len(lengths)
    return out


def seed003_stats(trial: Trial) -> dict:
    """Per-episode speed or yaw rate and roll/pitch max - min; mean and std over episodes."""
    lengths = first_episode_lengths(trial.done)
    speed, yaw_rate, d_roll, d_pitch = [], [], [], []
    for i, n in enumerate(lengths):
        if n < 2:
            continue
        b = {k: v[i, :n] for k, v in trial.base.items()}
        heading = b["yaw"][0]
        dx, dy = b["x"][-1] - b["x"][0], b["y"][-1] - b["y"][0]
        duration = (n - 1) * trial.ctrl_dt
        speed.append((dx * math.cos(heading) + dy * math.sin(heading)) / duration)
        yaw_rate.append((np.unwrap(b["yaw"])[-1] - b["yaw"][0]) / duration)
        d_roll.append(np.nanmax(b["roll"]) - np.nanmin(b["roll"]))
        d_pitch.append(np.nanmax(b["pitch"]) - np.nanmin(b["pitch"]))

    def ms(x):
        return (float(np.mean(x)), float(np.std(x))) if x else (float("nan"), float("nan"))

    fell = trial.done[np.arange(len(lengths)), lengths - 1]
    return {
        "speed": ms(speed),
        "yaw_rate": ms(yaw_rate),
        "d_roll": ms(d_roll),
        "d_pitch": ms(d_pitch),
        "episodes": len(lengths),
        "falls": int(np.sum(fell)),
        "mean_episode_s": float(np.mean(lengths) * trial.ctrl_dt),
    }


def _pm(v, digits=3) -> str:
    m, s = v
    return "n/a" if not math.isfinite(m) else f"{m:.{digits}f} ± {s:.{digits}f}"


def _pm_deg(v) -> str:
    m, s = v
    if not math.isfinite(m):
        return "n/a"
    return f"{m:.3f} ± {s:.3f} ({math.degrees(m):.1f}° ± {math.degrees(s):.1f}°)"


def markdown(trials: list[Trial], window_s: float = 3.0) -> str:
    """The two comparison tables as markdown."""
    trials = sorted(trials, key=lambda t: (t.task, t.terrain, t.controller))
    lines = [
        f"## Seed 000 metrics: first {window_s:g} s of each episode (mean ± std over all steps)",
        "",
        "| controller | terrain | task | command (vx, vy, yaw rate) | vx [m/s] | vz [m/s] | roll [rad] | pitch [rad] | falls in window |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in trials:
        s = seed000_stats(t, window_s)
        cmd = ", ".join(f"{c:g}" for c in t.command)
        lines.append(
            f"| {t.controller} | {t.terrain} | {t.task} | ({cmd}) | {_pm(s['vx'])} | {_pm(s['vz'])} | "
            f"{_pm(s['roll'])} | {_pm(s['pitch'])} | {s['falls']}/{s['episodes']} |"
        )
    lines += [
        "",
        "## Seed 003 metrics: per episode, then mean ± std over episodes (first episode of each env)",
        "",
        "| controller | terrain | task | command | speed [m/s] | yaw rate [rad/s] | Δroll max-min [rad] | Δpitch max-min [rad] | falls | mean episode [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in trials:
        s = seed003_stats(t)
        target = f"{t.command[2]:g} rad/s" if t.task == "turn" else f"{t.command[0]:g} m/s"
        lines.append(
            f"| {t.controller} | {t.terrain} | {t.task} | {target} | {_pm(s['speed'])} | {_pm(s['yaw_rate'])} | "
            f"{_pm_deg(s['d_roll'])} | {_pm_deg(s['d_pitch'])} | {s['falls']}/{s['episodes']} | "
            f"{s['mean_episode_s']:.2f} |"
        )
    incomplete = [t.path for t in trials if not t.complete]
    if incomplete:
        lines += ["", f"Truncated files (read up to their last flush): {', '.join(incomplete)}"]
    return "\n".join(lines) + "\n"


def summary_json(trials: list[Trial], window_s: float = 3.0) -> str:
    return json.dumps(
        [
            {
                "path": t.path,
                "controller": t.controller,
                "terrain": t.terrain,
                "task": t.task,
                "command": t.command,
                "seed000": seed000_stats(t, window_s),
                "seed003": seed003_stats(t),
            }
            for t in trials
        ],
        indent=2,
    ).replace("NaN", "null")
