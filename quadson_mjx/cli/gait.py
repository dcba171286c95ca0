"""Run a gait open loop in the closed-chain model on CPU MuJoCo and report seed 003 Table II's numbers.

    quadson-gait                          # trot at its seed speed, 10 s, flat ground
    quadson-gait --gait all               # walk, trot, pace, bound, gallop
    quadson-gait --gait walk --vx 0.05 --vy 0.02 --yaw-rate 0.1 --swing cycloid
    quadson-gait --gait trot_discontinuous --json runs/gait_eval.json
    quadson-gait --robot caramel --scene rough --yaw-rate 0.25 --vx 0   # seed 003's trot on Caramel
(`python eval/gait.py ...` runs the same command.)

Each control step (50 Hz by default) the gait's foot targets go through the five-bar IK
(quadson_mjx.gait.motor_targets) into the position-controlled motors; no feedback. The robot starts
in the model's `home` keyframe and the foot targets blend from the home feet into the gait over
--ramp-s (smoothstep), so that the first step does not jump. Reported over the trial after the ramp:
stayed up (base height > 0.1 m and |roll|, |pitch| < 45 deg for the whole trial, ramp included),
mean forward speed (world x travel / time; the robot starts facing +x) against the command, and
roll/pitch oscillation as max - min and standard deviation [deg] (seed 003, Table II), and the mean
pitch [deg] (negative: nose up). The default swing is the seed's Bezier (apex h / sqrt 3): with
"bezier_apex" (the environment's) the open-loop trot falls nose-up at 1.6 s (models/quadson/README.md).

--robot caramel runs seed 003's planner on Caramel instead (quadson_mjx.seed003
.walk_sample, the walk of its Tables II-III, for --duration-s after standing 1 s; --pid adds seed
003's stabilizer): mean velocity along the start heading, yaw rate, Δroll and Δpitch [deg].

A bad input (a non-finite command, a trial that is not a positive number of seconds up to
MAX_DURATION_S or no longer than the ramp, a control period that is not a multiple of the physics
step, a --json path in a missing or read-only folder) exits with status 2 and one line on stderr,
before anything runs; --json is written whole or not at all.
"""

from __future__ import annotations

import json
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from quadson_mjx import errors
from quadson_mjx.errors import UsageError
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.robots.quadson import fivebar
from quadson_mjx.robots.quadson import gait as G
from quadson_mjx.robots.quadson import model as M
from quadson_mjx.swing import SWING_SHAPES

FIVE = ("walk", "trot", "pace", "bound", "gallop")
MIN_HEIGHT_M = 0.1
MAX_TILT_DEG = 45.0
MAX_DURATION_S = 3600.0  # longest trial [s]


def planned_motor_targets(params, command, times, home_feet, ramp_s):
    """Open-loop plan: (n,) times [s] -> motor angles (n, 4, 3) [rad], valid (n, 4)."""
    feet = jax.jit(jax.vmap(G.foot_targets, in_axes=(0, None, None)))(
        jnp.asarray(times), jnp.asarray(command), params
    )
    s = np.clip(np.asarray(times) / ramp_s, 0.0, 1.0) if ramp_s > 0 else np.ones(len(times))
    alpha = jnp.asarray((s * s * (3 - 2 * s))[:, None, None], jnp.float32)
    feet = home_feet + alpha * (feet - home_feet)
    angles, valid = jax.jit(G.motor_targets)(feet)
    return np.asarray(angles, np.float64), np.asarray(valid)


def open_loop_targets(gait: str, duration_s: float, ctrl_dt: float = 0.02, ramp_s: float = 1.0) -> np.ndarray:
    """(n, 12) motor targets [rad] (C.ACTUATORS order) of Quadson's open-loop `gait` at its seed
    speed from the home feet, one row per control step of ctrl_dt [s] (as run_trial plays them)."""
    params = G.gait_params(gait)
    command = np.array([float(G.seed_speed(params)), 0.0, 0.0], np.float32)
    model = M.load_model()
    home = M.home_ctrl(model)[M.model_ids(model).motor_actuator].reshape(4, 3)
    home_feet = fivebar.leg_fk(jnp.asarray(home, jnp.float32))
    times = np.arange(round(duration_s / ctrl_dt)) * ctrl_dt
    angles, _ = planned_motor_targets(params, command, times, home_feet, ramp_s)
    return angles.reshape(len(times), 12)


