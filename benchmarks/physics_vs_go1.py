"""Our robots' MJX physics against MuJoCo Playground's feet-only Go1, in one run, per physics setting.

    python benchmarks/physics_vs_go1.py --go1-scene PATH/scene_mjx_feetonly_flat_terrain.xml \
        --envs 8192 32768 --out benchmarks/results/physics_vs_go1_h100.json

The anchor is Playground's `go1_mjx_feetonly.xml` flat scene (not part of this project: pass the path
of a checkout's `mujoco_playground/_src/locomotion/go1/xmls/scene_mjx_feetonly_flat_terrain.xml`;
its visual meshes, contype 0 and massless, are dropped so no mesh files are needed). Both robots run
the same protocol: N worlds, 0.02 s control steps (5 physics steps of 4 ms; 10 of 2 ms in the
settings and Go1 rows of a 2 ms timestep, --go1-timesteps), position targets =
home + N(0, 0.1 rad) drawn every control step; one jitted lax.scan over --steps control steps,
compiled once, best of --repeats timed runs.

Each setting (a change of the environment's model, see SETTINGS) of each robot (--robots: quadson,
caramel) is measured twice:
physics only as above, and the full environment (gait + IK + physics + reward + observation,
`jit(vmap(env.step))`) under the gait with actions drawn uniform in [-0.2, 0.2] (foot offsets of at
most 1 cm), which also reports the five-bar closure residual (max over worlds and control steps
of the distance between each leg's two p3 sites; 0 for Caramel, which has no loops) and the share
of worlds that fell. Prints a
markdown table; the JSON is rewritten after every measurement.

--impls jax warp measures every row (Go1's too) on both of MJX's implementations; "vs Go1" is
against Go1 on the JAX implementation (the anchor of every earlier run).

The setting rough_feet_only_nolimit_1contact collides each foot with the stone field's height field
into one contact (the surface's nearest point) instead of MJX's up to four (env.hfield_foot_contacts=1;
JAX only): what MJX's prism tests and the extra contacts cost.

--fivebar-models full light measures each setting on both of Quadson's leg models (env.fivebar_model;
the light one's rows are named SETTING+light); robots without that model (Caramel) are skipped for it.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from quadson_mjx import env_model, hfield_contact, warp_build
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.robots import ROBOT_NAMES, get_robot

NOISE_RAD = 0.1
ACTION_RANGE = 0.2

# name -> env config overrides; "env" is the environment's model as the seed preset runs it.
SETTINGS: dict[str, dict] = {
    "env": {},
    "feet_only": {"base_terrain_contact": False},
    "feet_only_nolimit": {"base_terrain_contact": False, "joint_limits": False},
    "feet_only_elliptic": {"base_terrain_contact": False, "cone": "elliptic"},
    "feet_only_nolimit_elliptic": {"base_terrain_contact": False, "joint_limits": False, "cone": "elliptic"},
    "feet_only_nolimit_cg": {"base_terrain_contact": False, "joint_limits": False, "solver": "cg"},
    "feet_only_nolimit_sparse": {"base_terrain_contact": False, "joint_limits": False, "jacobian": "sparse"},
    "feet_only_nolimit_cg_sparse": {
        "base_terrain_contact": False,
        "joint_limits": False,
        "solver": "cg",
        "jacobian": "sparse",
    },
    # the training physics at the 2 ms step of the robot's policies (10 physics steps per control step)
    "feet_only_nolimit_dt2": {"base_terrain_contact": False, "joint_limits": False, "sim_dt": 0.002},
    # the same on the stone field (its height field in the model; every world starts at home)
    "rough_feet_only_nolimit": {"terrain": "rough", "base_terrain_contact": False, "joint_limits": False},
    "rough_feet_only_nolimit_dt2": {
        "terrain": "rough",
        "base_terrain_contact": False,
        "joint_limits": False,
        "sim_dt": 0.002,
    },
    # the stone field with one contact per foot instead of MJX's up to four
    "rough_feet_only_nolimit_1contact": {
        "terrain": "rough",
        "base_terrain_contact": False,
        "joint_limits": False,
        "hfield_foot_contacts": 1,
    },
}

# Go1 rows: its sensors read after every control step (as Playground's env reads them), computed but
# never read (the protocol of this script's earlier runs: only qpos leaves the jitted rollout, and XLA
# drops the sensor work nothing reads), or switched off.
GO1_SENSORS = ("read", "unread", "off")


def _best_time(fn, args, repeats: int) -> tuple[float, float]:
    """-> (best wall time of `repeats` runs, compile + first run) [s]."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best, first


