"""Where a gait policy's feet leave the phase table: the committed policy of GAIT (results/gaits/)
walked as `quadson-gaits --gaits GAIT --controllers policy --envs 256 --seed S` walks it (the same
draws), under the recipe's model ranges. Every (control step, foot) that misses the table by more
than one step (gait_eval.tolerant_agreement, as pattern_match_1step counts it) is put in a class:

* "up in stance" or "down in swing": what the foot did against the table;
* its distance in control steps to the leg's nearest table transition (2 = a touchdown or lift-off
  two steps early or late; larger = inside the phase: a bounce in stance, a scuff in swing);
* whether a motor of that leg was at its torque limit then (|force| >= 98 % of its randomized
  force range), against how often that happens on the steps that match;
* the policy's foot offset then (the action times action_scale_m, gait frame x, y, z [mm]) against
  its mean on the leg's swing steps that match: whether the policy puts the foot down.

Last, the pattern per quarter of the randomized models by total mass, base CoM x, the weakest
motor's strength and the episode's own forward speed (from 1 s on, over the table's): whether the
misses belong to some models, and whether the episodes that run faster keep the table less well.

Then the share of the evaluated steps each class makes fail (a step fails when any foot misses), per
leg pair. The steps, the settle time and the first-episode rule are gait_eval.gait_stats's.

    python results/gaits/pattern_diagnosis.py bound 1 > results/gaits/pattern_diagnosis_bound_s1.log

A third argument names another run of the gait, a fourth on more env overrides (the run's own
physics, such as `sim_dt`, come from its config):

    python results/gaits/pattern_diagnosis.py bound 1 results/gaits/transfer/bound_2ms_fric
"""

import sys
from pathlib import Path

import jax
import numpy as np

from quadson_mjx import gait_eval, training
from quadson_mjx import rollout as R
from quadson_mjx.cli.gaits import apply_overrides, with_added_keys
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import SEED_EPISODE_S
from quadson_mjx.randomize import randomize

RANGES = ["mass_scale=0.85,1.15", "base_com_shift_m=-0.02,0.02", "motor_strength=0.8,1.2"]
SATURATED = 0.98  # of the motor's randomized force range

gait, seed = sys.argv[1], int(sys.argv[2])
run = Path(sys.argv[3]) if len(sys.argv) > 3 else Path(f"results/gaits/{gait}")
n_envs = 256
policy, env_cfg, _, _ = training.load_policy(run)
env_cfg = apply_overrides(
    with_added_keys(env_cfg), ["command_tracking=false", "randomize=true", *sys.argv[4:]]
)
env_cfg = apply_overrides(env_cfg, [f"randomization.{r}" for r in RANGES], prefix="env.")
env = LocomotionEnv(env_cfg)
rng = jax.random.fold_in(jax.random.PRNGKey(seed), 2)  # quadson-gaits' draws for its policy row
fields = ("done", "foot_force", "scheduled_stance", "actuator_force", "action", "lin_vel", "command")
parts = []
steps = int(round(SEED_EPISODE_S / env.ctrl_dt))
for _, seg in R.run(env, R.policy_controller(policy), rng, n_envs, steps, randomize=True):
    parts.append({k: np.asarray(getattr(seg, k)) for k in fields})
J = {k: np.concatenate([p[k] for p in parts]) for k in fields}
sys_v, _ = randomize(
    env.sys, jax.random.split(jax.random.fold_in(rng, 7), n_envs), env.config.randomization, env.base_body
)
force_max = np.asarray(sys_v.actuator_forcerange[:, :, 1])  # (B, 12)

first = gait_eval.first_episode_mask(J["done"])
t_index = np.arange(first.shape[0])[:, None]
use = first & (t_index >= int(round(1.0 / env.ctrl_dt))) & ~(J["done"] & first)  # (T, B)
contact = J["foot_force"] > gait_eval.FORCE_THRESHOLD_N  # (T, B, 4)
stance = J["scheduled_stance"].astype(bool)
ok = gait_eval.tolerant_agreement(contact, stance, 1)  # (T, B, 4)
miss = ~ok & use[..., None]

# steps to the leg's nearest table transition (a transition at t: stance[t] != stance[t - 1])
T = stance.shape[0]
change = np.zeros_like(stance)
change[1:] = stance[1:] != stance[:-1]
dist = np.full(stance.shape, T, int)
for d in range(T):
    if not (dist > d).any():
        break
    hit = np.zeros_like(change)
    hit[: T - d] |= change[d:]
    hit[d:] |= change[: T - d]
    dist = np.where((dist == T) & hit, d, dist)

sat = (np.abs(J["actuator_force"]) >= SATURATED * force_max[None]).reshape(T, n_envs, 4, 3).any(-1)

legs = env.robot.legs
n_steps = int(use.sum())
fail = miss.any(-1)
print(f"{gait} ({run}), seed {seed}: {n_envs} episodes, {n_steps} evaluated steps")
print(f"pattern +-1 step: {100 * (1 - fail[use].mean()):.2f} % (steps where every foot agrees)")
print(f"foot-steps that miss: {int(miss.sum())} of {4 * n_steps}")


