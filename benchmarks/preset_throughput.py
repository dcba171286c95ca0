"""Environment steps/s of the env presets as PPO runs them (training wrappers, domain randomization
where the preset has it), random actions.

    python benchmarks/preset_throughput.py --envs 64 --steps 50

Each preset x terrain is one jitted lax.scan of --steps control steps over --envs environments,
compiled once and timed over --repeats runs (best taken).
"""

from __future__ import annotations

import argparse
import functools
import sys
import time

import jax

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.randomize import randomization_fn
from quadson_mjx.tasks import ENV_PRESETS
from quadson_mjx.wrappers import wrap_for_training


def steps_per_s(preset: str, terrain: str, n_envs: int, n_steps: int, repeats: int) -> tuple[float, float]:
    """-> (env steps/s, compile + first run [s])."""
    env = LocomotionEnv(env_config(terrain=terrain, **ENV_PRESETS[preset]))
    rand = None
    if env.config.randomize:
        rand = functools.partial(
            randomization_fn(env.config.randomization, env.base_body),
            rng=jax.random.split(jax.random.PRNGKey(1), n_envs),
        )
    w = wrap_for_training(env, env.episode_length, randomization_fn=rand)
    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), n_envs))

    @jax.jit
    def run(state, key):
        def one(carry, k):
            s = carry
            a = jax.random.uniform(k, (n_envs, env.action_size), minval=-1.0, maxval=1.0)
            return w.step(s, a), None

        return jax.lax.scan(one, state, jax.random.split(key, n_steps))[0]

    t0 = time.perf_counter()
    jax.block_until_ready(run(state, jax.random.PRNGKey(2)))
    first = time.perf_counter() - t0
    best = float("inf")
    for r in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(run(state, jax.random.PRNGKey(3 + r)))
        best = min(best, time.perf_counter() - t0)
    return n_envs * n_steps / best, first


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--cases", nargs="+", default=["seed:flat", "robust:flat", "robust:rough"])
    args = p.parse_args(argv)
    print(f"{jax.devices()[0].device_kind}, {args.envs} envs, {args.steps} steps")
    print("| preset | terrain | env steps/s | compile + first run [s] |\n|---|---|---:|---:|")
    for case in args.cases:
        preset, terrain = case.split(":")
        sps, first = steps_per_s(preset, terrain, args.envs, args.steps, args.repeats)
        print(f"| {preset} | {terrain} | {sps:,.0f} | {first:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
