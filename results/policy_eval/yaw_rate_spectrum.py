"""Where in frequency the joystick policies' yaw-rate error lies.

yaw_rate_parts.py splits the error into the gait's phase-locked wobble, the cycle mean and "the
rest", and the rest is most of it on the stones. This script splits the same error (gyro z minus
the commanded yaw rate, the steps that quadson_mjx.policy_eval keeps: after the first second,
before any episode end) by frequency instead: each environment's kept whole gait cycles, as one
record, through a discrete Fourier transform; by Parseval the band powers add up to the square of
the RMS. Bands (the trot's cycle is 0.8 s: stride 1.25 Hz, a diagonal pair's step 2.5 Hz; control
at 50 Hz, Nyquist 25 Hz): below 1 Hz (drift and slow tracking), 1-3.5 Hz (the stride and the
steps), 3.5-8 Hz (their harmonics), 8-25 Hz (faster than any foot-step: impacts, the policy's own
chatter at the control rate).

    python results/policy_eval/yaw_rate_spectrum.py OUT.json RUN [RUN ...] > OUT.log

Per run three rows: the stones and flat ground as evaluated (randomized model, sensor errors,
pushes), and the stones with the nominal model, no pushes and no sensor errors. Each row: the 75
commands of quadson_mjx.commands.sweep_commands, one environment each, 20 s, seed 0 (the draws of
yaw_rate_parts.py, whose rollout and kept steps it uses). `--commands N --seconds S` for a quick check.

`--action-ema A [A ...]` instead: each run on the stones as evaluated, its actions low-passed
before the env gets them (a_t = A a_(t-1) + (1 - A) policy_t; A = 0: as trained), to see whether the
fast band is the policy's own chatter (a filter takes it out) or the ground's (it stays).

`--sampling` instead: each run on the stones and on flat ground as evaluated, the yaw-rate error
measured two ways from the same rollout: the gyro's z at the control tick (what policy_eval
keeps: one instantaneous sample every 20 ms) and the base's mean z rate over the control step
(the rotation from the step's start to its end as a rotation vector over ctrl_dt, in the body
frame at the step's start). The second cannot see motion faster than the control step; the
difference is the body's vibration within a step, which the 50 Hz sample folds into the 0-25 Hz
bands (aliasing).
"""

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from yaw_rate_parts import NOMINAL, cycle_steps, kept_cycles, yaw_rate_errors  # this folder's script

from quadson_mjx import rollout as R
from quadson_mjx.commands import sweep_commands
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.quat import quat_conj, quat_mul
from quadson_mjx.training import load_policy

BANDS_HZ = [(0.0, 1.0), (1.0, 3.5), (3.5, 8.0), (8.0, 25.01)]
CONDITIONS = [("stones", "rough", []), ("flat", "flat", []), ("stones, nominal, no pushes", "rough", NOMINAL)]


def band_rms(err: np.ndarray, keep: np.ndarray, steps_per_cycle: int, first_kept: int, dt: float):
    """err, keep: (T, B) -> (total RMS, [RMS per band of BANDS_HZ]) over each environment's kept
    whole cycles after first_kept; every environment weighs by its number of kept steps."""
    total = 0.0
    bands = np.zeros(len(BANDS_HZ))
    count = 0
    for b, cycles in enumerate(kept_cycles(keep, first_kept, steps_per_cycle)):
        if cycles < 2:
            continue
        n = cycles * steps_per_cycle
        e = err[first_kept : first_kept + n, b].astype(np.float64)
        spec = np.abs(np.fft.rfft(e)) ** 2 / n  # sum over the two-sided spectrum = sum(e^2)
        weight = np.full(spec.shape, 2.0)  # one-sided: every bin but DC (and Nyquist) stands for two
        weight[0] = 1.0
        if n % 2 == 0:
            weight[-1] = 1.0
        power = spec * weight  # sums to sum(e^2)
        freq = np.fft.rfftfreq(n, dt)
        for i, (lo, hi) in enumerate(BANDS_HZ):
            bands[i] += power[(freq >= lo) & (freq < hi)].sum()
        total += np.sum(e**2)
        count += n
    return float(np.sqrt(total / max(count, 1))), np.sqrt(bands / max(count, 1))


def low_passed(controller, a: float, action_size: int):
    """The controller with its actions through a first-order low-pass: out = a prev + (1 - a) new."""

    def act(carry, state, key):
        inner, prev = carry
        inner, new = controller.act(inner, state, key)
        out = a * prev + (1.0 - a) * new
        return (inner, out), out

    return R.Controller(controller.name, lambda: (controller.init(), jnp.zeros(action_size)), act)


def step_mean_rate_z(quat_wxyz: np.ndarray, dt: float) -> np.ndarray:
    """quat (T, B, 4) of the base at each control step's end (wxyz) -> (T, B): the mean body z
    rate over each step (the relative rotation from the previous step's end, as a rotation vector
    in the body frame at the step's start, over dt); the first step repeats the second's."""
    q = quat_mul(quat_conj(quat_wxyz[:-1]), quat_wxyz[1:])  # body frame at the step's start
    q = np.where(q[..., :1] < 0.0, -q, q)  # the shorter way round
    v = q[..., 1:]
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(norm, q[..., :1])
    rotvec = np.where(norm > 1e-12, v * angle / np.maximum(norm, 1e-12), 2.0 * v)
    rate = rotvec[..., 2] / dt
    return np.concatenate([rate[:1], rate], axis=0)


