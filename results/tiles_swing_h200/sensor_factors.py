"""Which of the sensor errors costs the tiles policy its stairs-up success. The uphill_factors
trial (32 robots per tile, vx 0.3 m/s for 3 s, levels 6 and 7 of slopes and stairs up) with the
model nominal (randomization ranges at the model's values, friction 0.8) and no pushes, the sensor
model's errors (quadson_mjx.env_recipes.SENSOR_MODEL) grouped as the robot has them: the IMU's
mounting tilt, the gyro's noise and bias, the gravity direction's noise, the encoders' noise and
quantisation, the readings' latency. Each group alone (the others zero), then each group removed
from the full set. The same keys for every row.

    python results/tiles_swing_h200/sensor_factors.py [--run RUN] > results/tiles_swing_h200/sensor_factors.log
    python results/tiles_swing_h200/sensor_factors.py --envs 128 --only "no sensor errors" \
        "all sensor errors" "latency only" "all but latency" > results/tiles_swing_h200/sensor_factors_128.log

(RUN defaults to results/tiles_swing_h200; 32 robots per tile: about 9 minutes on the 2-core CPU
machine, idle; 128: about 1.5 minutes a row.)
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from uphill_factors import CONDITIONS, main  # noqa: E402

from quadson_mjx.env_recipes import SENSOR_MODEL  # noqa: E402

GROUPS = {
    "IMU tilt": ("imu_tilt_rad",),
    "gyro noise + bias": ("gyro_noise_rps", "gyro_bias_rps"),
    "gravity noise": ("gravity_noise",),
    "encoders": ("encoder_noise_rad", "encoder_resolution_rad"),
    "latency": ("latency_s",),
}


def zeroed(keys) -> list[str]:
    return [f"sensor.{k}=0.0,0.0" if k == "latency_s" else f"sensor.{k}=0.0" for k in keys]


def sensor_conditions() -> dict[str, list[str]]:
    base = CONDITIONS["sensor errors only"]  # the nominal model with every sensor error
    every = [k for keys in GROUPS.values() for k in keys]
    assert sorted(every) == sorted(SENSOR_MODEL), "a sensor error is not in a group"
    out = {"no sensor errors": base + zeroed(every), "all sensor errors": base}
    for name, keys in GROUPS.items():
        out[f"{name} only"] = base + zeroed(k for k in every if k not in keys)
    for name, keys in GROUPS.items():
        out[f"all but {name}"] = base + zeroed(keys)
    return out


if __name__ == "__main__":
    conditions = sensor_conditions()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="results/tiles_swing_h200")
    ap.add_argument("--envs", type=int, default=32, help="robots per tile")
    ap.add_argument("--only", nargs="+", choices=list(conditions), help="these rows only")
    args = ap.parse_args()
    if args.only:
        conditions = {k: conditions[k] for k in args.only}
    main(args.run, conditions, args.envs)