def run_meta(args) -> dict:
    """What a result depends on: the device, the versions and the command's arguments."""
    return {
        "device": jax.devices()[0].device_kind,
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
        "args": vars(args),
    }


def recorder(meta: dict, out: str | None):
    """-> (rows, record): record(row) appends the row, prints it as JSON and rewrites `out` (when
    given) with meta and every row so far, so a run stopped by a time limit keeps what it measured."""
    rows: list[dict] = []

    def record(row: dict) -> None:
        rows.append(row)
        print(json.dumps(row), flush=True)
        if out:
            Path(out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))

    return rows, record


def load_go1(scene: str) -> mujoco.MjModel:
    """Playground's feet-only Go1 scene without its visual meshes (collision-free, massless). Its
    height-field and texture files are found beside the scene (Playground passes them as assets;
    the scene's meshdir points into a Menagerie checkout)."""
    spec = mujoco.MjSpec.from_file(scene)
    for asset in (*spec.hfields, *spec.textures):
        if asset.file:
            asset.file = str((Path(scene).parent / asset.file).resolve())
    for g in list(spec.geoms):
        if g.type == mujoco.mjtGeom.mjGEOM_MESH:
            spec.delete(g)
    for m in list(spec.meshes):
        spec.delete(m)
    return spec.compile()


def physics_only(
    m: mujoco.MjModel,
    qpos0,
    ctrl0,
    n_envs: int,
    steps: int,
    repeats: int,
    read_sensors: bool = True,
    impl: str = "jax",
    contacts_per_world: int | None = None,
    njmax: int | None = None,
) -> dict:
    """Control steps/s of bare MJX stepping with noisy position targets around ctrl0.

    qpos0 (nq,) or (n_envs, nq) and ctrl0 (nu,) or (n_envs, nu): one start for all worlds or one
    each. read_sensors: the rollout returns the sensor values of every control step (their sum), so
    they are computed as an env that reads them would; False returns only the final qpos, and XLA
    then drops the sensors' work (the earlier protocol). impl "warp": Warp's one contact buffer
    holds n_envs x contacts_per_world contacts, each world njmax constraint rows; the result says
    whether a step filled either ("overflow": contacts or constraints dropped)."""
    mx = env_model.put_model(m, impl)
    n_sub = round(0.02 / m.opt.timestep)
    qpos0, ctrl0 = jnp.asarray(qpos0), jnp.asarray(ctrl0)
    if impl == "warp":
        naconmax = n_envs * contacts_per_world
        base = mjx.make_data(m, impl="warp", naconmax=naconmax, njmax=njmax)
        warp_build.start(m, (naconmax, njmax)).wait()  # the kernels built in parallel, not timed
    else:
        base = mjx.make_data(mx)

    def one_world(q, u):
        return mjx.forward(mx, base.replace(qpos=q, ctrl=u))

    @jax.jit
    def rollout(data, key):
        def ctrl_step(d, k):
            d = d.replace(ctrl=ctrl0 + NOISE_RAD * jax.random.normal(k, (n_envs, ctrl0.shape[-1])))

            def sub(d, _):
                d = jax.vmap(mjx.step, in_axes=(None, 0))(mx, d)
                fill = (jnp.max(d._impl.nacon), jnp.max(d._impl.nefc)) if impl == "warp" else (0, 0)
                return d, fill

            d, fill = jax.lax.scan(sub, d, None, length=n_sub)
            fill = tuple(jnp.max(f) for f in fill)
            return d, (jnp.sum(d.sensordata) if read_sensors else 0.0, fill)

        data, (sensed, fill) = jax.lax.scan(ctrl_step, data, jax.random.split(key, steps))
        fill = tuple(jnp.max(f) for f in fill)
        return (data.qpos, sensed, fill) if read_sensors else (data.qpos, fill)

    q_axis, u_axis = (0 if qpos0.ndim == 2 else None), (0 if ctrl0.ndim == 2 else None)
    qs = qpos0 if q_axis == 0 else jnp.broadcast_to(qpos0, (n_envs, m.nq))
    us = ctrl0 if u_axis == 0 else jnp.broadcast_to(ctrl0, (n_envs, m.nu))
    data = jax.jit(jax.vmap(one_world))(qs, us)
    best, first = _best_time(rollout, (data, jax.random.PRNGKey(1)), repeats)
    out = {"physics_steps_per_s": n_envs * steps / best, "physics_compile_s": first - best}
    result = rollout(data, jax.random.PRNGKey(1))
    out["nonfinite_worlds"] = int(jnp.sum(~jnp.all(jnp.isfinite(result[0]), axis=1)))
    if impl == "warp":
        nacon, nefc = (int(x) for x in result[-1])
        out.update(naconmax=naconmax, nacon_max=nacon, njmax=njmax, nefc_max=nefc)
        out["overflow"] = nacon >= naconmax or nefc >= njmax
    return out


