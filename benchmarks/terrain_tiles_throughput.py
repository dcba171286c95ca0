"""Environment steps/s on the tiled ground, per tile type, against flat ground, the stone field and
MuJoCo Playground's feet-only Go1, in one run.

    python benchmarks/terrain_tiles_throughput.py --envs 8192 --steps 100 \
        --go1-scene PATH/scene_mjx_feetonly_flat_terrain.xml --out benchmarks/results/terrain_tiles_h100.json

Every row is the robust preset (the sensor-only joystick recipe: randomization, pushes, the
privileged critic's observation, feet-only contact) as PPO runs it: the training wrappers with domain
randomization and the auto-reset, whose tiled-ground respawn (curriculum and a fresh start on the
tile) runs every step. Actions are uniform in [-0.2, 0.2] (foot offsets of at most 1 cm) around the
gait, so the robots walk and sometimes fall and respawn, as early in training.

The tiled ground is compiled once: its rows differ only in where the robots start (all tile types
mixed, as training draws them, then every robot on one type), each at levels drawn uniformly over
all rows (curriculum off, so the mix stays as drawn). "flat" and "stones" are the plane and the
stone-field scenes. One jitted lax.scan over --steps control steps per row, best of --repeats. The
Go1 row (--go1-scene, see physics_vs_go1.py) is bare physics, the anchor of the other benchmarks.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
from physics_vs_go1 import load_go1, physics_only, run_meta

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.randomize import randomization_fn
from quadson_mjx.tasks import config_from_flags
from quadson_mjx.wrappers import wrap_for_training

ACTION_RANGE = 0.2


def wrapped(terrain: str, n_envs: int):
    cfg = config_from_flags(env_preset="robust", terrain=terrain).unlock()
    if terrain == "tiles":
        cfg.tiles.curriculum = False  # keep each row's mix of levels as drawn
    cfg.lock()
    env = LocomotionEnv(cfg)
    rand = functools.partial(
        randomization_fn(env.config.randomization, env.base_body),
        rng=jax.random.split(jax.random.PRNGKey(1), n_envs),
    )
    return env, wrap_for_training(env, env.episode_length, randomization_fn=rand)


def rollout_fn(env, w, n_envs: int, steps: int):
    """The jitted rollout: (state, key) -> (falls, episode ends) over `steps` control steps."""

    @jax.jit
    def run(state, key):
        def one(carry, k):
            s, falls, resets = carry
            a = jax.random.uniform(k, (n_envs, env.action_size), minval=-ACTION_RANGE, maxval=ACTION_RANGE)
            s = w.step(s, a)
            return (s, falls + jnp.sum(s.metrics["fall"]), resets + jnp.sum(s.done)), None

        init = (state, jnp.zeros(()), jnp.zeros(()))
        (_, falls, resets), _ = jax.lax.scan(one, init, jax.random.split(key, steps))
        return falls, resets

    return run


def timed_rollout(run, state, n_envs: int, steps: int, repeats: int) -> dict:
    t0 = time.perf_counter()
    jax.block_until_ready(run(state, jax.random.PRNGKey(2)))
    first = time.perf_counter() - t0
    best = float("inf")
    for r in range(repeats):
        t0 = time.perf_counter()
        falls, resets = jax.block_until_ready(run(state, jax.random.PRNGKey(3 + r)))
        best = min(best, time.perf_counter() - t0)
    return {
        "env_steps_per_s": n_envs * steps / best,
        "compile_and_first_s": first,
        "falls_per_env_step": float(falls) / (n_envs * steps),
        "episode_ends_per_env_step": float(resets) / (n_envs * steps),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[8192])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--go1-scene", default=None)
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    meta = run_meta(args)
    rows: list[dict] = []

    def record(row):
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.out:
            Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))

    print(f"# {meta}", flush=True)
    for n in args.envs:
        if args.go1_scene:
            go1 = load_go1(args.go1_scene)
            key = mujoco.mj_name2id(go1, mujoco.mjtObj.mjOBJ_KEY, "home")
            record({"robot": "go1_feetonly", "ground": "flat (physics only)", "envs": n,
                    **physics_only(go1, go1.key_qpos[key], go1.key_ctrl[key], n, args.steps, args.repeats)})  # fmt: skip
        for terrain, ground in (("flat", "flat"), ("rough", "stones field")):
            env, w = wrapped(terrain, n)
            state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), n))
            run = rollout_fn(env, w, n, args.steps)
            record({"robot": "quadson", "ground": ground, "envs": n,
                    **timed_rollout(run, state, n, args.steps, args.repeats)})  # fmt: skip
        env, w = wrapped("tiles", n)
        run = rollout_fn(env, w, n, args.steps)  # compiled once for every row of the tiled ground
        spec = env.tiles
        reset_on = jax.jit(w.reset_on_tiles)
        keys = jax.random.split(jax.random.PRNGKey(0), n)
        levels = jax.random.randint(jax.random.PRNGKey(5), (n,), 0, spec.levels)
        mixed = jax.random.randint(jax.random.PRNGKey(6), (n,), 0, len(spec.types))
        for ground, types in (
            ("tiles: all types", mixed),
            *((f"tiles: {t}", i) for i, t in enumerate(spec.types)),
        ):
            state = reset_on(keys, types, levels)
            record({"robot": "quadson", "ground": ground, "envs": n,
                    **timed_rollout(run, state, n, args.steps, args.repeats)})  # fmt: skip
    flat = {r["envs"]: r["env_steps_per_s"] for r in rows if r["ground"] == "flat"}
    go1 = {r["envs"]: r["physics_steps_per_s"] for r in rows if r["robot"] == "go1_feetonly"}
    print("\n| ground | envs | env steps/s | x flat | x Go1 physics | falls per 1000 steps |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        if r["robot"] != "quadson":
            continue
        sps, n = r["env_steps_per_s"], r["envs"]
        vs_go1 = f"{sps / go1[n]:.2f}" if n in go1 else "-"
        print(f"| {r['ground']} | {n} | {sps:,.0f} | {sps / flat[n]:.2f} | {vs_go1} | {1000 * r['falls_per_env_step']:.1f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
