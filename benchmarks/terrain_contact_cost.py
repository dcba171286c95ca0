"""Cost of ground contacts per scene: MJX physics steps/s of the robot on the flat and rough scenes,
with the base box touching the ground or only the feet (env_config's base_terrain_contact).

    python benchmarks/terrain_contact_cost.py --envs 64 --steps 20

Each case: B worlds from the home pose, --steps physics steps in one jitted lax.scan, compiled once,
best of --repeats. Prints one line per case; ratios within one run are what to compare.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from quadson_mjx.robots.quadson import model as qmodel


def physics_rate(mj_model, n_envs: int, n_steps: int, repeats: int) -> float:
    mx = mjx.put_model(mj_model)
    d0 = mjx.make_data(mx).replace(qpos=jnp.asarray(qmodel.home_qpos(mj_model)))
    batch = jax.vmap(lambda _: d0)(jnp.arange(n_envs))

    @jax.jit
    def run(d):
        return jax.lax.scan(
            lambda c, _: (jax.vmap(mjx.step, in_axes=(None, 0))(mx, c), ()), d, None, n_steps
        )[0]

    jax.block_until_ready(run(batch))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(run(batch))
        best = min(best, time.perf_counter() - t0)
    return n_envs * n_steps / best


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    print(f"devices: {', '.join(d.device_kind for d in jax.devices())}; {a.envs} worlds x {a.steps} steps")
    for terrain in ("flat", "rough"):
        for base_contact in (True, False):
            m = qmodel.load_model(terrain)
            if not base_contact:
                g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
                m.geom_contype[g] = m.geom_conaffinity[g] = 0
            rate = physics_rate(m, a.envs, a.steps, a.repeats)
            print(
                f"{terrain:5s}  base contact {str(base_contact):5s}  {rate:10,.0f} physics steps/s",
                flush=True,
            )


if __name__ == "__main__":
    main()