def env_under_gait(env: LocomotionEnv, n_envs: int, steps: int, repeats: int) -> dict:
    """Env steps/s, closure residual [m] and fallen share under the gait with small offsets."""
    closure = env.robot.closure_residual
    step = jax.vmap(env.step)
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n_envs))

    @jax.jit
    def rollout(state, key):
        def body(carry, k):
            s, res, fell = carry
            a = jax.random.uniform(k, (n_envs, env.action_size), minval=-ACTION_RANGE, maxval=ACTION_RANGE)
            s = step(s, a)
            if closure is None:
                r = jnp.zeros(n_envs)
            else:
                r = jax.vmap(lambda x: jnp.max(closure(env.mj_model, x)))(s.pipeline_state.site_xpos)
            return (s, jnp.maximum(res, r), fell | (s.done > 0)), None

        init = (state, jnp.zeros(n_envs), jnp.zeros(n_envs, bool))
        (state, res, fell), _ = jax.lax.scan(body, init, jax.random.split(key, steps))
        return res, fell

    best, first = _best_time(rollout, (state, jax.random.PRNGKey(1)), repeats)
    res, fell = rollout(state, jax.random.PRNGKey(1))
    return {
        "env_steps_per_s": n_envs * steps / best,
        "env_compile_s": first - best,
        "closure_residual_max_m": float(jnp.max(res)),
        "closure_residual_p99_m": float(jnp.percentile(res, 99)),
        "fell_frac": float(jnp.mean(fell)),
    }


