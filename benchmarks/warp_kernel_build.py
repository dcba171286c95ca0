"""How long Warp takes to build the kernels of the main job's environment step on a machine that has
none cached (each mode in its own empty kernel cache): "serial", as training does it (each module
compiled at its first launch), or "parallel" (every module registered once the step is traced,
compiled by wp.force_load over all CPU cores before the first launch).

    python benchmarks/warp_kernel_build.py serial parallel | tee benchmarks/results/warp_kernel_build_h100.log

Each mode runs in a fresh process (the kernel cache path is set before warp is imported).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time


def one(mode: str) -> None:
    os.environ["WARP_CACHE_PATH"] = f"/tmp/warp_kernel_build_{mode}_{os.getpid()}"
    import jax
    import jax.numpy as jnp
    import warp as wp
    from warp._src import context as wctx

    from quadson_mjx import tasks
    from quadson_mjx.config import apply_overrides
    from quadson_mjx.envs import make_env

    env = make_env(apply_overrides(tasks.config_from_flags(), ["impl=warp", "warp_max_worlds=4"]))
    t0 = time.perf_counter()
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    step.lower(jax.eval_shape(reset, keys), jnp.zeros((4, env.action_size)))
    n = len(wctx.user_modules)
    print(
        f"{mode}: modules registered after tracing the step: {n}, trace {time.perf_counter() - t0:.1f} s",
        flush=True,
    )
    if mode == "parallel":
        t = time.perf_counter()
        wp.force_load(device="cuda:0", modules=list(wctx.user_modules.values()), max_workers=os.cpu_count())
        print(
            f"{mode}: force_load of {n} modules on {os.cpu_count()} threads: {time.perf_counter() - t:.1f} s"
        )
    t = time.perf_counter()
    s = step(reset(keys), jnp.zeros((4, env.action_size)))
    jax.block_until_ready(s.obs)
    print(
        f"{mode}: first reset + step (compiling what is left): {time.perf_counter() - t:.1f} s; "
        f"total {time.perf_counter() - t0:.1f} s",
        flush=True,
    )


def main(argv=None):
    modes = (argv if argv is not None else sys.argv[1:]) or ["serial", "parallel"]
    if len(modes) == 1:
        return one(modes[0])
    for mode in modes:
        subprocess.run([sys.executable, __file__, mode], check=True)


if __name__ == "__main__":
    main()
