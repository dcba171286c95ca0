"""Controller comparison from rollout MCAP files (quadson_mjx.foxglove_mcap): the seeds' metrics.

Each file is one trial set: a controller on a terrain under one command, B environments = B
episodes. Only each environment's first episode counts (up to its first fall, which is reported).

  * seed 000 (section 8 evaluation): over the first `window_s` (3 s) of the trial, mean and standard
    deviation of the base's forward velocity vx and vertical velocity vz [m/s] (base frame) and of
    roll and pitch [rad], pooled over every step of every environment.
  * seed 003 (Tables II and III): per episode the mean speed (world displacement along the start
    heading / time) [m/s] or mean yaw rate (unwrapped yaw change / time) [rad/s] against the command,
    and roll and pitch oscillation as max - min [rad]; then mean and standard deviation over episodes.
  * command tracking (the joystick policy's targets): after the first `settle_s` (1 s: the gait's
    0.5 s ramp from standing, and the start), the RMS error of vx, vy [m/s] (base frame) and yaw rate
    [rad/s] against each environment's command, pooled over every step of every episode, raw and
    averaged over one gait cycle (0.8 s moving mean: the trot's within-stride sway removed); falls
    (an episode that reached the stone field's edge is not a fall); the time the base box spent
    below the ground under it. A trial whose environments carry different commands (the command
    sweep) is also broken down per commanded vx, vy and yaw rate.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from quadson_mjx import errors, mcap_check

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
    commands: np.ndarray | None = None  # (n_envs, 3) each env's command at its first step
    fall: np.ndarray | None = None  # (n_envs, n_steps) bool; older files: done
    off_field: np.ndarray | None = None  # (n_envs, n_steps) bool
    below: np.ndarray | None = None  # (n_envs, n_steps) bool: base box below the ground
    randomized: bool = False

    def __post_init__(self):
        if self.commands is None and self.done is not None:
            self.commands = np.tile(np.asarray(self.command, float), (self.done.shape[0], 1))
        if self.fall is None and self.done is not None:
            self.fall = self.done
        for name in ("off_field", "below"):
            if getattr(self, name) is None and self.done is not None:
                setattr(self, name, np.zeros_like(self.done))

    @property
    def task(self) -> str:
        if self.commands is not None and len(np.unique(self.commands, axis=0)) > 1:
            return "sweep"
        vx, vy, wz = self.command
        return "turn" if abs(wz) > 0 and math.hypot(vx, vy) < 1e-9 else "forward"

    @property
    def ground(self) -> str:
        return f"{self.terrain}, randomized" if self.randomized else self.terrain

    @property
    def label(self) -> str:
        return f"{self.controller} / {self.ground} / {self.task}"


def load_trial(path: str | Path) -> Trial:
    """Reads a rollout file (a truncated one up to its last flush) into a Trial. Raises
    errors.UsageError for a missing file or a folder, and for a file that is not a rollout MCAP
    (not an MCAP file, or one without /rollout/step messages)."""
    errors.check_readable(path, "rollout file")
    rollout = _metadata(path).get("rollout", {})
    steps: dict[int, list] = {}

    def sink(schema, channel, message):
        if channel.topic == "/rollout/step":
            m = json.loads(message.data)
            steps.setdefault(int(m["env"]), []).append(m)

    report = mcap_check.check(path, sink)
    if not steps:
        why = report.error if report.error and not report.counts else "it has no /rollout/step messages"
        raise errors.UsageError(f"{path}: not a rollout MCAP file ({why}); quadson-rollout writes them")
    n = min(len(v) for v in steps.values())
    envs = sorted(steps)
    base = {k: np.array([[_num(s["base"][k]) for s in steps[e][:n]] for e in envs]) for k in BASE_KEYS}
    done = np.array([[bool(s["done"]) for s in steps[e][:n]] for e in envs])

    def flags(key):  # None for files written before the key existed
        if key not in steps[envs[0]][0]:
            return None
        return np.array([[bool(s[key]) for s in steps[e][:n]] for e in envs])

    commands = np.array([[_num(steps[e][0]["command"][k]) for k in ("vx", "vy", "yaw_rate")] for e in envs])
    command = tuple(float(c) for c in commands[0])
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
        commands=commands,
        fall=flags("fall"),
        off_field=flags("off_field"),
        below=flags("base_below_terrain"),
        randomized=str(rollout.get("randomize", "False")) == "True",
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
    fell = trial.fall.any(axis=1) & (first_episode_lengths(trial.done) <= n_win)
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

    fell = trial.fall[np.arange(len(lengths)), lengths - 1]
    return {
        "speed": ms(speed),
        "yaw_rate": ms(yaw_rate),
        "d_roll": ms(d_roll),
        "d_pitch": ms(d_pitch),
        "episodes": len(lengths),
        "falls": int(np.sum(fell)),
        "mean_episode_s": float(np.mean(lengths) * trial.ctrl_dt),
    }


TRACK_KEYS = (("vx", 0), ("vy", 1), ("wz", 2))  # base velocity key, command index


def _moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Mean over the last n samples (fewer at the start) of a 1-D series."""
    c = np.cumsum(np.insert(x, 0, 0.0))
    k = np.arange(1, len(x) + 1)
    lo = np.maximum(k - n, 0)
    return (c[k] - c[lo]) / (k - lo)


