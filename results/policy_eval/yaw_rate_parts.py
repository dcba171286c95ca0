"""What the joystick policies' yaw-rate error is made of: the gait's own wobble, slow drift, or the
rest. The issue's metric is the RMS of the yaw-rate error over every control step after the first
second, not smoothed; a trot turns the body a little at every step, and no tracking of the command
removes that part without changing how the feet push.

Each environment's error e(t) = gyro z - commanded yaw rate (kept steps as in
quadson_mjx.policy_eval: after the first second, before any episode end) is split into three
orthogonal parts:

* phase-locked: the mean of e over the environment's gait cycles at each control step of the cycle
  (the gait clock is the episode time, so step k of every cycle is the same phase): the wobble that
  repeats every cycle;
* cycle mean: the mean over each whole cycle of what is left: a drift or slow tracking error;
* rest: what is left after both (pushes, stones, slips, noise).

Their squares add up to the square of the total RMS (up to the incomplete last cycle, left out).
Rows: the sensor-only policy (results/policy_h100_sensors) and the true-state policy
(results/policy_h100_joystick) on flat ground and on the stones, each in its run's randomized
models with pushes (as quadson_mjx.cli.policy_eval evaluates them, the same draws); then both and
the open-loop trot (zero foot offsets, in the sensor run's env) on flat ground with the nominal
model and no pushes (randomize=false: no sensor noise, bias, IMU tilt or latency either; encoder
quantisation kept), and the sensor-only policy there with ideal sensors (quantisation off as well:
the only difference from the row before it). Each row: the 75 commands of
quadson_mjx.commands.sweep_commands, one environment each, 20 s, seed 0.

    python results/policy_eval/yaw_rate_parts.py results/policy_eval/yaw_rate_parts.json \
        > results/policy_eval/yaw_rate_parts.log

(A third argument N and a fourth S run only the first N commands for S seconds: a quick check.)

    python results/policy_eval/yaw_rate_parts.py OUT.json --runs RUN [RUN ...]

gives the same split for the policies of other runs, three rows each: flat and stones as evaluated,
and flat ground with the nominal model and no pushes;

    python results/policy_eval/yaw_rate_parts.py OUT.json --factors RUN

one policy on the stones and on flat ground as evaluated and under one disturbance at a time
(FACTORS: none, the pushes, the sensor errors, the randomized model with the sensor errors);
`--factors RUN --only "sensor errors"` those FACTORS alone;

    python results/policy_eval/yaw_rate_parts.py OUT.json --sensor-groups RUN

the policy on the stones with the sensor errors split in two (SENSOR_GROUPS: the readings' latency
alone, and every other sensor error without it), on the nominal model without pushes;

    python results/policy_eval/yaw_rate_parts.py OUT.json --with RUN OVERRIDE [OVERRIDE ...]

the policy on the stones and on flat ground as evaluated and with the env overrides given (e.g.
sensor.imu_tilt_rad=0.01: a smaller range of one sensor error, the rest as evaluated).
"""

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from quadson_mjx import rollout as R
from quadson_mjx.commands import sweep_commands
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.policy_eval import SETTLE_S
from quadson_mjx.randomize import nominal_range_overrides
from quadson_mjx.training import load_policy

