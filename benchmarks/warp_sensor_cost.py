"""What the feet's contact sensors cost under MJX's Warp implementation: the main job's model as the
environment builds it for Warp on the stones (env_model.training_model: four contact sensors;
feet-only ground contact, no joint-limit rows, as the main job; on the flat scene the env now tells
contact from the feet's height instead, env_model.feet_on_plane) against the same model with its sensors disabled, bare physics (physics_vs_go1.physics_only:
5 physics steps per 0.02 s control step, noisy targets around home, the sensors read every control
step), one run.

    python benchmarks/warp_sensor_cost.py --envs 8192 32768 [--terrain flat rough] | tee benchmarks/results/warp_sensor_cost_h100.log

--terrain rough: the same on the stone field (the robot standing at home, off its flat patch).
"""

from __future__ import annotations

import argparse

from physics_vs_go1 import physics_only

from quadson_mjx import tasks
from quadson_mjx.config import apply_overrides
from quadson_mjx.env_model import training_model, warp_buffers
from quadson_mjx.robots import get_robot


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[8192, 32768])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--terrain", nargs="+", default=["flat"], choices=["flat", "rough"])
    args = p.parse_args(argv)
    for terrain, label in ((t, s) for t in args.terrain for s in ("4 contact sensors", "sensors disabled")):
        cfg = apply_overrides(tasks.config_from_flags(), ["impl=warp", f"terrain={terrain}"])
        m = training_model(get_robot("quadson"), cfg, contact_sensors=label == "4 contact sensors")
        contacts, rows = warp_buffers(m, 1)
        for n in args.envs:
            out = physics_only(
                m, m.key_qpos[0], m.key_ctrl[0], n, args.steps, args.repeats, True,
                impl="warp", contacts_per_world=contacts, njmax=rows,
            )  # fmt: skip
            print(
                f"{terrain} | {label} | {n} | {out['physics_steps_per_s']:,.0f} | overflow {out.get('overflow')}",
                flush=True,
            )


if __name__ == "__main__":
    main()