def _warp_sizes(m: mujoco.MjModel, impl: str) -> dict:
    """physics_only's Warp buffer arguments for m: the environment's own (env_model.warp_buffers)."""
    if impl != "warp":
        return {}
    contacts, rows = env_model.warp_buffers(m, 1)
    return {"contacts_per_world": contacts, "njmax": rows}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--go1-scene", default=None, help="Playground's scene_mjx_feetonly_flat_terrain.xml")
    p.add_argument(
        "--go1-sensors",
        nargs="+",
        default=["read"],
        choices=GO1_SENSORS,
        help="Go1 rows: sensors read every control step, computed but unread (dropped by XLA), or off",
    )
    p.add_argument(
        "--go1-timesteps",
        type=float,
        nargs="+",
        default=[0.0],
        help="Go1's physics timesteps [s] (0: its scene's 4 ms); the first is the anchor of 'vs Go1'",
    )
    p.add_argument("--envs", type=int, nargs="+", default=[8192, 32768])
    p.add_argument("--steps", type=int, default=100, help="control steps per timed rollout")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    p.add_argument(
        "--robots", nargs="*", default=["quadson"], choices=list(ROBOT_NAMES), help="none: Go1 only"
    )
    p.add_argument(
        "--fivebar-models",
        nargs="+",
        default=["full"],
        choices=["full", "light"],
        help="env.fivebar_model values to measure (light: Quadson's link 4 as a fixed-length tendon)",
    )
    p.add_argument(
        "--impls",
        nargs="+",
        default=["jax"],
        choices=["jax", "warp"],
        help="MJX implementations (env.impl) to measure every row on, Go1's included (warp: warp-lang)",
    )
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    meta = run_meta(args)
    rows, record = recorder(meta, args.out)

    print(f"# {meta}", flush=True)
    if args.go1_scene:
        go1 = load_go1(args.go1_scene)
        key = mujoco.mj_name2id(go1, mujoco.mjtObj.mjOBJ_KEY, "home")
        for sensors, impl, dt in (
            (s, i, t) for t in args.go1_timesteps for s in args.go1_sensors for i in args.impls
        ):
            m = load_go1(args.go1_scene)
            if sensors == "off":
                m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
            if dt > 0.0:
                m.opt.timestep = dt
            setting = f"sensors_{sensors}" + ("" if dt == args.go1_timesteps[0] else f"_dt{dt:g}")
            for n in args.envs:
                out = physics_only(
                    m, go1.key_qpos[key], go1.key_ctrl[key], n, args.steps, args.repeats, sensors == "read",
                    impl=impl, **_warp_sizes(m, impl),
                )  # fmt: skip
                row = {"robot": "go1_feetonly", "setting": setting, "impl": impl, "envs": n}
                record({**row, "timestep_s": float(m.opt.timestep), **out})
    for robot, name, fivebar, impl in (
        (r, s, f, i)
        for r in args.robots
        for f in args.fivebar_models
        for s in args.settings
        for i in args.impls
    ):
        if fivebar not in get_robot(robot).model_variants:
            continue
        if SETTINGS[name].get("hfield_foot_contacts", 4) != 4 and impl != "jax":
            continue
        cfg = env_config(robot=robot)
        for key, value in {**SETTINGS[name], "fivebar_model": fivebar, "impl": impl}.items():
            cfg[key] = value
        cfg.warp_max_worlds = max(args.envs)
        # the env makes its data and steps under its own setting; bare physics under the same
        with hfield_contact.sphere_contacts(cfg.hfield_foot_contacts):
            env = LocomotionEnv(cfg)
            m = env.mj_model
            if env.warp_buffers is not None:
                warp_build.start(m, env.warp_buffers).wait()
            home = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, env.robot.home_keyframe)
            dx = mjx.make_data(m)
            setting = name if fivebar == "full" else f"{name}+{fivebar}"
            for n in args.envs:
                row = {
                    "robot": robot,
                    "setting": setting,
                    "impl": impl,
                    "envs": n,
                    "timestep_s": float(m.opt.timestep),
                    "nv": m.nv,
                    "nefc": int(dx._impl.efc_J.shape[0]),
                }
                row.update(
                    physics_only(m, m.key_qpos[home], m.key_ctrl[home], n, args.steps, args.repeats, impl=impl,
                                 **_warp_sizes(m, impl))
                )  # fmt: skip
                row.update(env_under_gait(env, n, args.steps, args.repeats))
                record(row)

    anchor = {
        r["envs"]: r["physics_steps_per_s"]
        for r in rows
        if r["robot"] == "go1_feetonly"
        and r["setting"] == f"sensors_{args.go1_sensors[0]}"
        and r.get("impl", "jax") == "jax"
    }
    print(
        f"\ndevice: {meta['device']}; {args.steps} control steps of 0.02 s (0.02 s / timestep physics steps each)"
    )
    print(f"vs Go1: against Go1 with sensors {args.go1_sensors[0]} on MJX's JAX implementation")
    print(
        "| robot | setting | impl | timestep | envs | nv | constraint rows | physics (ctrl steps/s) | vs Go1 | env (steps/s) | closure max | fell |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        ratio = f"{r['physics_steps_per_s'] / anchor[r['envs']]:.2f}x" if r["envs"] in anchor else "-"
        env_sps = f"{r['env_steps_per_s']:,.0f}" if "env_steps_per_s" in r else "-"
        res = f"{1e3 * r['closure_residual_max_m']:.2f} mm" if "closure_residual_max_m" in r else "-"
        fell = f"{100 * r['fell_frac']:.1f} %" if "fell_frac" in r else "-"
        print(
            f"| {r['robot']} | {r['setting']} | {r.get('impl', 'jax')} | {1e3 * r.get('timestep_s', 0.004):g} ms | {r['envs']} | {r.get('nv', '-')} | {r.get('nefc', '-')} | "
            f"{r['physics_steps_per_s']:,.0f} | {ratio} | {env_sps} | {res} | {fell} |"
        )


if __name__ == "__main__":
    main()
