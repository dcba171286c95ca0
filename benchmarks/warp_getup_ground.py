"""The get-up task under MJX's Warp implementation against its JAX implementation, on flat ground
and on the stones: the same drops (GetupEnv.reset, randomization off), the same random actions
(N(0, 0.5) per motor, a new draw every control step), --steps control steps; per ground and
implementation, how many worlds are non-finite at the end and the first step one turned so, the
fullest contact list (Warp: its shared buffer's count against its size; JAX: contacts with negative
distance), and the base's height over the ground. Why the trainer refuses env.impl=warp for the
get-up task on a height field (env_model.check_warp_ground): this script lifts that refusal.

    python benchmarks/warp_getup_ground.py --worlds 4 --steps 40 | tee benchmarks/results/warp_getup_ground_cpu.log

Warp also prints "height field collision overflow" when a geom meets more than the 50 height-field
prisms it keeps per pair; count those lines in the output.
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from quadson_mjx import env_model, tasks
from quadson_mjx.config import apply_overrides
from quadson_mjx.envs import make_env

TASKS = {"flat": "QuadsonGetupFlat", "stones": "QuadsonGetupRough"}


def run(ground: str, impl: str, worlds: int, steps: int) -> dict:
    cfg = apply_overrides(
        tasks.make_task_config(TASKS[ground]),
        [f"impl={impl}", f"warp_max_worlds={worlds}", "randomize=false"],
    )
    env = make_env(cfg)
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    s = reset(jax.random.split(jax.random.PRNGKey(0), worlds))
    first_bad, most_contacts, heights = None, 0, []
    for t in range(steps):
        s = step(s, 0.5 * jax.random.normal(jax.random.PRNGKey(t), (worlds, env.action_size)))
        d = s.pipeline_state
        finite = np.isfinite(np.asarray(d.qpos)).all(axis=1) & np.isfinite(np.asarray(d.qvel)).all(axis=1)
        if first_bad is None and not finite.all():
            first_bad = t + 1
        if impl == "warp":
            most_contacts = max(most_contacts, int(np.asarray(d._impl.nacon).ravel()[0]))
        else:
            most_contacts = max(most_contacts, int(np.asarray((d._impl.contact.dist < 0).sum(-1)).max()))
        heights.append(np.asarray(d.qpos[:, 2] - env.ground_height(d.qpos[:, :2])))
    h = np.array(heights)
    return {
        "ground": ground,
        "impl": impl,
        "worlds": worlds,
        "steps": steps,
        "nonfinite_worlds": int((~finite).sum()),
        "first_nonfinite_step": first_bad,
        "contacts_most": most_contacts,
        "contact_buffer": env._warp_buffers[0] if impl == "warp" else None,
        "base_height_min_m": float(np.nanmin(h)),
        "base_height_final_m": [round(float(x), 4) for x in h[-1]],
    }


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--worlds", type=int, default=4)
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--grounds", nargs="+", default=["flat", "stones"], choices=sorted(TASKS))
    args = p.parse_args(argv)
    env_model.check_warp_ground = lambda cfg: None  # measure what the refusal is for
    import quadson_mjx.getup_env as getup_env

    getup_env.check_warp_ground = env_model.check_warp_ground
    for ground in args.grounds:
        for impl in ("jax", "warp"):
            print(json.dumps(run(ground, impl, args.worlds, args.steps)), flush=True)


if __name__ == "__main__":
    main()
