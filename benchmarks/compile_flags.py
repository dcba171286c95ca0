"""XLA compile time against run time of the environment's programs, per set of XLA flags, in one run.

    python benchmarks/compile_flags.py --out benchmarks/results/compile_flags_h100.json

Each flag set runs in a fresh subprocess (XLA_FLAGS set before jax starts, no persistent
compilation cache) that builds the main job's environment (the train command's default task:
Quadson, flat, seed gait, training physics) and compiles, ahead of time, the three programs that
dominate the main job's compilation: the batched reset (8192 worlds), a 20-step unroll of the
batched step with random actions (8192 worlds; the environment part of brax's training epoch) and a
938-step unroll at 128 worlds (the environment part of brax's evaluator). It prints the seconds of
lowering + compiling each program and the best of 3 timed runs of it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

FLAG_SETS = {
    "default": "",
    "autotune0": "--xla_gpu_autotune_level=0",
    "no_command_buffer": "--xla_gpu_enable_command_buffer=",
    "llvm_cheap": "--xla_llvm_disable_expensive_passes=true",
    "backend_O0": "--xla_backend_optimization_level=0",
}


def child(envs: int, eval_envs: int) -> dict:
    import jax

    from quadson_mjx.env import LocomotionEnv
    from quadson_mjx.env_config import env_config

    env = LocomotionEnv(env_config(base_terrain_contact=False, joint_limits=False))
    out = {"device": jax.devices()[0].device_kind}

    def unroll(n, steps):
        def run(state, key):
            def body(s, k):
                a = jax.random.uniform(k, (n, env.action_size), minval=-1.0, maxval=1.0)
                s = jax.vmap(env.step)(s, a)
                return s, s.reward

            return jax.lax.scan(body, state, jax.random.split(key, steps))

        return run

    reset = jax.vmap(env.reset)
    programs = {
        "reset": (reset, (jax.random.split(jax.random.PRNGKey(0), envs),), None),
        "unroll20": (unroll(envs, 20), None, envs),
        "eval938": (unroll(eval_envs, 938), None, eval_envs),
    }
    for name, (fn, args, n) in programs.items():
        if args is None:
            state = jax.jit(reset)(jax.random.split(jax.random.PRNGKey(0), n))
            args = (state, jax.random.PRNGKey(1))
        t0 = time.perf_counter()
        compiled = jax.jit(fn).lower(*args).compile()
        out[f"{name}_compile_s"] = time.perf_counter() - t0
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*args))
            best = min(best, time.perf_counter() - t0)
        out[f"{name}_run_s"] = best
        print(json.dumps({name: [out[f"{name}_compile_s"], best]}), file=sys.stderr, flush=True)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sets", nargs="+", default=list(FLAG_SETS), choices=list(FLAG_SETS))
    p.add_argument("--envs", type=int, default=8192)
    p.add_argument("--eval-envs", type=int, default=128)
    p.add_argument("--out", default=None)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.envs, args.eval_envs)))
        return
    rows = []
    for name in args.sets:
        env = {
            **os.environ,
            "XLA_FLAGS": (os.environ.get("XLA_FLAGS", "") + " " + FLAG_SETS[name]).strip(),
            "JAX_ENABLE_COMPILATION_CACHE": "false",
        }
        cmd = [
            sys.executable,
            __file__,
            "--child",
            "--envs",
            str(args.envs),
            "--eval-envs",
            str(args.eval_envs),
        ]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            print(f"{name}: failed\n{done.stderr[-2000:]}", flush=True)
            continue
        row = {"flags": name, "xla_flags": FLAG_SETS[name], "process_s": time.perf_counter() - t0}
        row.update(json.loads(done.stdout.strip().splitlines()[-1]))
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.out:
            Path(args.out).write_text(json.dumps(rows, indent=1))
    print(
        "\n| flags | " + " | ".join(f"{p} compile / run [s]" for p in ("reset", "unroll20", "eval938")) + " |"
    )
    print("|---|---:|---:|---:|")
    for r in rows:
        cells = [
            f"{r[f'{p}_compile_s']:.1f} / {r[f'{p}_run_s']:.3f}" for p in ("reset", "unroll20", "eval938")
        ]
        print(f"| {r['flags']} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
