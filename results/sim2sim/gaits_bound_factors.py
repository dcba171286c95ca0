"""The bound in MuJoCo C under one randomized factor at a time: which of the trained ranges makes it
fall? Each factor alone (the others at their nominal values), then all together, over the same
plant seeds as `eval/sim2sim.py --commands gait --randomize` (20 s at the gait's command, flat
ground, 20 ms latency, sensor noise on).

    python -m quadson_mjx.export results/gaits/bound /tmp/gaits/bound.onnx
    python results/sim2sim/gaits_bound_factors.py /tmp/gaits/bound.onnx --seeds 10 > results/sim2sim/gaits_bound_factors.log
"""

import argparse

import numpy as np

from quadson_mjx import sim2sim as S
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.robots import get_robot

NOMINAL = {"friction": (0.8, 0.8), "mass_scale": (1.0, 1.0), "motor_strength": (1.0, 1.0), "base_com_shift_m": (0.0, 0.0)}  # fmt: skip


def main():
    p = argparse.ArgumentParser()
    p.add_argument("policy")
    p.add_argument("--seeds", type=int, default=10)
    a = p.parse_args()
    robot = get_robot("quadson")
    env_config = S.LoopAdapter(a.policy).env_config
    full = {**S.DEFAULT_RANDOMIZATION, **env_config.get("randomization", {})}
    print("trained ranges:", {k: full[k] for k in NOMINAL})
    for factor in (*NOMINAL, "all"):
        ranges = dict(full) if factor == "all" else {**NOMINAL, factor: full[factor]}
        falls, pattern = [], []
        for seed in range(a.seeds):
            adapter = S.LoopAdapter(a.policy)
            # run_one's plant seed for the gait command set (schedule 0) on flat ground; a fresh model
            # each run (the plant randomizes its model in place)
            plant = P.Plant(
                robot,
                P.plant_model(robot, "flat"),
                P.ServoParams(latency_s=0.02),
                P.SensorParams(),
                S.plant_seed_of(seed),
                ranges,
                None,
            )
            row = S.run_episode(adapter, plant, ((0.0, adapter.gait_command),), 20.0, seed)
            if row["fell"]:
                falls.append(f"seed {seed} at {row['fall_time_s']:.2f} s")
            pattern.append(row["pattern_1step"] or 0.0)
        print(
            f"{factor:16s} falls {len(falls)}/{a.seeds} ({'; '.join(falls) or '-'}), pattern {np.mean(pattern):.3f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
