"""The get-up task under MJX's Warp implementation against its JAX implementation, on flat ground
and on the stones: the same drops (GetupEnv.reset, randomization off), the same random actions
(N(0, 0.5) per motor, a new draw every control step), --steps control steps; per ground and
implementation, how many worlds are non-finite at the end and the first step one turned so, the
fullest contact list (Warp: its shared buffer's count against its size; JAX: contacts with negative
distance), and the base's height over the ground. Why the trainer refuses env.impl=warp for the
get-up task on a height field (env_model.check_warp_ground): this script lifts that refusal.

    python benchmarks/warp_getup_ground.py --worlds 4 --steps 40 | tee benchmarks/results/warp_getup_ground_cpu.log

Warp also prints "height field collision overflow" when a geom meets more than the 50 height-field
prisms it keeps per pair; count those lines in the output.

--trace (stones, Warp): the first world whose largest joint speed passes 300 rad/s; from its state
one control step before, MuJoCo C with the same targets (largest speed per control step against
Warp's), and the contacts of Warp's forward pass against MuJoCo C's (geom pairs, distances), with
mj_geomDistance's distance of each geom Warp has touching the floor.

    python benchmarks/warp_getup_ground.py --worlds 4 --steps 40 --trace | tee -a benchmarks/results/warp_getup_ground_cpu.log
"""

from __future__ import annotations

import argparse
import json

import jax
import mujoco
import numpy as np
from mujoco import mjx

from quadson_mjx import env_model, tasks
from quadson_mjx.config import apply_overrides
from quadson_mjx.envs import make_env

TASKS = {"flat": "QuadsonGetupFlat", "stones": "QuadsonGetupRough"}


def _env(ground: str, impl: str, worlds: int):
    """The get-up task's env on `ground` under `impl`, randomization off."""
    cfg = apply_overrides(
        tasks.make_task_config(TASKS[ground]),
        [f"impl={impl}", f"warp_max_worlds={worlds}", "randomize=false"],
    )
    return make_env(cfg)


def _rollout(env, worlds: int, steps: int):
    """Yields (t, state) after each of `steps` control steps from the task's drops (seed 0), the
    actions N(0, 0.5) per motor, drawn with key t at control step t."""
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    s = reset(jax.random.split(jax.random.PRNGKey(0), worlds))
    yield -1, s
    for t in range(steps):
        s = step(s, 0.5 * jax.random.normal(jax.random.PRNGKey(t), (worlds, env.action_size)))
        yield t, s


def run(ground: str, impl: str, worlds: int, steps: int) -> dict:
    env = _env(ground, impl, worlds)
    first_bad, most_contacts, heights = None, 0, []
    for t, s in _rollout(env, worlds, steps):
        if t < 0:
            continue
        d = s.pipeline_state
        finite = np.isfinite(np.asarray(d.qpos)).all(axis=1) & np.isfinite(np.asarray(d.qvel)).all(axis=1)
        if first_bad is None and not finite.all():
            first_bad = t + 1
        if impl == "warp":
            most_contacts = max(most_contacts, int(np.asarray(d._impl.nacon).ravel()[0]))
        else:
            most_contacts = max(most_contacts, int(np.asarray((d._impl.contact.dist < 0).sum(-1)).max()))
        heights.append(np.asarray(d.qpos[:, 2] - env.ground_height(d.qpos[:, :2])))
    h = np.array(heights)
    return {
        "ground": ground,
        "impl": impl,
        "worlds": worlds,
        "steps": steps,
        "nonfinite_worlds": int((~finite).sum()),
        "first_nonfinite_step": first_bad,
        "contacts_most": most_contacts,
        "contact_buffer": env._warp_buffers[0] if impl == "warp" else None,
        "base_height_min_m": float(np.nanmin(h)),
        "base_height_final_m": [round(float(x), 4) for x in h[-1]],
    }