SECONDS = 20.0
# the nominal model, no pushes; randomize=false also turns the sensor errors off (noise, gyro bias,
# IMU tilt, latency); the encoders' quantisation stays
NOMINAL = ["randomize=false", "pushes=false"]
FACTORS = [  # (the ground's label suffix, overrides): one disturbance at a time, then all but the pushes
    (", nominal, no pushes", NOMINAL),
    (", pushes only", ["randomize=false", "pushes=true"]),
    (", sensor errors only", ["randomize=true", "pushes=false", *nominal_range_overrides()]),
    (", randomized model and sensors, no pushes", ["randomize=true", "pushes=false"]),
]
IDEAL_SENSORS = [  # the sensor-only actor's IMU and encoders without noise, bias, tilt or latency
    "sensor.gravity_noise=0",
    "sensor.gyro_noise_rps=0",
    "sensor.gyro_bias_rps=0",
    "sensor.imu_tilt_rad=0",
    "sensor.encoder_noise_rad=0",
    "sensor.encoder_resolution_rad=0",
    "sensor.latency_s=0,0",
]
SENSOR_ERRORS = ["randomize=true", "pushes=false", *nominal_range_overrides()]  # FACTORS' third
SENSOR_GROUPS = [  # the sensor errors split in two: the readings' latency, and the rest
    (
        ", sensor latency only",
        SENSOR_ERRORS + [o for o in IDEAL_SENSORS if not o.startswith("sensor.latency_s")],
    ),
    (", sensor errors but the latency", SENSOR_ERRORS + ["sensor.latency_s=0,0"]),
]
ROWS = [  # (label, run whose env config is used, controller "policy" or "gait", terrain, overrides)
    ("sensor-only policy", "results/policy_h100_sensors", "policy", "flat", []),
    ("sensor-only policy", "results/policy_h100_sensors", "policy", "rough", []),
    ("true-state policy", "results/policy_h100_joystick", "policy", "flat", []),
    ("true-state policy", "results/policy_h100_joystick", "policy", "rough", []),
    ("sensor-only policy", "results/policy_h100_sensors", "policy", "flat", NOMINAL),
    ("true-state policy", "results/policy_h100_joystick", "policy", "flat", NOMINAL),
    ("sensor-only policy", "results/policy_h100_sensors", "policy", "flat", NOMINAL + IDEAL_SENSORS),
    ("open-loop trot", "results/policy_h100_sensors", "gait", "flat", NOMINAL),
]


