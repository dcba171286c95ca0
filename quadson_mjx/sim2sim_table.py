"""The sim2sim runs pooled per condition, and their table (quadson_mjx.sim2sim's rows in, plain
data and text out)."""

from __future__ import annotations

import math

import numpy as np


def rms(sq_sum: float, n: int) -> float | None:
    """sqrt(sq_sum / n), None for no step."""
    return math.sqrt(sq_sum / n) if n else None


GROUP_KEYS = ("policy_name", "velocity_source", "terrain", "randomize", "pushes", "latency_s")


def _share(hits: float, n: int) -> float | None:
    return hits / n if n else None


def summarize(rows, by=GROUP_KEYS, split_step: bool = True) -> list[dict]:
    """Pools runs per condition (and the step schedule, the tile trial and the gait command apart
    from the sweep): runs, falls, fall rate, RMS and mean vx over every tracked step of the pooled
    runs, the contact pattern's share of those steps (exact and within one step), invalid-IK and
    fault steps, the share of runs that succeeded and of the commanded distance covered (runs
    written before those keys: None)."""
    groups: dict[tuple, list] = {}
    for r in rows:
        commands = r["label"] if r["label"] in ("step", "gait", "tile") else "sweep"
        key = tuple(r[k] for k in by) + ((commands,) if split_step else ())
        groups.setdefault(key, []).append(r)
    out = []
    for key, rs in groups.items():
        n = sum(r["tracked_steps"] for r in rs)
        sq = np.sum([r["sq_err_sum"] for r in rs], axis=0)
        out.append(
            {
                **dict(zip(by, key, strict=False)),
                **({"commands": key[-1]} if split_step else {}),
                "runs": len(rs),
                "falls": sum(r["fell"] for r in rs),
                "fall_rate": sum(r["fell"] for r in rs) / len(rs),
                "off_field": sum(r["off_field"] for r in rs),
                "vx_rms": rms(sq[0], n),
                "vy_rms": rms(sq[1], n),
                "yaw_rate_rms": rms(sq[2], n),
                "vx_mean": _share(sum(r["vx_sum"] for r in rs), n),
                "pattern": _share(sum(r["pattern_hits"] for r in rs), n),
                "pattern_1step": _share(sum(r["pattern_1step_hits"] for r in rs), n),
                "invalid_ik_steps": sum(r["invalid_ik_steps"] for r in rs),
                "fault_steps": sum(r["fault_steps"] for r in rs),
                "steps": sum(r["steps"] for r in rs),
                "success": _share(sum(r["success"] for r in rs), len(rs))
                if all("success" in r for r in rs)
                else None,
                "distance_share": _share(
                    sum(r.get("progress_m", 0.0) for r in rs), sum(r.get("commanded_m", 0.0) for r in rs)
                ),
            }
        )
    return out


def format_table(
    summary,
    columns=("policy_name", "velocity_source", "terrain", "commands", "randomize", "pushes", "latency_s"),
) -> str:
    """A plain-text table of summarize's rows: the mean vx only for the gait command (a sweep's
    commands differ), the contact pattern within one control step; the success and distance
    shares where a row is a tile trial."""
    tiles = any(s.get("commands") == "tile" for s in summary)
    head = [*columns, "runs", "falls", "vx_rms", "vy_rms", "yaw_rms", "vx_mean", "pattern", "ik_inv"]
    head += ["success", "distance"] if tiles else []
    lines = [head]
    for s in summary:
        f = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
        pattern = "-" if s["pattern_1step"] is None else f"{100 * s['pattern_1step']:.1f}%"
        lines.append(
            [str(s.get(c, "")) for c in columns]
            + [
                str(s["runs"]),
                f"{s['falls']} ({100 * s['fall_rate']:.0f}%)",
                f(s["vx_rms"]),
                f(s["vy_rms"]),
                f(s["yaw_rate_rms"]),
                f(s["vx_mean"] if s.get("commands") == "gait" else None),
                pattern,
                str(s["invalid_ik_steps"]),
            ]
            + (
                [
                    "-" if s["success"] is None else f"{100 * s['success']:.0f}%",
                    f(s["distance_share"]),
                ]
                if tiles
                else []
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return "\n".join("  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)) for line in lines)
