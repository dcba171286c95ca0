"""Where the joystick task's time goes on each MJX implementation: the whole environment (gait, IK,
physics, reward, observation, the training wrappers with domain randomization and auto-reset) of
`--task QuadsonJoystickRough --env.obs_history=3`, stepped under random actions as PPO's rollouts
step it, on JAX and on Warp, with one part of the task taken away at a time.

    python benchmarks/warp_task_cost.py --envs 8192 --out benchmarks/results/warp_task_cost_h100.json

Variants (env overrides on the task): "task" as it trains; "no_randomize" (randomize=false: one
nominal model for all worlds, no sensor errors); "no_pushes"; "flat" (terrain=flat instead of the
stone field); "flat_no_randomize" both. `--task main` measures the main job's env instead (flat, no
randomization or pushes: the variants that add those do not apply), `--bare` the env's vmapped
step without the training wrappers. `--fivebar-models` and `--sim-dts` measure each variant with each
five-bar model (full, light) and physics timestep (0: the model's 4 ms). On Warp the stones' feet
take MuJoCo's height-field collider (hfield_foot_contacts=4: the one-contact foot collider is JAX's
only); each row names the value it ran with. Each: one jitted lax.scan of --steps control steps,
compiled once, best of --repeats.

    python benchmarks/warp_task_cost.py --envs 16384 --variants task --impls jax \
        --fivebar-models full light --sim-dts 0.004 0.002 --overrides yaw_error_tau_s=0.5
"""

from __future__ import annotations

import argparse
import json
import types
from pathlib import Path

import jax
from physics_vs_go1 import _best_time, run_meta

from quadson_mjx import env_model, tasks
from quadson_mjx.config import apply_overrides
from quadson_mjx.envs import make_env
from quadson_mjx.wrappers import wrap_for_evaluation

VARIANTS = {
    "task": [],
    "no_randomize": ["randomize=false"],
    "no_pushes": ["pushes=false"],
    "flat": ["terrain=flat"],
    "flat_no_randomize": ["terrain=flat", "randomize=false"],
}


def steps_per_s(cfg, n: int, steps: int, repeats: int, bare: bool = False) -> tuple[float, float]:
    """-> (env steps/s, compile + first run [s]) of n worlds in the training wrappers (bare: the
    env's own step, vmapped, without them)."""
    env = make_env(cfg)
    if bare:
        w = types.SimpleNamespace(reset=jax.vmap(env.reset), step=jax.vmap(env.step))
    else:
        w = wrap_for_evaluation(env, cfg, n, seed=0, steps=env.episode_length)
    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), n))

    @jax.jit
    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (n, env.action_size), minval=-1.0, maxval=1.0)
            return w.step(s, a), None

        state, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state.obs

    best, first = _best_time(rollout, (state, jax.random.PRNGKey(1)), repeats)
    return n * steps / best, first


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[8192])
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--impls", nargs="+", default=["jax", "warp"], choices=["jax", "warp"])
    p.add_argument(
        "--task", choices=["joystick", "main"], default="joystick",
        help="the joystick task (QuadsonJoystickRough, obs_history=3) or the main job's env",
    )  # fmt: skip
    p.add_argument(
        "--overrides", nargs="*", default=[],
        help="env config overrides on top of the task and variant (e.g. observation=sensors)",
    )  # fmt: skip
    p.add_argument("--fivebar-models", nargs="+", default=["full"], choices=["full", "light"])
    p.add_argument(
        "--sim-dts", type=float, nargs="+", default=[0.0], help="physics timesteps [s]; 0: the model's"
    )  # fmt: skip
    p.add_argument("--bare", action="store_true", help="the env's vmapped step without the training wrappers")
    p.add_argument(
        "--graph-mode", default=None, choices=["WARP", "WARP_STAGED"],
        help="how Warp's foreign calls replay their CUDA graphs on a GPU (env_model.WARP_GRAPH_MODE; "
        "default mujoco.mjx's choice: WARP on a GPU)",
    )  # fmt: skip
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    env_model.WARP_GRAPH_MODE = args.graph_mode
    meta = run_meta(args)
    print(f"# {meta}", flush=True)
    rows = []
    cases = [
        (v, f, dt, i)
        for v in args.variants
        for f in args.fivebar_models
        for dt in args.sim_dts
        for i in args.impls
    ]
    for variant, fivebar, dt, impl in cases:
        if args.task == "main":
            base = tasks.config_from_flags()
        else:
            base = apply_overrides(tasks.make_task_config("QuadsonJoystickRough"), ["obs_history=3"])
        cfg = apply_overrides(
            base,
            [
                *VARIANTS[variant], *args.overrides, f"impl={impl}", f"warp_max_worlds={max(args.envs)}",
                f"fivebar_model={fivebar}", f"sim_dt={dt}",
            ],
        )  # fmt: skip
        if impl == "warp" and cfg.get("hfield_foot_contacts", 4) != 4:
            cfg = apply_overrides(cfg, ["hfield_foot_contacts=4"])
        for n in args.envs:
            sps, first = steps_per_s(cfg, n, args.steps, args.repeats, args.bare)
            row = {
                "task": args.task,
                "bare": args.bare,
                "graph_mode": (args.graph_mode or "mjx default") if impl == "warp" else None,
                "variant": variant,
                "overrides": args.overrides,
                "fivebar_model": fivebar,
                "sim_dt": dt,
                "hfield_foot_contacts": cfg.get("hfield_foot_contacts"),
                "impl": impl,
                "envs": n,
                "env_steps_per_s": sps,
                "compile_s": first,
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"\ndevice: {meta['device']}; {args.steps} control steps per timing")
    print("| variant | five-bar | sim_dt [s] | worlds | JAX (env steps/s) | Warp | Warp / JAX |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for variant, fivebar, dt in dict.fromkeys(c[:3] for c in cases):
        for n in args.envs:
            got = {
                r["impl"]: r["env_steps_per_s"]
                for r in rows
                if (r["variant"], r["fivebar_model"], r["sim_dt"], r["envs"]) == (variant, fivebar, dt, n)
            }
            ratio = f"{got['warp'] / got['jax']:.2f}" if len(got) == 2 else "-"
            cells = " | ".join(f"{got[i]:,.0f}" if i in got else "-" for i in ("jax", "warp"))
            print(f"| {variant} | {fivebar} | {dt:g} | {n} | {cells} | {ratio} |")


if __name__ == "__main__":
    main()
