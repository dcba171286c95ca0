"""Which randomized episodes of the 150M-step pace or bound (results/gaits/before_finetune/, the
policies before their fine-tuning) fall, and how: for each of seeds 1-3 (the seeds of
results/gaits/eval_cpu_pace_bound_s*.json, the same draws as quadson-gaits --seed S), every
falling episode with the time of its fall, roll and pitch then [deg], its model's ground friction,
total mass [kg], weakest motor's strength factor and base CoM x [m], and its mean forward speed over
the 0.5 s before the fall [m/s]; then the means over all 256 models.

    python results/gaits/fall_diagnosis.py bound 1,2,3 > results/gaits/fall_diagnosis_bound.log

Another run, and the evaluation's ranges (`randomization.KEY=LOW,HIGH`, as quadson-gaits
--randomization sets them), after the seeds: the robot's bound at its 2 ms step, the draws of
results/gaits/transfer/eval_cpu_bound_2ms_s*:

    python results/gaits/fall_diagnosis.py bound 1,2,3 results/gaits/transfer/bound_2ms \
        randomization.mass_scale=0.85,1.15 randomization.base_com_shift_m=-0.02,0.02 \
        randomization.motor_strength=0.8,1.2 > results/gaits/transfer/fall_diagnosis_bound_2ms.log
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

gait = sys.argv[1]
seeds = [int(s) for s in sys.argv[2].split(",")]
run = Path(sys.argv[3]) if len(sys.argv) > 3 else Path(f"results/gaits/before_finetune/{gait}")
policy, env_cfg, _, _ = training.load_policy(run)
env_cfg = with_added_keys(env_cfg)
env_cfg = apply_overrides(env_cfg, ["command_tracking=false", "randomize=true", *sys.argv[4:]])
env = LocomotionEnv(env_cfg)
ctl = R.policy_controller(policy)
n = 256
steps = int(round(18.75 / env.ctrl_dt))
for seed in seeds:
    rng = jax.random.fold_in(jax.random.PRNGKey(seed), 2)
    parts = []
    for _, seg in R.run(env, ctl, rng, n, steps, randomize=True):
        parts.append({k: getattr(seg, k) for k in ("done", "fall", "rpy", "lin_vel", "foot_force")})
    J = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    first = gait_eval.first_episode_mask(J["done"])
    fell = np.any(J["fall"] & first, 0)
    sys_v, _ = randomize(
        env.sys, jax.random.split(jax.random.fold_in(rng, 7), n), env.config.randomization, env.base_body
    )
    fr = np.asarray(sys_v.geom_friction[:, 0, 0])
    ms = np.asarray(sys_v.body_mass.sum(1))
    st = np.asarray(sys_v.actuator_gainprm[:, :, 0]).min(1) / float(env.sys.actuator_gainprm[0, 0])
    com = np.asarray(sys_v.body_ipos[:, env.base_body, 0])
    print(f"seed {seed}: falls {fell.sum()}")
    for b in np.nonzero(fell)[0]:
        t = int(np.argmax(J["fall"][:, b] & first[:, b]))
        r, p, _ = np.degrees(J["rpy"][t, b])
        print(
            f"  env {b}: t={t * env.ctrl_dt:.2f}s roll {r:.0f} pitch {p:.0f} fric {fr[b]:.2f} mass {ms[b]:.2f} min_strength {st[b]:.2f} com {com[b]:.3f} vx_before {J['lin_vel'][max(t - 25, 0) : t, b, 0].mean():.2f}"
        )
    print(f"  all: fric {fr.mean():.2f} mass {ms.mean():.2f} strength {st.mean():.2f}", flush=True)
