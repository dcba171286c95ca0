"""MJX's two implementations, JAX and Warp, on the same models in one run: bare physics throughput
against MuJoCo Playground's feet-only Go1 under each, and how far each strays from MuJoCo C.

    python benchmarks/warp_backend.py --go1-scene PATH/scene_mjx_feetonly_flat_terrain.xml \
        --envs 8192 32768 --out benchmarks/results/warp_backend_h100.json

Rows (--models): Playground's feet-only Go1 (the anchor; see physics_vs_go1.py for the file); the
walking model on flat ground, on the stone field (base box colliding too, or `_feet` only) and on
the tiles (`_feet`), standing at home; the get-up model (every geom collides with the ground) on
flat ground and the stones, from --agree-worlds of the get-up task's own drops (GetupEnv.reset:
0.2-0.5 m, random orientation and motor angles) landed (held 1 s in MuJoCo C, then at rest) and
clear of the ground (landed_starts), repeated to fill the worlds. Protocol as physics_vs_go1.py: 5
physics steps of 4 ms per 0.02 s control step, targets = the start's + N(0, 0.1 rad) drawn every
control step, one jitted lax.scan of --steps control steps (--getup-steps for the get-up rows,
whose JAX rows on the stones are slow), compiled once, best of --repeats.

Warp keeps one contact buffer for all worlds and a fixed number of constraint rows per world; both
are sized here (unless --contacts-per-world / --njmax say): naconmax = worlds x the larger of the
geom pairs that may collide (its broad phase hands them on) and 2 x the most contacts one world had
in MuJoCo C over the agreement run; njmax = 2 x the most constraint rows there (at least 32). A row
whose run filled either is marked "overflow" (contacts or constraints dropped: not valid). Warp
also prints a warning when a geom meets more than the 50 height-field contacts it keeps: look for
"height field collision overflow" in the output.

Agreement: --agree-worlds starts of each model, held at the start's targets for --agree-steps
control steps in MuJoCo C (mj_step) and in MJX under each implementation; the largest difference
of base position [mm] and of joint angle [mrad] against C at the end (Go1 and the walking model
stand: a difference is drift; the get-up model lies on the ground). Prints a markdown table and
rewrites the JSON after every measurement.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from physics_vs_go1 import load_go1, physics_only, recorder, run_meta

from quadson_mjx import tasks
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.env_model import put_model
from quadson_mjx.getup_env import GetupEnv

MODELS = (
    "go1",
    "walk_flat",
    "walk_stones",
    "walk_stones_feet",
    "walk_tiles_feet",
    "getup_flat",
    "getup_stones",
)


def starts(name: str, go1_scene: str | None, n: int) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """-> (model, qpos (n, nq), ctrl (n, nu)) of a row's starts."""
    if name == "go1":
        m = load_go1(go1_scene)
        key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
        return m, np.tile(m.key_qpos[key], (n, 1)), np.tile(m.key_ctrl[key], (n, 1))
    kind, ground, *feet = name.split("_")
    terrain = {"flat": "flat", "stones": "rough", "tiles": "tiles"}[ground]
    if kind == "walk":
        env = LocomotionEnv(env_config(terrain=terrain, base_terrain_contact=not feet))
        m = env.mj_model
        key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, env.robot.home_keyframe)
        qpos = np.tile(m.key_qpos[key], (n, 1))
        if env._field is not None:  # off the stone field's flat patch at the origin
            qpos[:, :2] = np.asarray(env._field.origin[:2]) + 0.3
            qpos[:, 2] += float(env.ground_height(jnp.asarray(qpos[0, :2])))
        return m, qpos, np.tile(m.key_ctrl[key], (n, 1))
    env = GetupEnv(tasks.make_task_config(f"QuadsonGetup{terrain.title()}"))
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n))
    return env._mj_model, np.asarray(state.pipeline_state.qpos), np.asarray(state.pipeline_state.ctrl)