def sampling_rows(run: str, commands: np.ndarray, seconds: float) -> list[dict]:
    """The --sampling rows of one run: per ground, the error from the tick's gyro sample and from
    the step's mean rate, over the same kept whole cycles."""
    policy, env_cfg, _, _ = load_policy(Path(run))
    rows = []
    for label, terrain, overrides in CONDITIONS[:2]:
        cfg = apply_overrides(with_added_keys(env_cfg), [f"terrain={terrain}", *overrides], prefix="env.")
        env = LocomotionEnv(cfg)
        steps_per_cycle, first_kept = cycle_steps(env)
        t0 = time.monotonic()
        segs = list(
            R.run(
                env,
                R.policy_controller(policy),
                jax.random.PRNGKey(0),
                len(commands),
                int(round(seconds / env.ctrl_dt)),
                segment_steps=250,
                command=commands,
                randomize=bool(cfg.randomize),
            )
        )
        cmd = np.concatenate([s.command[..., 2] for _, s in segs])
        sample = np.concatenate([s.ang_vel[..., 2] for _, s in segs])
        mean = step_mean_rate_z(
            np.concatenate([s.qpos[..., 3:7] for _, s in segs]).astype(np.float64), env.ctrl_dt
        )
        keep = np.cumsum(np.concatenate([s.done for _, s in segs]), axis=0) == 0
        falls = int(np.concatenate([s.fall for _, s in segs]).any(axis=0).sum())
        for how, rate in (("gyro sample at the tick", sample), ("mean rate over the step", mean)):
            total, bands = band_rms(rate - cmd, keep, steps_per_cycle, first_kept, env.ctrl_dt)
            rows.append(row(run, f"{label}, {how}", overrides, total, bands, falls, len(commands), t0))
    return rows


def row(run, ground, overrides, total, bands, falls, envs, t0, **extra) -> dict:
    """One row of the JSON output."""
    return {
        "run": run,
        "ground": ground,
        "overrides": overrides,
        **extra,
        "rms_total": total,
        "bands_hz": BANDS_HZ,
        "rms_bands": bands.tolist(),
        "falls": falls,
        "envs": envs,
        "wall_s": round(time.monotonic() - t0, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--commands", type=int, default=75)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--action-ema", type=float, nargs="+", default=None)
    ap.add_argument("--sampling", action="store_true")
    args = ap.parse_args()
    commands = sweep_commands().astype(np.float32)[: args.commands]
    heads = " | ".join(f"{lo:g}-{min(hi, 25):g} Hz" for lo, hi in BANDS_HZ)
    print(f"| policy | ground | yaw-rate error RMS [rad/s] | {heads} | falls |")
    print("|---|---|---|" + "---|" * len(BANDS_HZ) + "---|")
    rows = []
    for run in args.runs if args.sampling else []:
        for r in sampling_rows(run, commands, args.seconds):
            cells = " | ".join(f"{x:.3f}" for x in r["rms_bands"])
            print(
                f"| {Path(run).name} | {r['ground']} | {r['rms_total']:.3f} | {cells} | {r['falls']}/{len(commands)} |"
            )
            rows.append(r)
    for run in [] if args.sampling else args.runs:
        policy, env_cfg, _, _ = load_policy(Path(run))
        conditions = (
            CONDITIONS if args.action_ema is None else [("stones", "rough", [])] * len(args.action_ema)
        )
        for i, (label, terrain, overrides) in enumerate(conditions):
            cfg = apply_overrides(with_added_keys(env_cfg), [f"terrain={terrain}", *overrides], prefix="env.")
            env = LocomotionEnv(cfg)
            steps_per_cycle, first_kept = cycle_steps(env)
            t0 = time.monotonic()
            controller = R.policy_controller(policy)
            if args.action_ema is not None:
                controller = low_passed(controller, args.action_ema[i], env.action_size)
                label = f"stones, actions low-passed {args.action_ema[i]:g}"
            err, keep, falls = yaw_rate_errors(env, controller, commands, args.seconds, bool(cfg.randomize))
            total, bands = band_rms(err, keep, steps_per_cycle, first_kept, env.ctrl_dt)
            cells = " | ".join(f"{x:.3f}" for x in bands)
            print(
                f"| {Path(run).name} | {label} | {total:.3f} | {cells} | {falls}/{len(commands)} |",
                flush=True,
            )
            ema = None if args.action_ema is None else args.action_ema[i]
            rows.append(row(run, label, overrides, total, bands, falls, len(commands), t0, action_ema=ema))
    settings = {"seconds": args.seconds, "commands": len(commands), "seed": 0}
    Path(args.out).write_text(json.dumps({"settings": settings, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
