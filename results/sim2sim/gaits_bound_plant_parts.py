"""Which of the sim2sim plant's differences from training makes the randomized bound fall? The
plant as eval/sim2sim.py builds it, then with one difference taken back at a time, then all of
them: training's 4 ms timestep (the plant steps 2 ms), no servo deadband, no torque-speed limit (training's position servo has only its peak
torque), feet-only contact (the plant lets every leg link touch the ground). Training's solver
settings cannot be taken back in MuJoCo C: with 1 Newton iteration, 5 line-search iterations and
the pyramidal cone (the plant: 100, 50, elliptic) the plant diverges within 0.1 s (NaN), with
training's Euler integrator or the plant's implicit-fast. Last, the plant as in sim2sim under the ranges of the committed MJX
evaluation (its `--randomization` flags: masses 0.85-1.15, CoM +-2 cm, motors 0.8-1.2, friction
the config's 0.5-1.2), narrower than the bound's training ranges (masses to 1.25, CoM to +3 cm).
With --solver-iterations N (a policy trained with env.solver_iterations N), two more conditions:
the plant integrated as MJX trains, at 4 ms with the Euler integrator, N Newton iterations, 5
line-search iterations and the pyramidal cone ("MJX integration"), alone and with the four
parts. The bound under its trained randomization ranges, 20 s at its gait's
command on flat ground, 20 ms latency, sensor noise on, the plant seeds of
`eval/sim2sim.py --commands gait --randomize` (seed k: the suite's seed k).

    python -m quadson_mjx.export results/gaits/bound /tmp/gaits/bound.onnx
    python results/sim2sim/gaits_bound_plant_parts.py /tmp/gaits/bound.onnx --seeds 30 > results/sim2sim/gaits_bound_plant_parts.log
    python -m quadson_mjx.export results/gaits/transfer/bound /tmp/transfer/bound.onnx
    python results/sim2sim/gaits_bound_plant_parts.py /tmp/transfer/bound.onnx --seeds 30 --solver-iterations 4 \
        > results/gaits/transfer/plant_parts.log
"""

import argparse
import concurrent.futures as cf
import dataclasses
import multiprocessing as mp

import mujoco
import numpy as np

from quadson_mjx import sim2sim as S
from quadson_mjx import sim2sim_model as M
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.robots import get_robot

PARTS = ("timestep_4ms", "no_deadband", "no_speed_limit", "feet_only")
MJX_EVAL_RANGES = {
    "mass_scale": (0.85, 1.15),
    "base_com_shift_m": (-0.02, 0.02),
    "motor_strength": (0.8, 1.2),
}
CONDITIONS = (
    ("plant as in sim2sim", (), None),
    *((f"+ {p}", (p,), None) for p in PARTS),
    ("+ all four", PARTS, None),
    ("MJX evaluation ranges", (), MJX_EVAL_RANGES),
)


def run(args) -> dict:
    policy, parts, override, seed, iterations = args
    robot = get_robot("quadson")
    adapter = S.LoopAdapter(policy)
    model = M.plant_model(robot, "flat", timestep_s=0.004 if "timestep_4ms" in parts else M.TIMESTEP_S)
    if "training_integration" in parts:
        model.opt.timestep = 0.004
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        model.opt.iterations, model.opt.ls_iterations = iterations, 5
        model.opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    if "feet_only" in parts:
        feet = set(robot.foot_geoms())
        for g in range(model.ngeom):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
            if model.geom_bodyid[g] != 0 and name not in feet:
                model.geom_contype[g] = model.geom_conaffinity[g] = 0
    servo = P.ServoParams(latency_s=0.02)
    if "no_deadband" in parts:
        servo = dataclasses.replace(servo, deadband_rad=0.0)
    ranges = {**S.DEFAULT_RANDOMIZATION, **adapter.env_config.get("randomization", {}), **(override or {})}
    plant = P.Plant(robot, model, servo, P.SensorParams(), S.plant_seed_of(seed), ranges, None)
    if "no_speed_limit" in parts:
        plant.no_load_speed = None
    row = S.run_episode(adapter, plant, ((0.0, adapter.gait_command),), 20.0, seed)
    return {"fell": row["fell"], "pattern": row["pattern_1step"] or 0.0, "seed": seed}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("policy")
    p.add_argument("--seeds", type=int, default=30)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--solver-iterations", type=int, default=None)
    a = p.parse_args()
    conditions = CONDITIONS
    if a.solver_iterations:
        conditions += (
            ("+ MJX integration", ("training_integration",), None),
            ("+ all four + MJX int.", (*PARTS, "training_integration"), None),
        )
    with cf.ProcessPoolExecutor(a.workers, mp_context=mp.get_context("spawn")) as ex:
        for name, parts, override in conditions:
            jobs = [(a.policy, parts, override, s, a.solver_iterations) for s in range(a.seeds)]
            rows = list(ex.map(run, jobs))
            fell = [r["seed"] for r in rows if r["fell"]]
            print(
                f"{name:22s} falls {len(fell):2d}/{a.seeds} (seeds {fell}), "
                f"pattern +-1 step {np.mean([r['pattern'] for r in rows]):.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
