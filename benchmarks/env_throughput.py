"""Environment throughput: full env steps/s (gait + IK + physics + reward + observation) against
physics-only stepping of the same model, in one run, so the environment's overhead is visible.

    python benchmarks/env_throughput.py --envs 1024 8192 32768 --steps 200 --out env.json

For each batch size B: (1) physics only: B worlds, 5 physics steps per control step, position
targets = home + N(0, 0.1 rad); (2) env: jit(vmap(env.step)) with uniform random actions in [-1, 1];
(3) env + training wrappers (episode limit, auto-reset with per-episode resampling), as PPO runs it.
Each is one jitted lax.scan over --steps control steps; compiled once, timed over --repeats runs
(best taken). Prints a markdown table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax
from mujoco import mjx

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.wrappers import wrap_for_training


def _time(fn, args, repeats):
    out = fn(*args)
    jax.block_until_ready(out)  # compile + first run
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def physics_only(env: LocomotionEnv, n_envs: int, steps: int, repeats: int) -> float:
    sys_ = env.sys
    n_sub = env._n_substeps
    home_q, home_u = env._home_qpos, env._home_ctrl

    def one_world(key):
        d = mjx.make_data(sys_).replace(qpos=home_q, ctrl=home_u)
        return mjx.forward(sys_, d)

    @jax.jit
    def rollout(data, key):
        def ctrl_step(carry, k):
            d = carry
            u = home_u + 0.1 * jax.random.normal(k, (n_envs, home_u.shape[0]))
            d = d.replace(ctrl=u)

            def sub(d, _):
                return jax.vmap(mjx.step, in_axes=(None, 0))(sys_, d), None

            d, _ = jax.lax.scan(sub, d, None, length=n_sub)
            return d, None

        data, _ = jax.lax.scan(ctrl_step, data, jax.random.split(key, steps))
        return data.qpos

    data = jax.jit(jax.vmap(one_world))(jax.random.split(jax.random.PRNGKey(0), n_envs))
    return _time(rollout, (data, jax.random.PRNGKey(1)), repeats)


def env_steps(env, n_envs: int, steps: int, repeats: int, wrapped: bool) -> float:
    if wrapped:
        w = wrap_for_training(env, episode_length=env.episode_length)
        reset, step = jax.jit(w.reset), w.step
    else:
        reset, step = jax.jit(jax.vmap(env.reset)), jax.vmap(env.step)
    state = reset(jax.random.split(jax.random.PRNGKey(0), n_envs))

    @jax.jit
    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (n_envs, env.action_size), minval=-1.0, maxval=1.0)
            return step(s, a), None

        state, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state.obs

    return _time(rollout, (state, jax.random.PRNGKey(1)), repeats)


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--envs", type=int, nargs="+", default=[1024, 8192, 32768])
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-wrapped", action="store_true")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    env = LocomotionEnv(env_config())
    device = jax.devices()[0].device_kind
    rows = []
    for n in args.envs:
        t_phys = physics_only(env, n, args.steps, args.repeats)
        t_env = env_steps(env, n, args.steps, args.repeats, wrapped=False)
        t_wrap = None if args.no_wrapped else env_steps(env, n, args.steps, args.repeats, wrapped=True)
        row = {
            "envs": n,
            "physics_steps_per_s": n * args.steps / t_phys,
            "env_steps_per_s": n * args.steps / t_env,
            "wrapped_env_steps_per_s": None if t_wrap is None else n * args.steps / t_wrap,
        }
        row["env_overhead"] = t_env / t_phys - 1.0
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.out:
            meta = {
                "device": device,
                "jax": jax.__version__,
                "python": platform.python_version(),
                "args": vars(args),
            }
            Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    print(
        f"\ndevice: {device}; {args.steps} control steps of {env.ctrl_dt} s ({env._n_substeps} physics steps each)"
    )
    print("| envs | physics only (ctrl steps/s) | env (steps/s) | env + training wrappers | env overhead |")
    print("|---:|---:|---:|---:|---:|")
    for r in rows:
        w = "-" if r["wrapped_env_steps_per_s"] is None else f"{r['wrapped_env_steps_per_s']:,.0f}"
        print(
            f"| {r['envs']} | {r['physics_steps_per_s']:,.0f} | {r['env_steps_per_s']:,.0f} | {w} | "
            f"{100 * r['env_overhead']:.1f}% |"
        )


if __name__ == "__main__":
    main()
