"""The get-up task's drops in MuJoCo C, through the robot's get-up policy code: does the policy stand
the robot up outside MJX, and does it turn the body over in the air there too?

Starts: the get-up task's own drops (GetupEnv.reset on flat ground or the stones, seed 0: class, pose, motor
angles, 0.2-0.5 m up, at rest), placed in sim2sim's MuJoCo C plant (2 ms steps, every leg geom and
the base touching the ground, the servo model with its torque-speed line, deadband and 20 ms
latency, IMU and encoder noise and bias, and a randomized model from the walking run's ranges, as
in the knock-downs), its servos holding the start's motor angles. The exported get-up policy runs
through deploy_supervisor.GetupPolicy (the code that runs on the robot: observation, mirroring,
targets, clamp) every 20 ms from the release. Success as the task counts it: tilt below 10 deg and
the base within 2 cm of the home stance's height, held 1 s, begun within 5 s. Also, per drop, the
tilt when the first geom touches the ground (how far the body turned in the air) against the tilt
at release.

    python results/getup_warp_h100/drops_mujoco_c.py RUN [--drops 100] [--ground stones] [--walk results/policy_h100_sensors]

On the stones the plant's field is sim2sim's (the training field repeated around itself); the
script leaves out the starts over ground that differs between the two (the training field's flat
patch at its origin, which sim2sim's does not have) and says how many.
"""

import argparse
import math
import tempfile
from pathlib import Path

import jax
import mujoco
import numpy as np

from quadson_mjx import export, tasks
from quadson_mjx.deploy_supervisor import tilt
from quadson_mjx.getup_env import GetupEnv
from quadson_mjx.knockdown import build
from quadson_mjx.robots.quadson import getup_start


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("--drops", type=int, default=100)
    p.add_argument("--walk", default="results/policy_h100_sensors")
    p.add_argument("--ground", default="flat", choices=("flat", "stones"))
    args = p.parse_args()
    env = GetupEnv(
        tasks.make_task_config({"flat": "QuadsonGetupFlat", "stones": "QuadsonGetupRough"}[args.ground])
    )
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), args.drops))
    q0, u0 = np.asarray(state.pipeline_state.qpos), np.asarray(state.pipeline_state.ctrl)
    classes = np.asarray(state.info["start_class"])
    with tempfile.TemporaryDirectory() as tmp:
        walk = export.export_run(Path(args.walk), Path(tmp) / "walk.onnx")
        getup = export.export_run(Path(args.run), Path(tmp) / "getup.onnx")
        sup, plant, _ = build(walk, getup, args.ground)
    assert plant.m.nq == q0.shape[1], (plant.m.nq, q0.shape)
    plant.reset()  # its ground placed (the height query casts rays)
    same = np.array(  # the same ground under the start in both models
        [
            abs(plant.ground_height(q[:2]) - float(env.ground_height(jax.numpy.asarray(q[:2])))) < 1e-3
            for q in q0
        ]
    )
    policy, dt = sup.getup, sup.dt
    stand_h = env.stand_height  # the task's: the home stance's base height above the ground
    g = env.config.getup  # the task's success: tilt, height, hold, within
    rows = []
    for i in np.flatnonzero(same):
        plant.reset()
        d = plant.d
        d.qpos[:] = q0[i]
        d.qvel[:] = 0.0
        plant.targets = u0[i][plant.act].copy() if u0.shape[1] == plant.m.nu else d.qpos[plant.qadr].copy()
        plant._queue = []
        mujoco.mj_forward(plant.m, d)
        policy.reset()
        t0_tilt, touch_tilt, began, stood = tilt(d.qpos[3:7]), None, None, None
        for k in range(int(round((g.success_within_s + g.success_hold_s) / dt))):
            rd = plant.read()
            out = policy.act(rd.imu_quat_wxyz, rd.gyro, rd.motor_pos)
            if out is not None:
                plant.send(out[0])
            plant.advance(dt)
            if touch_tilt is None and d.ncon > 0:
                touch_tilt = tilt(d.qpos[3:7])
            up = (
                tilt(d.qpos[3:7]) < g.success_tilt_rad
                and abs(plant.truth()["height"] - stand_h) < g.success_height_m
            )
            t = (k + 1) * dt
            if up and began is None and t <= g.success_within_s + 1e-9:
                began = t
            elif not up:
                began = None
            if began is not None and t - began >= g.success_hold_s - 1e-9:
                stood = began
                break
        rows.append(
            (
                int(classes[i]),
                stood,
                math.degrees(t0_tilt),
                math.degrees(touch_tilt or 0.0),
                math.degrees(tilt(d.qpos[3:7])),
            )
        )
    names = list(getup_start.CLASSES)
    print(
        f"{args.run}: {len(rows)} of the task's {args.ground} drops in MuJoCo C through GetupPolicy (standing height "
        f"{stand_h:.3f} m; {args.drops - len(rows)} of {args.drops} left out, their ground not the same in both)"
    )
    print(
        "| start | stood | median time to stand [s] | tilt at release -> at first contact, median [deg] | failures' final tilt [deg] |"
    )
    print("|---|---|---|---|---|")
    for c, name in enumerate(names):
        r = [x for x in rows if x[0] == c]
        if not r:
            continue
        ok = [x for x in r if x[1] is not None]
        t_med = np.median([x[1] for x in ok]) if ok else float("nan")
        print(
            f"| {name} | {len(ok)} / {len(r)} | {t_med:.2f} | {np.median([x[2] for x in r]):.0f} -> {np.median([x[3] for x in r]):.0f} "
            f"| {', '.join(f'{x[4]:.0f}' for x in r if x[1] is None) or '-'} |"
        )
    ok = sum(x[1] is not None for x in rows)
    print(f"all: {ok} / {len(rows)} ({100 * ok / len(rows):.1f} %)")


if __name__ == "__main__":
    main()
