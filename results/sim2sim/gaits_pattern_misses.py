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
from pathlib import Path

import numpy as np

from quadson_mjx import gait_pattern
from quadson_mjx import sim2sim as S
from quadson_mjx.robots import get_robot

GAITS = ("walk", "trot", "pace", "bound", "gallop")


class _Footfalls:
    """A run_episode recorder keeping each tracked step's feet down and the table's stance."""

    def __init__(self, adapter):
        self.adapter, self.contact, self.stance = adapter, [], []

    def step(self, k, plant, readings, out, command, truth, ended):
        if (k + 1) * self.adapter.ctrl_dt > S.WARMUP_S + 1e-9:
            self.contact.append(plant.foot_forces() > gait_pattern.FORCE_THRESHOLD_N)
            self.stance.append(self.adapter.scheduled_stance())


def walk_once(policy: Path, seed: int):
    """-> (contact (T, 4), stance (T, 4)) over the tracked steps of one run (sim2sim.run_one's)."""
    adapter = S.LoopAdapter(policy)
    robot = get_robot(adapter.env_config.get("robot", "quadson"))
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, S.plant_seed_of(seed), False, False)
    feet = _Footfalls(adapter)
    S.run_episode(adapter, plant, ((0.0, adapter.gait_command),), 20.0, seed, feet)
    return np.array(feet.contact), np.array(feet.stance)


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
