"""Where a joystick policy's yaw-rate error lies in frequency. The run's env config at the 2 ms
physics step (its randomization, sensor errors and pushes as trained) on TERRAIN, 8 commands x 2
environments for 15 s, driven by the policy or by the gait alone (zero offsets); the error wz -
commanded yaw rate over every control step after the first second, in the environments whose
episode did not end (by a fall, or at the stone field's edge after a fast command): its RMS, the
RMS of each environment's mean (the bias), the shares of its power per frequency band (from the
FFT of each environment's error, summed over environments), and the six strongest frequencies.
The same for vx.

    python results/policy_h200_sensors_dt2_lr3/yaw_spectrum.py RUN policy|gait TERRAIN [KEY=VALUE ...]
"""

import sys
from pathlib import Path

import jax
import numpy as np

from quadson_mjx import rollout as R
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.policy_eval import eval_config
from quadson_mjx.training import load_policy

COMMANDS = np.repeat(
    np.array(
        [[0.3, 0, 0], [0.0, 0, 0], [0.2, 0, 0.5], [-0.2, 0.1, 0], [0.4, 0, -0.3], [0.0, 0.15, 0], [0.1, 0, 0.8], [0.3, -0.1, 0.2]],
        np.float32,
    ),
    2,
    axis=0,
)  # fmt: skip
STEPS, SETTLE = 750, 50
BANDS = ((0.0, 0.25), (0.25, 1.0), (1.0, 2.5), (2.5, 4.0), (4.0, 8.0), (8.0, 25.1))  # Hz


def spectrum(x, dt):
    """x (T, envs) -> (band shares, six strongest frequencies with their shares)."""
    f = np.fft.rfftfreq(x.shape[0], dt)
    power = (np.abs(np.fft.rfft(x, axis=0)) ** 2).sum(axis=1)
    shares = {f"{lo}-{hi} Hz": float(power[(f >= lo) & (f < hi)].sum() / power.sum()) for lo, hi in BANDS}
    top = np.argsort(power)[::-1][:6]
    return shares, [(round(float(f[i]), 2), round(float(power[i] / power.sum()), 3)) for i in top]


def main(run: str, driver: str, terrain: str, overrides: list[str]) -> None:
    policy, env_cfg, _, _ = load_policy(Path(run))
    cfg = eval_config(env_cfg, terrain, ["sim_dt=0.002", *overrides])
    env = LocomotionEnv(cfg)
    controller = R.policy_controller(policy) if driver == "policy" else R.gait_only(env)
    yaw, vx, done = [], [], []
    for _, traj in R.run(
        env, controller, jax.random.PRNGKey(0), len(COMMANDS), STEPS, segment_steps=250,
        command=COMMANDS, randomize=bool(cfg.randomize),
    ):  # fmt: skip
        yaw.append(traj.ang_vel[..., 2] - traj.command[..., 2])
        vx.append(traj.lin_vel[..., 0] - traj.command[..., 0])
        done.append(traj.done)
    up = ~np.concatenate(done)[SETTLE:].any(axis=0)  # no fall, no truncation at the field's edge
    print(
        f"{run}, {driver}, {terrain} {' '.join(overrides)}: {int(up.sum())} of {len(COMMANDS)} environments without an episode end"
    )
    for name, series in (("yaw rate", yaw), ("vx", vx)):
        e = np.concatenate(series)[SETTLE:][:, up]
        shares, top = spectrum(e, env.ctrl_dt)
        print(f"  {name}: RMS {np.sqrt(np.mean(e**2)):.3f}, bias RMS {np.sqrt(np.mean(e.mean(0) ** 2)):.3f}")
        print("    power by band: " + ", ".join(f"{k} {v:.2f}" for k, v in shares.items()))
        print(f"    strongest [Hz, share]: {top}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:])