def cycle_steps(env) -> tuple[int, int]:
    """-> (control steps per gait cycle, the first kept step): SETTLE_S rounded up to whole cycles,
    so that the first kept step starts a cycle."""
    steps_per_cycle = int(round(float(env.gait_params.cycle_s) / env.ctrl_dt))
    first_kept = -(-int(round(SETTLE_S / env.ctrl_dt)) // steps_per_cycle) * steps_per_cycle
    return steps_per_cycle, first_kept


def yaw_rate_errors(env, controller, commands: np.ndarray, seconds: float, randomize: bool):
    """One environment per command for `seconds`, seed 0 -> (err, keep, falls): the yaw-rate error
    (gyro z minus the command) and the steps before each environment's first episode end, (T, B)
    each, and the number of environments that fell."""
    segs = list(
        R.run(
            env,
            controller,
            jax.random.PRNGKey(0),
            len(commands),
            int(round(seconds / env.ctrl_dt)),
            segment_steps=250,
            command=commands,
            randomize=randomize,
        )
    )
    err = np.concatenate([s.ang_vel[..., 2] - s.command[..., 2] for _, s in segs])
    done = np.concatenate([s.done for _, s in segs])
    fall = np.concatenate([s.fall for _, s in segs])
    return err, np.cumsum(done, axis=0) == 0, int(fall.any(axis=0).sum())


def kept_cycles(keep: np.ndarray, first_kept: int, steps_per_cycle: int) -> np.ndarray:
    """keep: (T, B) -> (B,) whole gait cycles of each environment's kept steps after first_kept
    (an environment with an episode end keeps its whole cycles before it)."""
    after = keep[first_kept:]
    n = np.where(after.all(axis=0), after.shape[0], np.argmin(after, axis=0))
    return n // steps_per_cycle


def parts(err: np.ndarray, keep: np.ndarray, steps_per_cycle: int, first_kept: int) -> np.ndarray:
    """err, keep: (T, B) -> (4,) RMS of total, phase-locked, cycle mean, rest over the whole cycles
    after first_kept of each environment's kept steps (an environment with an episode end keeps its
    whole cycles before it)."""
    sq = np.zeros(4)
    count = 0
    for b, cycles in enumerate(kept_cycles(keep, first_kept, steps_per_cycle)):
        if cycles < 2:
            continue
        e = err[first_kept : first_kept + cycles * steps_per_cycle, b].reshape(cycles, steps_per_cycle)
        locked = e.mean(axis=0, keepdims=True)
        slow = (e - locked).mean(axis=1, keepdims=True)
        rest = e - locked - slow
        sq += [
            np.sum(e**2),
            np.sum(np.broadcast_to(locked, e.shape) ** 2),
            np.sum(np.broadcast_to(slow, e.shape) ** 2),
            np.sum(rest**2),
        ]
        count += e.size
    return np.sqrt(sq / max(count, 1))


def run_rows(runs: list[str]) -> list[tuple]:
    """ROWS' three policy rows (flat, stones, flat nominal without pushes) for each run in `runs`."""
    return [
        (Path(run).name, run, "policy", terrain, overrides)
        for run in runs
        for terrain, overrides in (("flat", []), ("rough", []), ("flat", NOMINAL))
    ]


def factor_rows(run: str, only: str | None = None) -> list[tuple]:
    """The policy of `run` on the stones and on flat ground as evaluated, then under each of FACTORS;
    `only`: the FACTORS whose label holds it, alone."""
    conditions = [[]] if only is None else []
    conditions += [o for label, o in FACTORS if only is None or only in label]
    if not conditions:
        raise SystemExit(f"--only {only!r}: no condition of {[label for label, _ in FACTORS]}")
    return [(Path(run).name, run, "policy", terrain, o) for terrain in ("rough", "flat") for o in conditions]


def main(json_path: str, n_commands: int = 75, seconds: float = SECONDS, rows=ROWS) -> None:
    commands = sweep_commands().astype(np.float32)[:n_commands]
    out = []
    print("| controller | ground | yaw-rate error RMS [rad/s] | phase-locked | cycle mean | rest | falls |")
    print("|---|---|---|---|---|---|---|")
    for label, run, kind, terrain, overrides in rows:
        policy, env_cfg, _, _ = load_policy(Path(run))
        cfg = apply_overrides(with_added_keys(env_cfg), [f"terrain={terrain}", *overrides], prefix="env.")
        env = LocomotionEnv(cfg)
        controller = R.policy_controller(policy) if kind == "policy" else R.gait_only(env)
        steps_per_cycle, first_kept = cycle_steps(env)
        t0 = time.monotonic()
        err, keep, falls = yaw_rate_errors(env, controller, commands, seconds, bool(cfg.randomize))
        rms = parts(err, keep, steps_per_cycle, first_kept)
        row = {
            "controller": label,
            "run": run,
            "terrain": terrain,
            "overrides": overrides,
            "steps_per_cycle": steps_per_cycle,
            "rms_total": float(rms[0]),
            "rms_phase_locked": float(rms[1]),
            "rms_cycle_mean": float(rms[2]),
            "rms_rest": float(rms[3]),
            "falls": falls,
            "envs": len(commands),
            "wall_s": round(time.monotonic() - t0, 1),
        }
        out.append(row)
        ground = "stones" if terrain == "rough" else "flat"
        labels = SENSOR_GROUPS + FACTORS  # the longer overrides first: FACTORS' are their prefixes
        named = next((label for label, o in labels if o == overrides[: len(o)] and overrides), None)
        ideal = set(IDEAL_SENSORS) <= set(overrides)
        ground += named or ("" if ideal or not overrides else ", " + " ".join(overrides))
        ground += ", ideal sensors" if ideal else ""
        print(
            f"| {label} | {ground} | {rms[0]:.3f} | {rms[1]:.3f} | {rms[2]:.3f} | {rms[3]:.3f} "
            f"| {falls}/{len(commands)} |",
            flush=True,
        )
    settings = {"seconds": seconds, "commands": len(commands), "seed": 0}
    Path(json_path).write_text(json.dumps({"settings": settings, "rows": out}, indent=1) + "\n")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[2] == "--factors":
        only = sys.argv[5] if len(sys.argv) > 5 and sys.argv[4] == "--only" else None
        main(sys.argv[1], rows=factor_rows(sys.argv[3], only))
    elif len(sys.argv) > 2 and sys.argv[2] == "--sensor-groups":
        main(
            sys.argv[1],
            rows=[(Path(sys.argv[3]).name, sys.argv[3], "policy", "rough", o) for _, o in SENSOR_GROUPS],
        )
    elif len(sys.argv) > 4 and sys.argv[2] == "--with":
        run, extra = sys.argv[3], sys.argv[4:]
        main(
            sys.argv[1],
            rows=[(Path(run).name, run, "policy", t, o) for t in ("rough", "flat") for o in ([], extra)],
        )
    elif len(sys.argv) > 2 and sys.argv[2] == "--runs":
        main(sys.argv[1], rows=run_rows(sys.argv[3:]))
    else:
        main(sys.argv[1], *(int(sys.argv[2]), float(sys.argv[3])) if len(sys.argv) > 3 else ())
