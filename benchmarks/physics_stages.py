"""Where an MJX physics step spends its time: each stage of `mjx.step`, per robot, in one run.

    python benchmarks/physics_stages.py --go1-scene PATH/scene_mjx_feetonly_flat_terrain.xml \
        --envs 32768 --out benchmarks/results/physics_stages_h100.json

Models: Playground's feet-only Go1 (as `physics_vs_go1.py` loads it, sensors on, as Playground
trains it) and each robot's training physics (`LocomotionEnv`'s model under the train script's
FAST_PHYSICS: feet-only contact, no joint-limit rows, sensors off), plus --variants of Quadson's
solver settings, and with --terrains Quadson's training model on the stone field ("rough") and
the tiled ground ("tiles"), where the feet meet MJX's height-field collider instead of a plane
(each foot sphere against the field's prisms under it, up to 4 contacts a foot: the rows "hfield
prisms per foot" and ncon / nefc say how many; the walking tasks on rough ground now make one
contact a foot instead, env.hfield_foot_contacts=1, which this script leaves out). For each model: N worlds are stepped 50 control steps from home with noisy
position targets (as `physics_vs_go1.py`; on a height field from where the env's reset puts the robot
on the ground), so contacts and the closure are active; then every
stage of MJX's step (the functions `mjx.step` calls, in its order) is timed alone on that batch:
one jit running the stage --repeat times in a `fori_loop` over its own output (no loop-invariant
hoisting), best of 3. Stages fused inside `mjx.step` can cost less there than alone; the row
"step" is the whole step timed the same way. Prints a markdown table of ns per world per physics
step; the JSON is rewritten after every model.
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, constraint, forward, sensor, smooth, solver
from physics_vs_go1 import NOISE_RAD, load_go1, run_meta

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.tasks import FAST_PHYSICS

# The training physics of every task (quadson_mjx.tasks.FAST_PHYSICS).
TRAINING = FAST_PHYSICS

# name -> change of Quadson's training model (MjModel attribute path -> value)
VARIANTS = {
    "ls3": {"opt.ls_iterations": 3},
    "ls1": {"opt.ls_iterations": 1},
    "cg": {"opt.solver": int(mujoco.mjtSolver.mjSOL_CG)},
    "sparse": {"opt.jacobian": int(mujoco.mjtJacobian.mjJAC_SPARSE)},
    "cg_sparse": {
        "opt.solver": int(mujoco.mjtSolver.mjSOL_CG),
        "opt.jacobian": int(mujoco.mjtJacobian.mjJAC_SPARSE),
    },
    "noeq": {"eq_active0": 0},
}


def stages(m: mjx.Model):
    """(name, fn(d) -> d) in the order mjx.step runs them (mujoco-mjx 3.x forward.py)."""

    def velocity(d):
        d = d.tree_replace(
            {
                "_impl.actuator_velocity": d._impl.actuator_moment @ d.qvel,
                "_impl.ten_velocity": d._impl.ten_J @ d.qvel,
            }
        )
        return d

    out = [
        ("noop", lambda m, d: d.replace(time=d.time + 1.0)),  # the loop's own cost, the floor
        ("kinematics", smooth.kinematics),
        ("com_pos", smooth.com_pos),
        ("crb", smooth.crb),
        ("factor_m", smooth.factor_m),
        ("collision", collision_driver.collision),
        ("make_constraint", constraint.make_constraint),
        ("transmission", smooth.transmission),
        ("sensor_pos", sensor.sensor_pos),
        ("velocity", lambda m, d: velocity(d)),
        ("com_vel", smooth.com_vel),
        ("passive", forward.passive.passive),
        ("rne", smooth.rne),
        ("sensor_vel", sensor.sensor_vel),
        ("fwd_actuation", forward.fwd_actuation),
        ("fwd_acceleration", forward.fwd_acceleration),
        ("solve", solver.solve),
        ("sensor_acc", sensor.sensor_acc),
        ("euler", forward.euler),
        ("step", mjx.step),
    ]
    return [(name, lambda d, f=f: f(m, d)) for name, f in out]


def settle(mx: mjx.Model, qpos0, ctrl0, n: int, steps: int = 50) -> mjx.Data:
    """n worlds after `steps` control steps of 5 physics steps with noisy targets around ctrl0."""
    ctrl0 = jnp.asarray(ctrl0)

    def one(_):
        return mjx.forward(mx, mjx.make_data(mx).replace(qpos=jnp.asarray(qpos0), ctrl=ctrl0))

    @jax.jit
    def run(d, key):
        def ctrl_step(d, k):
            d = d.replace(ctrl=ctrl0 + NOISE_RAD * jax.random.normal(k, (n, ctrl0.shape[0])))
            d, _ = jax.lax.scan(lambda d, _: (jax.vmap(mjx.step, in_axes=(None, 0))(mx, d), None), d, None, 5)
            return d, None

        return jax.lax.scan(ctrl_step, d, jax.random.split(key, steps))[0]

    return run(jax.jit(jax.vmap(one))(jnp.arange(n)), jax.random.PRNGKey(0))


def time_stage(fn, d, repeat: int) -> tuple[float, float]:
    """-> (best seconds per application over 3 timed runs, compile + first run [s])."""

    @jax.jit
    def loop(d):
        return jax.lax.fori_loop(0, repeat, lambda i, d: jax.vmap(fn)(d), d)

    t0 = time.perf_counter()
    jax.block_until_ready(loop(d))
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(loop(d))
        best = min(best, time.perf_counter() - t0)
    return best / repeat, first


def hfield_prisms_per_foot(m: mujoco.MjModel) -> int:
    """The prisms MJX's height-field collider tests per geom it collides with the field: 2 per cell
    of the subgrid MJX's collision driver sizes for the pair; 0 without a height-field pair."""
    sizes = [
        key.subgrid_size
        for key in collision_driver._geom_groups(m)
        if int(key.types[0]) == int(mujoco.mjtGeom.mjGEOM_HFIELD)
    ]
    return max((2 * x * y for x, y in sizes), default=0)