def share(mask):
    """Percent of the evaluated steps on which some foot misses in the way `mask` (T, B, 4) says."""
    return 100 * (mask & miss).any(-1)[use].mean()


classes = {
    "up in stance, 2 steps from a transition": ~contact & stance & (dist == 2),
    "up in stance, 3-4 steps": ~contact & stance & (dist >= 3) & (dist <= 4),
    "up in stance, >= 5 steps (a bounce)": ~contact & stance & (dist >= 5),
    "down in swing, 2 steps from a transition": contact & ~stance & (dist == 2),
    "down in swing, 3-4 steps": contact & ~stance & (dist >= 3) & (dist <= 4),
    "down in swing, >= 5 steps (a scuff)": contact & ~stance & (dist >= 5),
}
print("\nsteps failed by each class [% of evaluated steps] (a step may count in several):")
print(f"{'class':45s} {'any leg':>8s} " + " ".join(f"{leg:>6s}" for leg in legs))
for name, m in classes.items():
    per_leg = [100 * (m & miss)[..., i][use].mean() for i in range(4)]
    print(f"{name:45s} {share(m):8.2f} " + " ".join(f"{v:6.2f}" for v in per_leg))
front, hind = np.zeros(4, bool), np.zeros(4, bool)
front[[i for i, leg in enumerate(legs) if leg.startswith("F")]] = True
hind[~front] = True
only_front = (miss & front).any(-1) & ~(miss & hind).any(-1)
only_hind = (miss & hind).any(-1) & ~(miss & front).any(-1)
print(
    f"\nfailed steps: front legs only {100 * only_front[use].mean():.2f} %, hind legs only "
    f"{100 * only_hind[use].mean():.2f} %, both {100 * (fail & ~only_front & ~only_hind)[use].mean():.2f} %"
)
valid = use[..., None] & np.ones(4, bool)
print(
    f"a motor of the leg at {100 * SATURATED:.0f} % of its torque limit: on missed foot-steps "
    f"{100 * sat[miss].mean():.1f} %, on matching foot-steps {100 * sat[valid & ok].mean():.1f} %"
)
for name, m in classes.items():
    sel = m & miss
    if sel.any():
        print(f"  {name:45s} {100 * sat[sel].mean():5.1f} % of {int(sel.sum())}")

scale_mm = 1000 * float(env_cfg.action_scale_m)
offsets = J["action"][..., :12].reshape(T, n_envs, 4, 3) * scale_mm  # (T, B, 4, 3) [mm]
scuff = classes["down in swing, >= 5 steps (a scuff)"] & miss
clean_swing = ~stance & ok & use[..., None] & (dist >= 5)
print("\npolicy foot offset x, y, z [mm] in mid-swing (>= 5 steps from a transition), per leg:")
for i, leg in enumerate(legs):
    a = offsets[..., i, :][scuff[..., i]]
    b = offsets[..., i, :][clean_swing[..., i]]
    sa = " ".join(f"{v:6.1f}" for v in a.mean(0)) if len(a) else "     -      -      -"
    print(
        f"  {leg}: on scuffs {sa} ({len(a)}); on clean swing "
        + " ".join(f"{v:6.1f}" for v in b.mean(0))
        + f" ({len(b)})"
    )
sat_motor = (np.abs(J["actuator_force"]) >= SATURATED * force_max[None]).reshape(T, n_envs, 4, 3)
print("share of scuff foot-steps with each motor of the leg at its limit (motors 0, 1, 2):")
for i, leg in enumerate(legs):
    if scuff[..., i].any():
        print(
            f"  {leg}: " + " ".join(f"{100 * v:5.1f} %" for v in sat_motor[..., i, :][scuff[..., i]].mean(0))
        )

fail_share = np.array([fail[use[:, b], b].mean() if use[:, b].any() else np.nan for b in range(n_envs)])
speed = np.array(
    [J["lin_vel"][use[:, b], b, 0].mean() if use[:, b].any() else np.nan for b in range(n_envs)]
) / float(J["command"][0, 0, 0])
models = {
    "total mass [kg]": np.asarray(sys_v.body_mass.sum(1)),
    "base CoM x [m]": np.asarray(sys_v.body_ipos[:, env.base_body, 0]),
    "weakest motor strength": force_max.min(1) / float(env.sys.actuator_forcerange[0, 1]),
    "speed / table": speed,
}
print("\npattern +-1 step [%] per quarter of the models (lowest quarter first):")
for name, v in models.items():
    v = np.where(np.isnan(v), np.nanmin(v), v)  # an episode that fell before 1 s goes to the slowest quarter
    edges = np.quantile(v, [0.25, 0.5, 0.75])
    q = np.digitize(v, edges)
    cells = []
    for k in range(4):
        sel = q == k
        cells.append(f"{v[sel].min():.3f}-{v[sel].max():.3f}: {100 * (1 - np.nanmean(fail_share[sel])):.1f}")
    print(f"  {name:24s} " + " | ".join(cells))
ok_b = ~np.isnan(fail_share) & ~np.isnan(speed)
print(
    f"mean speed / table {np.nanmean(speed):.3f}; correlation of an episode's speed and its pattern: "
    f"{np.corrcoef(speed[ok_b], 1 - fail_share[ok_b])[0, 1]:+.2f}"
)
