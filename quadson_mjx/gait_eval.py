"""How well a controller walks a gait: falls, speed, body oscillation and the foot-contact pattern.

`evaluate(env, controller, ...)` rolls out B environments for one episode each (one randomized
model per environment when the env config randomizes; quadson_mjx.rollout) and `gait_stats`
summarises the trajectory. Everything is measured on each environment's first episode, after
`settle_s` (the start ramp and the first steps), up to the step where it fell:

* falls: episodes that ended by tilt, height or the base in the ground, out of B.
* speed: mean body-frame forward velocity [m/s] per episode, then mean and std over episodes;
  `speed_ratio` = mean / command.
* roll, pitch std [deg]: per episode, then averaged over episodes.
* contact pattern: a foot is "down" when its normal contact force exceeds `force_threshold_n`
  (from MJX's constraint forces, as a foot sensor reads it); the phase table says "stance" when the
  leg's phase is below the gait's duty (Trajectory.scheduled_stance, at the end of the control
  step; the forces are those of the last 4 ms physics substep, MuJoCo's contact timing). Per
  control step, `pattern_match` is the share of steps where all four feet agree with the table;
  `pattern_match_1step` lets each foot's touchdown and lift-off fall one control step (20 ms) early
  or late, so that a touchdown between two 50 Hz samples is not a mismatch; `foot_agreement` is
  the share of (step, foot) pairs that agree; `duty_measured` (4,) the share of steps each foot is
  down, against the table's duty.
"""

from __future__ import annotations

import math

import numpy as np

from quadson_mjx import gait
from quadson_mjx import rollout as R
from quadson_mjx.gait_pattern import FORCE_THRESHOLD_N, tolerant_agreement  # noqa: F401 (also this module's API)


def first_episode_mask(done: np.ndarray) -> np.ndarray:
    """done: (T, B) bool -> (T, B) bool, True up to and including each env's first done step."""
    done = np.asarray(done, bool)
    ended_before = np.cumsum(done, axis=0) - done  # dones strictly before step t
    return ended_before == 0


def gait_stats(
    traj: R.Trajectory,
    ctrl_dt: float,
    command_vx: float,
    duty: float,
    settle_s: float = 1.0,
    force_threshold_n: float = FORCE_THRESHOLD_N,
) -> dict:
    """traj: a host Trajectory [T, B] starting at each environment's reset -> dict of results
    (see the module docstring; SI, angles in degrees where named _deg)."""
    first = first_episode_mask(traj.done)  # (T, B)
    fell = np.any(traj.fall & first, axis=0)  # (B,)
    settle = int(round(settle_s / ctrl_dt))
    t_index = np.arange(first.shape[0])[:, None]
    use = first & (t_index >= settle) & ~(traj.done & first)  # steps of the walk, not the fall itself
    n_env = first.shape[1]
    speeds, roll_std, pitch_std = [], [], []
    for b in range(n_env):
        m = use[:, b]
        if m.sum() < 2:
            continue
        speeds.append(float(np.mean(traj.lin_vel[m, b, 0])))
        roll_std.append(float(np.std(np.degrees(traj.rpy[m, b, 0]))))
        pitch_std.append(float(np.std(np.degrees(traj.rpy[m, b, 1]))))
    contact = traj.foot_force > force_threshold_n  # (T, B, 4)
    stance = np.asarray(traj.scheduled_stance, bool)
    strict = np.all(contact == stance, axis=-1)  # (T, B)
    tolerant = np.all(tolerant_agreement(contact, stance, 1), axis=-1)
    mean_speed = float(np.mean(speeds)) if speeds else math.nan
    return {
        "episodes": int(n_env),
        "falls": int(np.sum(fell)),
        "command_vx": float(command_vx),
        "speed_mean": mean_speed,
        "speed_std": float(np.std(speeds)) if speeds else math.nan,
        "speed_ratio": mean_speed / command_vx if command_vx else math.nan,
        "roll_std_deg": float(np.mean(roll_std)) if roll_std else math.nan,
        "pitch_std_deg": float(np.mean(pitch_std)) if pitch_std else math.nan,
        "pattern_match": float(np.mean(strict[use])) if use.any() else math.nan,
        "pattern_match_1step": float(np.mean(tolerant[use])) if use.any() else math.nan,
        "foot_agreement": float(np.mean((contact == stance)[use])) if use.any() else math.nan,
        "duty_measured": [float(v) for v in np.mean(contact[use], axis=0)] if use.any() else [],
        "duty_table": float(duty),
        "steps_measured": int(use.sum()),
    }


def footfall_lines(contact: np.ndarray, stance: np.ndarray, legs) -> list[str]:
    """A footfall diagram as text, one character per control step: contact, stance (T, 4) bool ->
    per leg two lines, the phase table ('#' stance, '.' swing) and the feet measured ('#' down)."""
    lines = []
    for i, leg in enumerate(legs):
        lines.append(f"{leg} table {''.join('#' if v else '.' for v in stance[:, i])}")
        lines.append(f"{leg} feet  {''.join('#' if v else '.' for v in contact[:, i])}")
    return lines


FIELDS = ("lin_vel", "rpy", "foot_force", "scheduled_stance", "done", "fall")


def evaluate(
    env,
    controller: R.Controller,
    rng,
    n_envs: int,
    seconds: float,
    settle_s: float = 1.0,
    footfall_s: tuple[float, float] | None = None,
) -> dict:
    """One episode of `seconds` in each of n_envs environments (randomized models when the env
    config randomizes), the gait's forward command -> gait_stats, plus with footfall_s = (start,
    end) [s] the footfall diagram of environment 0 over that window ("footfalls": footfall_lines;
    empty if it fell before the window's end)."""
    if env.config.command_tracking:
        raise ValueError(
            "evaluate runs the gait's own forward command: use an env config without command_tracking"
        )
    n_steps = int(round(seconds / env.ctrl_dt))
    params = env.gait_params
    command_vx = float(gait.seed_speed(params))
    parts = []
    for _, seg in R.run(
        env, controller, rng, n_envs, n_steps, command=None, randomize=bool(env.config.randomize)
    ):
        parts.append({k: getattr(seg, k) for k in FIELDS})
    joined = {k: np.concatenate([p[k] for p in parts], axis=0) for k in FIELDS}
    traj = R.Trajectory(**{f: joined.get(f) for f in R.Trajectory._fields})
    stats = gait_stats(traj, env.ctrl_dt, command_vx, float(params.duty), settle_s)
    if footfall_s is not None:
        lo, hi = (int(round(t / env.ctrl_dt)) for t in footfall_s)
        fell = bool(np.any(first_episode_mask(traj.done)[:hi, 0] & traj.done[:hi, 0]))
        contact = traj.foot_force[lo:hi, 0] > FORCE_THRESHOLD_N
        stats["footfalls"] = (
            [] if fell else footfall_lines(contact, traj.scheduled_stance[lo:hi, 0], env.robot.legs)
        )
    return stats
