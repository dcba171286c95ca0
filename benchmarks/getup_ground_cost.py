"""What the stones cost the get-up task: env steps/s of jit(vmap(GetupEnv.step)) on flat ground and
on the stone field in one run, and where the heightfield's work comes from.

    python benchmarks/getup_ground_cost.py --envs 64 --steps 20 --out getup_ground.json

MJX collides a geom with a heightfield by testing it against every prism of the heightfield cells
its bounding sphere may touch (a fixed sub-grid per geom, decided when the model is put on the
device), each with the pair's convex collider; against a plane each geom is one analytic test. The
script lists, for the stone field, each geom that touches the ground with its bounding radius, its
sub-grid and its prisms per physics step, then times both grounds (random actions in [-1, 1], one
jitted lax.scan over --steps control steps, compiled once, best of --repeats). Prints a table and
writes JSON.
"""

from __future__ import annotations

import argparse
import json
import platform

import jax
import mujoco
import numpy as np
from env_throughput import _time as best_time  # compiled once, best of repeats

from quadson_mjx import tasks
from quadson_mjx.getup_env import GetupEnv


def heightfield_prisms(m: mujoco.MjModel) -> list[dict]:
    """Each geom that collides with the model's heightfield: its name, type, bounding radius and
    the prisms MJX tests it against per physics step (mjx's collision_driver sub-grid rule)."""
    hfields = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD]
    if not hfields:
        return []
    hg = hfields[0]
    h = m.geom_dataid[hg]
    nrow, ncol = int(m.hfield_nrow[h]), int(m.hfield_ncol[h])
    xtick = 2 * m.hfield_size[h][0] / (ncol - 1)
    ytick = 2 * m.hfield_size[h][1] / (nrow - 1)
    rows = []
    for g in range(m.ngeom):
        touches = (m.geom_contype[g] & m.geom_conaffinity[hg]) or (m.geom_contype[hg] & m.geom_conaffinity[g])
        if g == hg or not touches:
            continue
        rb = float(m.geom_rbound[g])
        xb = min(int(np.ceil(2 * rb / xtick)) + 1, ncol)
        yb = min(int(np.ceil(2 * rb / ytick)) + 1, nrow)
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g])
        rows.append(
            {
                "geom": mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"{body} #{g}",
                "type": mujoco.mjtGeom(m.geom_type[g]).name.removeprefix("mjGEOM_").lower(),
                "rbound_m": rb,
                "subgrid": [xb, yb],
                "prisms": 2 * xb * yb,
            }
        )
    return rows


def steps_per_s(env: GetupEnv, n_envs: int, steps: int, repeats: int) -> float:
    act = env.action_size

    @jax.jit
    def rollout(key):
        state = jax.vmap(env.reset)(jax.random.split(key, n_envs))

        def body(s, k):
            a = jax.random.uniform(k, (n_envs, act), minval=-1.0, maxval=1.0)
            return jax.vmap(env.step)(s, a), None

        s, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
        return s.reward

    return n_envs * steps / best_time(rollout, (jax.random.PRNGKey(0),), repeats)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[64])
    p.add_argument("--steps", type=int, default=20, help="control steps per timed rollout")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default=None, help="JSON file")
    args = p.parse_args(argv)
    envs = {g: GetupEnv(tasks.make_task_config(f"QuadsonGetup{g.title()}")) for g in ("flat", "rough")}
    prisms = heightfield_prisms(envs["rough"]._mj_model)
    print("| geom | type | bounding radius [m] | sub-grid | prisms per physics step |")
    print("|---|---|---:|---|---:|")
    for r in prisms:
        print(
            f"| {r['geom']} | {r['type']} | {r['rbound_m']:.3f} | {r['subgrid'][0]}x{r['subgrid'][1]} | {r['prisms']} |"
        )
    print(f"| all {len(prisms)} | | | | {sum(r['prisms'] for r in prisms)} |\n")
    device = jax.devices()[0].device_kind
    print(f"device: {device}; {args.steps} control steps per rollout, best of {args.repeats}")
    print("| worlds | flat [env steps/s] | stones [env steps/s] | stones / flat |")
    print("|---:|---:|---:|---:|")
    rows = []
    for n in args.envs:
        flat = steps_per_s(envs["flat"], n, args.steps, args.repeats)
        rough = steps_per_s(envs["rough"], n, args.steps, args.repeats)
        rows.append({"envs": n, "flat": flat, "stones": rough, "ratio": rough / flat})
        print(f"| {n} | {flat:,.0f} | {rough:,.0f} | {rough / flat:.3f} |", flush=True)
    if args.out:
        meta = {"device": device, "host": platform.node(), "steps": args.steps, "repeats": args.repeats}
        with open(args.out, "w") as f:
            json.dump({**meta, "prisms": prisms, "throughput": rows}, f, indent=1)


if __name__ == "__main__":
    main()