def tracking_errors(trial: Trial, settle_s: float = 1.0, avg_s: float = 0.8, envs=None) -> dict:
    """Command-tracking errors of each env's first episode after settle_s: -> {"vx", "vy", "wz"}:
    (raw errors, errors of the avg_s moving mean) as 1-D arrays pooled over envs; "episodes";
    "falls"; "off_field"; "below_s" (time with the base box below the ground [s], summed)."""
    lengths = first_episode_lengths(trial.done)
    envs = range(len(lengths)) if envs is None else envs
    skip = int(round(settle_s / trial.ctrl_dt))
    n_avg = max(1, int(round(avg_s / trial.ctrl_dt)))
    out = {k: ([], []) for k, _ in TRACK_KEYS}
    falls = off = 0
    below = 0.0
    for i in envs:
        n = lengths[i]
        falls += int(trial.fall[i, n - 1])
        off += int(trial.off_field[i, n - 1])
        below += float(np.sum(trial.below[i, :n])) * trial.ctrl_dt
        for k, c in TRACK_KEYS:
            v = trial.base[k][i, :n]
            out[k][0].append(v[skip:] - trial.commands[i, c])
            out[k][1].append(_moving_mean(v, n_avg)[skip:] - trial.commands[i, c])
    res = {k: tuple(np.concatenate(e) if e else np.zeros(0) for e in pair) for k, pair in out.items()}
    return {**res, "episodes": len(envs), "falls": falls, "off_field": off, "below_s": below}


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.square(e)))) if e.size else float("nan")


def tracking_stats(trial: Trial, settle_s: float = 1.0, avg_s: float = 0.8, envs=None) -> dict:
    """RMS tracking errors (raw and cycle-averaged) per axis, falls, time below ground; see
    tracking_errors."""
    e = tracking_errors(trial, settle_s, avg_s, envs)
    out = {k: _rms(e[k][0]) for k, _ in TRACK_KEYS}
    out.update({f"{k}_avg": _rms(e[k][1]) for k, _ in TRACK_KEYS})
    out.update({k: e[k] for k in ("episodes", "falls", "off_field", "below_s")})
    return out


def tracking_by_command(trial: Trial, axis: int, settle_s: float = 1.0, avg_s: float = 0.8) -> list:
    """[(commanded value on axis (0 vx, 1 vy, 2 yaw rate), tracking_stats over the envs with it)]."""
    values = np.unique(np.round(trial.commands[:, axis], 6))
    return [
        (
            float(v),
            tracking_stats(trial, settle_s, avg_s, np.flatnonzero(np.isclose(trial.commands[:, axis], v))),
        )
        for v in values
    ]