def sunk_m(m: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """(n,) how far the deepest ground-colliding geom's centre lies below the ground under it [m]
    (negative: every centre above it), from the project's height query."""
    from quadson_mjx import terrain

    field = terrain.heightfield(m)
    kinds = (int(mujoco.mjtGeom.mjGEOM_HFIELD), int(mujoco.mjtGeom.mjGEOM_PLANE))
    ground = [g for g in range(m.ngeom) if int(m.geom_type[g]) in kinds]
    parts = [g for g in range(m.ngeom) if g not in ground and any(collide(m, g, f) for f in ground)]
    d = mujoco.MjData(m)
    out = []
    for q in qpos:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        p = d.geom_xpos[parts]
        h = np.asarray(terrain.ground_height(field, jnp.asarray(p[:, :2])))
        out.append(float(np.max(h - p[:, 2])))
    return np.array(out)


def landed_starts(name: str, k: int) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """k of the get-up task's drops landed in MuJoCo C (held 1 s), keeping only those with no geom's
    centre below the ground under it: on the stones MuJoCo C lets a thin link capsule sink through
    the height field as it lands (up to 4 cm, no contact reported), and such a start throws the
    robot out of the ground under either MJX implementation (a first measurement's non-finite
    worlds)."""
    m, qpos, ctrl = starts(name, None, 8 * k)
    qpos = mujoco_c(m, qpos, ctrl, 50)["qpos"]
    clean = np.flatnonzero(sunk_m(m, qpos) <= 0.0)
    if len(clean) < k:
        raise SystemExit(f"{name}: only {len(clean)} of {8 * k} landed drops are clear of the ground")
    return m, qpos[clean[:k]], ctrl[clean[:k]]


def collide(m: mujoco.MjModel, a: int, b: int) -> bool:
    """contype/conaffinity let geoms a and b collide."""
    return bool((m.geom_contype[a] & m.geom_conaffinity[b]) or (m.geom_contype[b] & m.geom_conaffinity[a]))


def candidate_pairs(m: mujoco.MjModel) -> int:
    """How many geom pairs may collide (contype/conaffinity, not within one body, not parent and
    child unless that filter is off, not both on the world body; plus explicit pairs): what Warp's
    broad phase may hand on per world, which its contact buffer must hold."""
    filter_parent = not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    body, parent = m.geom_bodyid, m.body_parentid
    weld = m.body_weldid
    n = int(m.npair)
    for i in range(m.ngeom):
        for j in range(i + 1, m.ngeom):
            bi, bj = body[i], body[j]
            if not collide(m, i, j):
                continue
            if weld[bi] == weld[bj] or (weld[bi] == 0 and weld[bj] == 0):
                continue
            pi, pj = weld[parent[weld[bi]]], weld[parent[weld[bj]]]
            if filter_parent and ((pi == weld[bj] != 0) or (pj == weld[bi] != 0)):
                continue
            n += 1
    return n


def mujoco_c(m: mujoco.MjModel, qpos: np.ndarray, ctrl: np.ndarray, steps: int) -> dict:
    """MuJoCo C from each start, targets held: final qpos, and the most contacts / rows seen."""
    d = mujoco.MjData(m)
    n_sub = round(0.02 / m.opt.timestep)
    final, ncon, nefc = [], 0, 0
    for q, u in zip(qpos, ctrl, strict=True):
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.ctrl[:] = q, u
        for _ in range(steps * n_sub):
            mujoco.mj_step(m, d)
            ncon, nefc = max(ncon, d.ncon), max(nefc, d.nefc)
        final.append(d.qpos.copy())
    return {"qpos": np.array(final), "ncon_max": ncon, "nefc_max": nefc}


def mjx_final(m, qpos, ctrl, steps: int, impl: str, naconmax=None, njmax=None) -> np.ndarray:
    """MJX under `impl` from each start, targets held: final qpos (n, nq)."""
    mx = put_model(m, impl)
    n_sub = round(0.02 / m.opt.timestep)
    if impl == "warp":
        base = mjx.make_data(m, impl="warp", naconmax=naconmax, njmax=njmax)
    else:
        base = mjx.make_data(mx)

    @jax.jit
    def run(q, u):
        d = jax.vmap(lambda q, u: base.replace(qpos=q, ctrl=u))(q, u)
        step = jax.vmap(mjx.step, in_axes=(None, 0))
        d = jax.lax.fori_loop(0, steps * n_sub, lambda _, d: step(mx, d), d)
        return d.qpos

    return np.asarray(run(jnp.asarray(qpos), jnp.asarray(ctrl)))


def difference(a: np.ndarray, b: np.ndarray, m: mujoco.MjModel) -> dict:
    """Base position [mm] and hinge angle [mrad] differences between two (n, nq) sets: the largest,
    the median over worlds, and how many worlds ended non-finite in a."""
    hinge = [m.jnt_qposadr[j] for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    base = 1e3 * np.max(np.abs(a[:, :3] - b[:, :3]), axis=1)
    joint = 1e3 * np.max(np.abs(a[:, hinge] - b[:, hinge]), axis=1)
    return {
        "base_mm": float(np.max(base)),
        "joint_mrad": float(np.max(joint)),
        "base_median_mm": float(np.median(base)),
        "joint_median_mrad": float(np.median(joint)),
        "nonfinite_worlds": int(np.sum(~np.isfinite(a).all(axis=1))),
    }


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--go1-scene", default=None, help="Playground's scene_mjx_feetonly_flat_terrain.xml")
    p.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    p.add_argument("--impls", nargs="+", default=["jax", "warp"], choices=["jax", "warp"])
    p.add_argument("--envs", type=int, nargs="+", default=[8192, 32768])
    p.add_argument("--getup-envs", type=int, nargs="+", default=[8192])
    p.add_argument("--steps", type=int, default=100, help="control steps per timed rollout")
    p.add_argument("--getup-steps", type=int, default=20, help="the same for the get-up rows")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--agree-worlds", type=int, default=16)
    p.add_argument("--agree-steps", type=int, default=50, help="control steps of the agreement run")
    p.add_argument("--contacts-per-world", type=int, default=None, help="Warp's contact buffer per world")
    p.add_argument("--njmax", type=int, default=None, help="Warp's constraint rows per world")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    if "go1" in args.models and not args.go1_scene:
        p.error("the go1 row needs --go1-scene (or leave go1 out of --models)")
    meta = run_meta(args)
    rows, record = recorder(meta, args.out)

    print(f"# {meta}", flush=True)
    for name in args.models:
        getup = name.startswith("getup")
        sizes, steps = (args.getup_envs, args.getup_steps) if getup else (args.envs, args.steps)
        k = args.agree_worlds
        if getup:  # k drops, landed: held 1 s in MuJoCo C, then at rest (qvel 0) on the ground
            m, qpos, ctrl = landed_starts(name, k)
        else:
            m, qpos, ctrl = starts(name, args.go1_scene, k)
        c = mujoco_c(m, qpos, ctrl, args.agree_steps)
        pairs = candidate_pairs(m)
        per_world = args.contacts_per_world or max(2 * c["ncon_max"], pairs, 8)
        njmax = args.njmax or max(2 * c["nefc_max"], 32)
        agree = {}
        for impl in args.impls:
            q = mjx_final(m, qpos, ctrl, args.agree_steps, impl, k * per_world, njmax)
            agree[impl] = difference(q, c["qpos"], m)
        record(
            {
                "model": name,
                "agreement_vs_c": agree,
                "c_ncon_max": c["ncon_max"],
                "c_nefc_max": c["nefc_max"],
                "candidate_pairs": pairs,
            }
        )
        for impl in args.impls:
            for n in sizes:
                reps = -(-n // k)  # the k starts, repeated to n worlds
                q_n, u_n = np.tile(qpos, (reps, 1))[:n], np.tile(ctrl, (reps, 1))[:n]
                out = physics_only(
                    m, q_n, u_n, n, steps, args.repeats, impl=impl, contacts_per_world=per_world, njmax=njmax
                )
                record({"model": name, "impl": impl, "envs": n, "steps": steps, **out})

    anchor = {
        (r["impl"], r["envs"]): r["physics_steps_per_s"]
        for r in rows
        if r.get("model") == "go1" and "impl" in r
    }
    agreement = {r["model"]: r["agreement_vs_c"] for r in rows if "agreement_vs_c" in r}
    print(f"\ndevice: {meta['device']}; control steps of 0.02 s (5 physics steps each)")
    print(
        "| model | impl | envs | physics (ctrl steps/s) | vs Go1, same impl | vs Go1, JAX | warp / jax | "
        "vs C at the end, median / max: base, joints | overflow |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---|---|")
    for r in (r for r in rows if "impl" in r):
        sps = r["physics_steps_per_s"]
        same = anchor.get((r["impl"], r["envs"]))
        jax_go1 = anchor.get(("jax", r["envs"]))
        own_jax = next(
            (
                x["physics_steps_per_s"]
                for x in rows
                if x.get("model") == r["model"] and x.get("impl") == "jax" and x["envs"] == r["envs"]
            ),
            None,
        )
        a = agreement[r["model"]][r["impl"]]
        print(
            f"| {r['model']} | {r['impl']} | {r['envs']} | {sps:,.0f} | "
            f"{f'{sps / same:.2f}x' if same else '-'} | {f'{sps / jax_go1:.2f}x' if jax_go1 else '-'} | "
            f"{f'{sps / own_jax:.2f}x' if own_jax else '-'} | {a['base_median_mm']:.2f} / {a['base_mm']:.2f} mm, "
            f"{a['joint_median_mrad']:.1f} / {a['joint_mrad']:.1f} mrad{', non-finite ' + str(a['nonfinite_worlds']) if a['nonfinite_worlds'] else ''} | "
            f"{'yes' if r.get('overflow') else 'no'}{'; non-finite ' + str(r['nonfinite_worlds']) if r['nonfinite_worlds'] else ''} |"
        )


if __name__ == "__main__":
    main()
