"""What costs the tiles policy its uphill success under the evaluation's randomization: the
randomized model, the pushes, or both. The MJX tiles trial (quadson_mjx.tiles_eval: 32 robots per
tile from its centre, vx 0.3 m/s for 3 s, success = no fall and >= 80 % of the commanded distance)
on slopes and stairs up at levels 6 and 7 (14 / 16 degrees, 2.8 / 3.2 cm), four ways: nominal
model without pushes, pushes only, randomized model only, both (the evaluation's condition); then
the randomized model one range at a time (the run's range for that one, the others nominal, the
sensor errors on as randomize=true has them), and the sensor errors alone. The same keys for all,
so each robot meets the same ground and draws.

    python results/tiles_swing_h200/uphill_factors.py [RUN] > results/tiles_swing_h200/uphill_factors.log
    python results/tiles_swing_h200/uphill_factors.py --envs 128 --only "nominal, no pushes" \
        "randomized only" "randomized + pushes" > results/tiles_swing_h200/uphill_factors_128.log

(RUN defaults to results/tiles_swing_h200; 32 robots per tile: about 6 minutes on the 2-core CPU
machine, idle; 128: about 1.5 minutes a row.)
"""

import argparse
import time
from pathlib import Path

from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.randomize import nominal_range_overrides
from quadson_mjx.tiles_eval import evaluate_tiles
from quadson_mjx.training import load_policy

NOMINAL_MODEL = nominal_range_overrides()  # with randomize=true: the sensor errors only


def only(key: str, value: str) -> list[str]:
    """randomize=true, no pushes, one model range as trained and the others nominal."""
    return [
        "randomize=true",
        "pushes=false",
        *nominal_range_overrides(keep=(key.removeprefix("randomization."),)),
        f"{key}={value}",
    ]


CONDITIONS = {
    "nominal, no pushes": ["randomize=false", "pushes=false"],
    "pushes only": ["randomize=false", "pushes=true"],
    "randomized only": ["randomize=true", "pushes=false"],
    "randomized + pushes": ["randomize=true", "pushes=true"],
    # the randomized model one range at a time (each with the sensor errors, which randomize=true brings)
    "sensor errors only": ["randomize=true", "pushes=false", *NOMINAL_MODEL],
    "friction 0.5-1.2": only("randomization.friction", "0.5,1.2"),
    "mass x0.85-1.15": only("randomization.mass_scale", "0.85,1.15"),
    "motors x0.8-1.2": only("randomization.motor_strength", "0.8,1.2"),
    "CoM +-2 cm": only("randomization.base_com_shift_m", "-0.02,0.02"),
    "latency 0-20 ms": only("randomization.latency_s", "0.0,0.02"),
}


def main(run: str, conditions: dict[str, list[str]] = CONDITIONS, envs: int = 32) -> None:
    """One row per condition: the env overrides (env. prefix implied) on the run's own config;
    envs robots per tile."""
    policy, env_cfg, _, _ = load_policy(Path(run))
    print(f"run {run}; {envs} robots per tile, 3 s at vx 0.3 m/s; success % (mean distance share), falls")
    print(
        f"{'condition':22s} {'slope up 14':>16s} {'slope up 16':>16s} {'stairs up 2.8':>16s} {'stairs up 3.2':>16s}"
    )
    for name, over in conditions.items():
        t0 = time.monotonic()
        cfg = apply_overrides(with_added_keys(env_cfg), over, prefix="env.")
        rows = evaluate_tiles(
            cfg, policy, levels=[6, 7], envs_per_tile=envs, seconds=3.0, types=["slope_up", "stairs_up"]
        )
        cells = [f"{100 * r['success']:5.0f} ({r['distance_share']:.2f}) {r['falls']}" for r in rows]
        print(
            f"{name:22s} " + " ".join(f"{c:>16s}" for c in cells) + f"   [{time.monotonic() - t0:.0f} s]",
            flush=True,
        )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", nargs="?", default="results/tiles_swing_h200")
    ap.add_argument("--envs", type=int, default=32, help="robots per tile")
    ap.add_argument("--only", nargs="+", choices=list(CONDITIONS), help="these rows only")
    args = ap.parse_args()
    main(args.run, {k: CONDITIONS[k] for k in args.only} if args.only else CONDITIONS, args.envs)