def trace(worlds: int, steps: int, fast: float = 300.0) -> None:
    env = _env("stones", "warp", worlds)
    m = env.mj_model
    states, w = [], None
    for t, s in _rollout(env, worlds, steps):
        states.append(s)
        if t < 0:
            continue
        speed = np.nan_to_num(np.abs(np.asarray(s.pipeline_state.qvel)), nan=np.inf).max(axis=1)
        if w is None and (speed > fast).any():
            w, k = int(np.argmax(speed > fast)), t  # control step k + 1 passed `fast`; start at k
        if w is not None and t >= k + 3:
            break
    if w is None:
        print(json.dumps({"trace": f"no world passed {fast} rad/s in {steps} steps"}))
        return
    lat = int(np.asarray(s.info["latency_steps"])[w])
    sub = env._n_substeps
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = (
        np.asarray(getattr(states[k].pipeline_state, f)[w], np.float64) for f in ("qpos", "qvel")
    )
    c_speed = []
    for j in range(k, len(states) - 1):
        for i in range(sub):
            src = states[j].info["last_ctrl"] if i < lat else states[j + 1].pipeline_state.ctrl
            d.ctrl[:] = np.asarray(src[w], np.float64)
            mujoco.mj_step(m, d)
        c_speed.append(round(float(np.abs(d.qvel).max()), 1))
    warp_speed = [
        round(float(np.abs(np.asarray(x.pipeline_state.qvel[w])).max()), 1) for x in states[k + 1 :]
    ]
    # the contacts at control step k's state: Warp's forward pass (one world) against MuJoCo C's
    one = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 1)).pipeline_state
    at = states[k].pipeline_state
    one = one.replace(qpos=at.qpos[w : w + 1], qvel=at.qvel[w : w + 1], ctrl=at.ctrl[w : w + 1])
    dw = jax.jit(jax.vmap(mjx.forward, in_axes=(None, 0)))(env.sys, one)._impl
    n = int(np.asarray(dw.nacon).ravel()[0])
    geom, dist = np.asarray(dw.contact__geom).reshape(-1, 2)[:n], np.asarray(dw.contact__dist).ravel()[:n]
    d.qpos[:], d.qvel[:] = (np.asarray(getattr(at, f)[w], np.float64) for f in ("qpos", "qvel"))
    mujoco.mj_forward(m, d)
    touching = sorted({int(g) for pair in geom for g in pair if g != 0})
    fromto = np.zeros(6)
    print(json.dumps({
        "trace_world": w, "from_control_step": k,
        "max_joint_speed_warp": warp_speed, "max_joint_speed_mujoco_c": c_speed,
        "contacts_warp": sorted((int(a), int(b), round(float(x), 4)) for (a, b), x in zip(geom, dist, strict=True)),
        "contacts_mujoco_c": sorted((int(c.geom1), int(c.geom2), round(float(c.dist), 4)) for c in d.contact[: d.ncon]),
        "mj_geomDistance_to_floor": {
            f"{g} {mujoco.mjtGeom(m.geom_type[g]).name}": round(mujoco.mj_geomDistance(m, d, 0, g, 0.05, fromto), 4)
            for g in touching
        },
    }))  # fmt: skip


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--worlds", type=int, default=4)
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--grounds", nargs="+", default=["flat", "stones"], choices=sorted(TASKS))
    p.add_argument("--trace", action="store_true", help="only the trace of the first fast world (see above)")
    args = p.parse_args(argv)
    env_model.check_warp_ground = lambda cfg: None  # measure what the refusal is for
    import quadson_mjx.getup_env as getup_env

    getup_env.check_warp_ground = env_model.check_warp_ground
    if args.trace:
        trace(args.worlds, args.steps)
        return
    for ground in args.grounds:
        for impl in ("jax", "warp"):
            print(json.dumps(run(ground, impl, args.worlds, args.steps)), flush=True)


if __name__ == "__main__":
    main()