def run_trial(
    gait: str,
    command=None,
    swing=None,
    duration_s=10.0,
    ctrl_dt=0.02,
    ramp_s=1.0,
    scene="flat",
    fivebar_model="full",
) -> dict:
    """One open-loop trial -> dict of results (SI, angles in degrees where named _deg); fivebar_model: the
    leg model (model.FIVEBAR_MODELS)."""
    params = G.gait_params(gait) if swing is None else G.gait_params(gait, swing=swing)
    if command is None:
        command = (float(G.seed_speed(params)), 0.0, 0.0)
    model = M.load_model(scene, fivebar_model)
    ids = M.model_ids(model)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home"))
    mujoco.mj_forward(model, data)
    n_sub = round(ctrl_dt / model.opt.timestep)
    if n_sub < 1 or abs(n_sub * model.opt.timestep - ctrl_dt) > 1e-9:
        raise UsageError(
            f"--ctrl-dt {ctrl_dt}: not a whole multiple of the physics timestep {model.opt.timestep} s"
        )
    n = round(duration_s / ctrl_dt)
    times = np.arange(n) * ctrl_dt
    home_angles = M.home_ctrl(model)[ids.motor_actuator].reshape(4, 3)
    home_feet = fivebar.leg_fk(jnp.asarray(home_angles, jnp.float32))
    angles, valid = planned_motor_targets(params, np.asarray(command, np.float32), times, home_feet, ramp_s)

    root = ids.root_qposadr
    pos, rpy = np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
    pos[0], rpy[0] = data.qpos[root : root + 3], quat_to_rpy(data.qpos[root + 3 : root + 7])
    warnings_before = int(np.sum(data.warning.number))
    for k in range(n):
        data.ctrl[ids.motor_actuator] = angles[k].reshape(12)
        mujoco.mj_step(model, data, nstep=n_sub)
        pos[k + 1], rpy[k + 1] = data.qpos[root : root + 3], quat_to_rpy(data.qpos[root + 3 : root + 7])

    tilt_deg = np.degrees(np.abs(rpy[:, :2]))
    ok = (pos[:, 2] > MIN_HEIGHT_M) & np.all(tilt_deg < MAX_TILT_DEG, axis=1)
    up = bool(np.all(ok))
    w = times >= ramp_s  # the window after the ramp (state k+1 follows control step k)
    win_pos, win_rpy = pos[1:][w], np.degrees(rpy[1:][w])
    span = times[w][-1] + ctrl_dt - ramp_s if np.any(w) else float("nan")
    start_pos = pos[1:][times < ramp_s][-1] if ramp_s > 0 else pos[0]
    return {
        "gait": gait,
        "swing": SWING_SHAPES[int(params.swing)],
        "command": [float(c) for c in command],
        "duration_s": duration_s,
        "stayed_up": up,
        "fell_at_s": None if up else float(np.argmin(ok) * ctrl_dt),
        "mean_vx": float((win_pos[-1, 0] - start_pos[0]) / span),
        "mean_vy": float((win_pos[-1, 1] - start_pos[1]) / span),
        "yaw_change_deg": float(win_rpy[-1, 2] - win_rpy[0, 2]),
        "min_height_m": float(pos[:, 2].min()),
        "roll_range_deg": float(np.ptp(win_rpy[:, 0])),
        "roll_std_deg": float(np.std(win_rpy[:, 0])),
        "pitch_range_deg": float(np.ptp(win_rpy[:, 1])),
        "pitch_std_deg": float(np.std(win_rpy[:, 1])),
        "pitch_mean_deg": float(np.mean(win_rpy[:, 1])),  # > 0 nose down, < 0 nose up
        "ik_invalid_fraction": float(np.mean(~valid)),
        "mujoco_warnings": int(np.sum(data.warning.number)) - warnings_before,
    }


