"""Where the gait policies' feet leave the phase table in MuJoCo C: each committed gait policy
through the deploy loop against the sim2sim plant, as `eval/sim2sim.py --commands gait --terrain
flat` runs it (nominal model, 20 ms latency, sensor noise, 20 s, the same seeds), every (control
step, foot) after the first second that misses the table by more than one control step
(gait_pattern.tolerant_agreement, as the pattern within one step counts it), put in a class:
"down in swing" (a foot on the ground where the table has it in the air) or "up in stance", per
foot, as a share of the steps. A run that falls counts up to its fall.

    for g in walk trot pace bound gallop; do python -m quadson_mjx.export results/gaits/$g /tmp/gaits/$g.onnx; done
    python results/sim2sim/gaits_pattern_misses.py /tmp/gaits --seeds 10 > results/sim2sim/gaits_pattern_misses.log
"""

import argparse
import math
from pathlib import Path

import numpy as np

from quadson_mjx import gait_pattern
from quadson_mjx import sim2sim as S
from quadson_mjx.robots import get_robot

GAITS = ("walk", "trot", "pace", "bound", "gallop")


def walk_once(policy: Path, seed: int):
    """-> (contact (T, 4), stance (T, 4)) over the tracked steps of one run."""
    adapter = S.LoopAdapter(policy)
    robot = get_robot(adapter.env_config.get("robot", "quadson"))
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, 1_000_003 * seed, False, False)
    rng = np.random.default_rng(seed)  # run_episode's heading draw
    plant.reset((0.0, 0.0), float(rng.uniform(-math.pi, math.pi)))
    adapter.reset(plant.read())
    command, dt = np.asarray(adapter.gait_command), adapter.ctrl_dt
    contact, stance = [], []
    for k in range(int(round(20.0 / dt))):
        out = adapter.step(plant.read(), command, None)
        plant.send(out.motor_targets)
        plant.advance(dt)
        if (k + 1) * dt > S.WARMUP_S + 1e-9:
            contact.append(plant.foot_forces() > gait_pattern.FORCE_THRESHOLD_N)
            stance.append(adapter.scheduled_stance())
        r, p, _ = plant.truth()["rpy"]
        if abs(r) > math.pi / 4 or abs(p) > math.pi / 4:
            break
    return np.array(contact), np.array(stance)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("folder", help="folder of walk.onnx, trot.onnx, ...")
    p.add_argument("--seeds", type=int, default=10)
    a = p.parse_args()
    for g in GAITS:
        contact, stance = zip(
            *(walk_once(Path(a.folder) / f"{g}.onnx", s) for s in range(a.seeds)), strict=True
        )
        ok = np.concatenate(
            [gait_pattern.tolerant_agreement(c, s, 1) for c, s in zip(contact, stance, strict=True)]
        )
        c, s = np.concatenate(contact), np.concatenate(stance)
        miss = ~ok
        swing_touch = np.mean(miss & c & ~s, axis=0) * 100
        stance_up = np.mean(miss & ~c & s, axis=0) * 100
        steps_ok = np.mean(np.all(ok, axis=1)) * 100
        print(
            f"{g:6s} pattern +-1 step {steps_ok:5.1f} % of {len(ok)} steps; misses per foot FL FR RL RR [% of steps]: "
            f"down in swing {' '.join(f'{v:4.1f}' for v in swing_touch)}, up in stance {' '.join(f'{v:4.1f}' for v in stance_up)}",
            flush=True,
        )


if __name__ == "__main__":
    main()
