"""Which randomized models make a gait policy run slow, and whether its motors are at their limit
then: the episodes of one gait evaluation (the same draws as quadson-gaits --seed S with the same
--randomization), each episode's mean forward speed from 1 s to its end (episodes that fall left
out), split into quartiles of its model's total mass, weakest motor's strength factor, base CoM x
and ground friction; per quartile the mean speed over the table's, and the share of (step, motor)
pairs whose torque is within 2 % of that motor's randomized limit.

    python results/gaits/transfer/speed_diagnosis.py bound 5 results/gaits/transfer/bound_2ms_fric \
        randomization.mass_scale=0.85,1.15 randomization.base_com_shift_m=-0.02,0.02 \
        randomization.motor_strength=0.8,1.2 > results/gaits/transfer/speed_diagnosis_bound_2ms_fric_s5.log
"""

import sys
from pathlib import Path

import jax
import numpy as np

from quadson_mjx import gait_eval, training
from quadson_mjx import rollout as R
from quadson_mjx.cli.gaits import apply_overrides, with_added_keys
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.randomize import randomize

gait, seed, run = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
policy, env_cfg, _, _ = training.load_policy(run)
env_cfg = apply_overrides(
    with_added_keys(env_cfg), ["command_tracking=false", "randomize=true", *sys.argv[4:]]
)
env = LocomotionEnv(env_cfg)
n, steps = 256, int(round(18.75 / env.ctrl_dt))
rng = jax.random.fold_in(jax.random.PRNGKey(seed), 2)
parts = []
for _, seg in R.run(env, R.policy_controller(policy), rng, n, steps, randomize=True):
    parts.append(
        {k: np.asarray(getattr(seg, k)) for k in ("done", "fall", "lin_vel", "actuator_force", "command")}
    )
J = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
first = gait_eval.first_episode_mask(J["done"])
fell = np.any(J["fall"] & first, 0)
sys_v, _ = randomize(
    env.sys, jax.random.split(jax.random.fold_in(rng, 7), n), env.config.randomization, env.base_body
)
model = {
    "mass [kg]": np.asarray(sys_v.body_mass.sum(1)),
    "weakest motor": np.asarray(sys_v.actuator_gainprm[:, :, 0]).min(1)
    / float(env.sys.actuator_gainprm[0, 0]),
    "base CoM x [m]": np.asarray(sys_v.body_ipos[:, env.base_body, 0]),
    "friction": np.asarray(sys_v.geom_friction[:, 0, 0]),
}
limit = np.asarray(sys_v.actuator_forcerange[:, :, 1])  # (n, nu) [N m]
measured = first & (np.arange(J["done"].shape[0])[:, None] * env.ctrl_dt >= 1.0)  # from 1 s to the end
table = float(J["command"][0, 0, 0])
speed = np.array([J["lin_vel"][measured[:, b], b, 0].mean() for b in range(n)]) / table
at_limit = np.abs(J["actuator_force"]) >= 0.98 * limit[None]  # (T, n, nu)
sat = np.array([at_limit[measured[:, b], b].mean() for b in range(n)])
keep = ~fell
print(f"{gait} seed {seed} ({run}): {keep.sum()} of {n} episodes that did not fall")
print(
    f"speed / table {speed[keep].mean():.3f}; torque within 2 % of its limit {100 * sat[keep].mean():.2f} % of (step, motor)"
)
for name, v in model.items():
    edges = np.quantile(v[keep], [0.25, 0.5, 0.75])
    q = np.digitize(v, edges)
    cells = []
    for k in range(4):
        m = keep & (q == k)
        cells.append(f"{v[m].min():.3f}-{v[m].max():.3f}: {speed[m].mean():.3f}, {100 * sat[m].mean():.2f} %")
    print(f"  {name:15s} quartiles (range: speed / table, at limit): " + " | ".join(cells))
slow = keep & (speed < 0.85)
print(f"  slowest: {slow.sum()} episodes under 0.85 of the table's speed")
for b in np.nonzero(slow)[0]:
    print(
        "    env",
        b,
        f"speed {speed[b]:.3f}",
        " ".join(f"{k.split()[0]} {v[b]:.3f}" for k, v in model.items()),
        f"at limit {100 * sat[b]:.2f} %",
    )