def _table(rows) -> str:
    head = (
        "gait     swing        cmd vx  mean vx  up (fell)  min z   Δroll  σroll  Δpitch σpitch  pitch  IK bad"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        up = "yes" if r["stayed_up"] else f"NO {r['fell_at_s']:4.1f} s"
        lines.append(
            f"{r['gait'][:8]:8s} {r['swing']:11s} {r['command'][0]:7.3f} {r['mean_vx']:8.3f}  {up:9s} "
            f"{r['min_height_m']:6.3f} {r['roll_range_deg']:7.2f} {r['roll_std_deg']:6.2f} "
            f"{r['pitch_range_deg']:7.2f} {r['pitch_std_deg']:6.2f} {r['pitch_mean_deg']:6.2f} "
            f"{100 * r['ik_invalid_fraction']:6.2f}%"
        )
    return "\n".join(lines)


def caramel_main(args, parser) -> int:
    from quadson_mjx import seed003 as E
    from quadson_mjx.robots.caramel import gait as CG

    if args.gait not in ("trot", *CG.GAIT_NAMES) or args.swing not in (None, "cycloid"):
        parser.error(
            f"caramel runs {CG.GAIT_NAMES[0]} with the cycloid swing (got --gait {args.gait}, --swing {args.swing})"
        )
    if args.ctrl_dt != 0.02:
        parser.error("caramel's planner runs at seed 003's 50 Hz tick (--ctrl-dt 0.02)")
    command = (CG.SEED_SPEED if args.vx is None else args.vx, args.vy, args.yaw_rate)
    r = E.walk_sample(
        args.scene,
        command,
        pid=args.pid,
        distance_m=float("inf"),
        turn_rad=float("inf"),
        max_time_s=args.duration_s,
    )
    row = {
        "robot": "caramel",
        "gait": CG.GAIT_NAMES[0],
        "scene": args.scene,
        "pid": args.pid,
        "command": command,
        **r,
    }
    print(
        f"caramel {row['gait']} {args.scene}{' + PID' if args.pid else ''}, command {command}: "
        f"{'FELL' if r['fell'] else 'up'} for {r['time_s']:.1f} s, velocity {100 * r['velocity_mps']:.2f} cm/s, "
        f"yaw rate {r['yaw_rate_radps']:.3f} rad/s, Δroll {r['roll_deg']:.2f} deg, Δpitch {r['pitch_deg']:.2f} deg, "
        f"{r['invalid_ticks']} ticks clamped"
    )
    if args.json:
        errors.write_text_atomic(args.json, json.dumps(row, indent=2, default=float))
    return 0


def check_args(args) -> None:
    """UsageError for numbers the trial cannot run with and an unwritable --json, before it runs."""
    for flag, value in (("--vx", args.vx), ("--vy", args.vy), ("--yaw-rate", args.yaw_rate)):
        if value is not None:
            errors.check_number(flag, value)
    errors.check_number("--duration-s", args.duration_s, 0.0, MAX_DURATION_S, above=True)
    errors.check_number("--ctrl-dt", args.ctrl_dt, 0.0, 1.0, above=True)
    errors.check_number("--ramp-s", args.ramp_s, 0.0)
    if args.robot == "quadson" and not args.duration_s > args.ramp_s + args.ctrl_dt:
        raise UsageError(
            f"--duration-s {args.duration_s}: the trial must outlast the ramp (--ramp-s {args.ramp_s}) "
            f"by at least one control step"
        )
    if args.json:
        errors.check_writable(args.json, "--json")


@errors.one_line_errors
def main(argv=None) -> int:
    p = errors.ArgumentParser(prog="quadson-gait", description=__doc__.split("\n\n")[0])
    p.add_argument("--gait", default="trot", choices=[*G.GAIT_NAMES, "all"])
    p.add_argument("--swing", default=None, choices=SWING_SHAPES, help="default: the gait's own")
    p.add_argument("--vx", type=float, default=None, help="m/s; default: the gait's seed speed")
    p.add_argument("--vy", type=float, default=0.0)
    p.add_argument("--yaw-rate", type=float, default=0.0)
    p.add_argument("--duration-s", type=float, default=10.0)
    p.add_argument("--ctrl-dt", type=float, default=0.02)
    p.add_argument("--ramp-s", type=float, default=1.0)
    p.add_argument("--scene", default="flat", choices=sorted(M.SCENES))
    p.add_argument("--json", default=None, help="write the results here")
    p.add_argument("--robot", default="quadson", choices=["quadson", "caramel"])
    p.add_argument("--pid", action="store_true", help="caramel: seed 003's roll/pitch stabilizer")
    args = p.parse_args(argv)
    check_args(args)
    if args.robot == "caramel":
        return caramel_main(args, p)

    rows = []
    for gait in FIVE if args.gait == "all" else (args.gait,):
        params = G.gait_params(gait)
        vx = float(G.seed_speed(params)) if args.vx is None else args.vx
        rows.append(
            run_trial(
                gait,
                (vx, args.vy, args.yaw_rate),
                args.swing,
                args.duration_s,
                args.ctrl_dt,
                args.ramp_s,
                args.scene,
            )
        )
    print(_table(rows))
    if args.json:
        errors.write_text_atomic(args.json, json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