def _pm(v, digits=3) -> str:
    m, s = v
    return "n/a" if not math.isfinite(m) else f"{m:.{digits}f} ± {s:.{digits}f}"


def _pm_deg(v) -> str:
    m, s = v
    if not math.isfinite(m):
        return "n/a"
    return f"{m:.3f} ± {s:.3f} ({math.degrees(m):.1f}° ± {math.degrees(s):.1f}°)"


def _f3(v: float) -> str:
    """A number to 3 decimals, or n/a where nothing was measured (an episode shorter than settle_s)."""
    return f"{v:.3f}" if math.isfinite(v) else "n/a"


def _tracking_row(s: dict) -> str:
    return (
        f"{_f3(s['vx'])} / {_f3(s['vy'])} / {_f3(s['wz'])} | {_f3(s['vx_avg'])} / {_f3(s['vy_avg'])} / "
        f"{_f3(s['wz_avg'])} | {s['falls']}/{s['episodes']} | {s['off_field']} | {s['below_s']:.2f} |"
    )


def tracking_markdown(trials: list[Trial], settle_s: float = 1.0, avg_s: float = 0.8) -> list[str]:
    head = (
        "| controller | ground | task | RMS error vx / vy [m/s] / yaw rate [rad/s] | same, "
        f"{avg_s:g} s mean | falls | at field edge | base in ground [s] |"
    )
    lines = [
        "",
        f"## Command tracking: each episode after its first {settle_s:g} s, pooled over episodes",
        "",
        head,
        "|---|---|---|---|---|---|---|---|",
    ]
    for t in trials:
        lines.append(
            f"| {t.controller} | {t.ground} | {t.task} | " + _tracking_row(tracking_stats(t, settle_s, avg_s))
        )
    for t in (t for t in trials if t.task == "sweep"):
        for axis, name in enumerate(("vx [m/s]", "vy [m/s]", "yaw rate [rad/s]")):
            lines += [
                "",
                f"### {t.label}: per commanded {name}",
                "",
                f"| commanded {name} | RMS error vx / vy / yaw rate | same, {avg_s:g} s mean | falls | at field edge | base in ground [s] |",
                "|---|---|---|---|---|---|",
            ]
            for v, s in tracking_by_command(t, axis, settle_s, avg_s):
                lines.append(f"| {v:g} | " + _tracking_row(s))
    return lines


def markdown(trials: list[Trial], window_s: float = 3.0, settle_s: float = 1.0, avg_s: float = 0.8) -> str:
    """The comparison tables as markdown."""
    trials = sorted(trials, key=lambda t: (t.task, t.terrain, t.randomized, t.controller))
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
            f"| {t.controller} | {t.ground} | {t.task} | ({cmd}) | {_pm(s['vx'])} | {_pm(s['vz'])} | "
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
            f"| {t.controller} | {t.ground} | {t.task} | {target} | {_pm(s['speed'])} | {_pm(s['yaw_rate'])} | "
            f"{_pm_deg(s['d_roll'])} | {_pm_deg(s['d_pitch'])} | {s['falls']}/{s['episodes']} | "
            f"{s['mean_episode_s']:.2f} |"
        )
    lines += tracking_markdown(trials, settle_s, avg_s)
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
                "randomized": t.randomized,
                "seed000": seed000_stats(t, window_s),
                "seed003": seed003_stats(t),
                "tracking": tracking_stats(t),
                **(
                    {
                        "tracking_by_" + n: tracking_by_command(t, a)
                        for a, n in enumerate(("vx", "vy", "yaw_rate"))
                    }
                    if t.task == "sweep"
                    else {}
                ),
            }
            for t in trials
        ],
        indent=2,
    ).replace("NaN", "null")