def model_info(m: mujoco.MjModel, d: mjx.Data) -> dict:
    return {
        "nv": int(m.nv),
        "nbody": int(m.nbody),
        "ngeom": int(m.ngeom),
        "nsite": int(m.nsite),
        "neq": int(m.neq),
        "nefc": int(d._impl.efc_J.shape[-2]),
        "ncon": int(d._impl.contact.dist.shape[-1]),
        "hfield_cells": int(m.hfield_nrow[0] * m.hfield_ncol[0]) if m.nhfield else 0,
        "sensors": not bool(m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_SENSOR),
        "solver": int(m.opt.solver),
        "ls_iterations": int(m.opt.ls_iterations),
    }


def set_attr(m: mujoco.MjModel, path: str, value) -> None:
    obj, *rest = path.split(".")
    if rest:
        setattr(getattr(m, obj), rest[0], value)
    else:
        getattr(m, obj)[:] = value


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--go1-scene", default=None, help="Playground's scene_mjx_feetonly_flat_terrain.xml")
    p.add_argument("--robots", nargs="+", default=["quadson", "caramel"])
    p.add_argument("--variants", nargs="*", default=[], choices=list(VARIANTS))
    p.add_argument(
        "--terrains",
        nargs="*",
        default=[],
        choices=["rough", "tiles"],
        help="also Quadson's training model on these grounds (height fields)",
    )
    p.add_argument("--envs", type=int, default=32768)
    p.add_argument("--repeat", type=int, default=20, help="stage applications per timed call")
    p.add_argument(
        "--variant-stages",
        nargs="+",
        default=["noop", "factor_m", "make_constraint", "fwd_acceleration", "solve", "euler", "step"],
        help="stages timed for the --variants (all stages for the base models)",
    )
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    meta = run_meta(args)
    print(f"# {meta}", flush=True)
    models: list[tuple] = []  # (name, MjModel, qpos0, ctrl0, stages to time or None: all)
    if args.go1_scene:
        go1 = load_go1(args.go1_scene)
        key = mujoco.mj_name2id(go1, mujoco.mjtObj.mjOBJ_KEY, "home")
        models.append(("go1_feetonly", go1, go1.key_qpos[key], go1.key_ctrl[key], None))
    for robot in args.robots:
        env = LocomotionEnv(env_config(robot=robot, **TRAINING))
        m = env.mj_model
        key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, env.robot.home_keyframe)
        models.append((robot, m, m.key_qpos[key], m.key_ctrl[key], None))
        if robot == "quadson":
            for v in args.variants:
                mv = copy.deepcopy(m)  # the training model, changed below
                for path, value in VARIANTS[v].items():
                    set_attr(mv, path, value)
                models.append((f"quadson_{v}", mv, m.key_qpos[key], m.key_ctrl[key], args.variant_stages))
            for terrain in args.terrains:
                env_t = LocomotionEnv(env_config(robot=robot, terrain=terrain, **TRAINING))
                qpos0 = np.asarray(jax.jit(env_t.reset)(jax.random.PRNGKey(0)).pipeline_state.qpos)
                models.append((f"quadson_{terrain}", env_t.mj_model, qpos0, m.key_ctrl[key], None))
    rows = []
    for name, m, qpos0, ctrl0, only in models:
        mx = mjx.put_model(m)
        d = settle(mx, qpos0, ctrl0, args.envs)
        row = {"model": name, **model_info(m, d), "envs": args.envs, "ns": {}, "compile_s": {}}
        row["hfield_prisms_per_foot"] = hfield_prisms_per_foot(m)
        for stage, fn in stages(mx):
            if only is not None and stage not in only:
                continue
            best, first = time_stage(fn, d, args.repeat)
            row["ns"][stage] = best / args.envs * 1e9
            row["compile_s"][stage] = first
            print(f"{name:>16} {stage:>16} {row['ns'][stage]:8.2f} ns/world-step", flush=True)
        rows.append(row)
        if args.out:
            Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    names = [r["model"] for r in rows]
    print("\n| stage | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for stage in rows[0]["ns"]:
        print(
            f"| {stage} | "
            + " | ".join(f"{r['ns'][stage]:.2f}" if stage in r["ns"] else "" for r in rows)
            + " |"
        )
    for key in ("nv", "nbody", "nefc", "ncon", "hfield_prisms_per_foot"):
        print(f"| {key} | " + " | ".join(str(r[key]) for r in rows) + " |")


if __name__ == "__main__":
    main()
