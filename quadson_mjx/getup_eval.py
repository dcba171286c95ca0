"""A get-up policy over many drops, per start class: success and time to stand, as the task defines
them (quadson_mjx.getup_env: upright within 10 deg and the base within 2 cm of the standing height,
held 1 s, begun within 5 s of the drop).

Every drop is a fresh start of the task (getup_start: class, orientation, motor angles, height) on
its own randomized model (the run's randomization ranges) with the run's sensor model; the policy
acts with its mean action, as deployed. One episode per drop, 6 s.

    rows, total = evaluate_getup(env_cfg, policy, terrain="flat", drops=512, seed=0)
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.getup_env import TOPPLED_CLASS, GetupEnv
from quadson_mjx.robots.quadson.getup_start import CLASSES
from quadson_mjx.robots.quadson.mirror import (
    TRAINED,
    mirror_getup_observation,
    mirror_motors,
    resolve_mirror_to,
    trained_mirror_to,
    wants_mirror,
)
from quadson_mjx.sensors import gravity_direction
from quadson_mjx.stats import success_interval
from quadson_mjx.wrappers import wrap_for_evaluation

ON_BACK_TILT_RAD = math.radians(150.0)  # an episode that ends tilted further lies on its back
# the total's breakdown by the start's tilt (the body z axis against the vertical at the drop) [deg]
START_TILT_BINS_DEG = (0.0, 45.0, 90.0, 120.0, 150.0, 180.0)
GROUNDS = {"flat": "flat", "stones": "rough"}  # the evaluation's word -> env.terrain


STARTS = {  # the evaluation's starts -> the overrides that make every episode one
    "drops": ["getup.stand_start_prob=0.0"],
    "topples": ["getup.stand_start_prob=1.0", "getup.topple_prob=1.0"],
}


def getup_env_config(env_cfg, ground: str, starts: str = "drops"):
    """The run's env config (a get-up run's) on `ground` ("flat" or "stones"), every episode a drop
    (starts "drops") or a knock-over from the home stance (starts "topples", at the run's
    env.getup.topple_rate_rps, whether or not it trained any)."""
    cfg = with_added_keys(env_cfg)
    if cfg.task != "getup":
        raise ValueError(f"get-up evaluation: the run trained env.task={cfg.task!r}, not getup")
    if ground not in GROUNDS:
        raise ValueError(f"get-up evaluation: ground {ground!r}; choose from {list(GROUNDS)}")
    if starts not in STARTS:
        raise ValueError(f"get-up evaluation: starts {starts!r}; choose from {list(STARTS)}")
    return apply_overrides(cfg, [f"terrain={GROUNDS[ground]}", *STARTS[starts]], prefix="env.")


def mirrored_policy(policy, mirror):
    """policy(obs, key) -> (action, extras) run on the mirror image where mirror (B,) is set: its
    actor observation mirrored in, its action mirrored out (robots.quadson.mirror)."""

    def run(obs, key):
        state = obs["state"]
        m = mirror[:, None]
        seen = {**obs, "state": jnp.where(m, mirror_getup_observation(state), state)}
        action, extras = policy(seen, key)
        return jnp.where(m, mirror_motors(action), action), extras

    return run


def evaluate_getup(
    env_cfg,
    policy,
    ground: str = "flat",
    drops: int = 512,
    seed: int = 0,
    starts: str = "drops",
    mirror_to: str | None = TRAINED,
):
    """policy(obs, key) -> (action, extras) (training.load_policy) of a get-up run whose env config
    is env_cfg, over `drops` starts on `ground` -> (rows: one per start class of getup_start.CLASSES
    with drops, successes, success share, time to stand [s] (mean, median, 90th percentile, of the
    successes), share of steps with legs overlapping and with a chain-guarded leg, the largest motor
    speed [rad/s]; total: the same over every start, plus non-finite resets and, by the body's tilt
    at the drop (START_TILT_BINS_DEG), drops, successes and failures ending on the back). starts "topples":
    knock-overs from the home stance instead of drops, one row "toppled". mirror_to "left" runs the
    policy mirrored in every episode that starts with the body's right side lower (gravity's body y
    below 0), so that it always meets the left side's fall ("right": the other way round), as
    deploy_supervisor.GetupPolicy(mirror_to=...) does at the start of an attempt. A run trained
    mirrored (env.getup.mirror_to) is evaluated on the side it trained on, by the environment itself
    (mirror_to TRAINED or that side; another: ValueError, mirror.resolve_mirror_to)."""
    if drops < 1:
        raise ValueError(f"get-up evaluation: drops {drops}: need at least 1")
    trained = trained_mirror_to(env_cfg)
    mirror_to = resolve_mirror_to(mirror_to, trained)  # a bad mirror_to: ValueError before compiling
    if trained is not None:
        mirror_to = None  # the environment mirrors, as in training
    cfg = getup_env_config(env_cfg, ground, starts)
    env = GetupEnv(cfg)
    n_steps = env.episode_length
    w = wrap_for_evaluation(env, cfg, drops, seed, n_steps)

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        state = w.reset(jax.random.split(k_reset, drops))
        act = mirrored_policy(policy, wants_mirror(state.obs["state"][:, 1], mirror_to))  # gravity.y

        def one(carry, k):
            s, acc = carry
            action, _ = act(s.obs, k)
            s = w.step(s, action)
            m = s.metrics
            acc = {
                "success": acc["success"] + m["success"],
                "time_to_stand": acc["time_to_stand"] + m["time_to_stand"],
                "overlap_steps": acc["overlap_steps"] + m["legs_overlap"],
                "guarded_steps": acc["guarded_steps"] + (m["chain_guarded_legs"] > 0),
                "max_motor_speed": jnp.maximum(acc["max_motor_speed"], m["max_motor_speed"]),
                "nan_reset": acc["nan_reset"] + m["nan_reset"],
                "final_tilt": m["tilt"],  # the last step's, after the scan
            }
            return (s, acc), None

        zeros = jnp.zeros(drops)
        acc = {k: zeros for k in ("success", "time_to_stand", "overlap_steps", "guarded_steps", "max_motor_speed", "nan_reset", "final_tilt")}  # fmt: skip
        (_, acc), _ = jax.lax.scan(one, (state, acc), jax.random.split(k_run, n_steps))
        up = -gravity_direction(state.pipeline_state.qpos[:, 3:7])[:, 2]  # cos(tilt) at the drop
        start_tilt = jnp.arccos(jnp.clip(up, -1.0, 1.0))
        return acc, state.info["start_class"], state.info["start_valid"], start_tilt

    acc, label, valid, start_tilt = run(jax.random.PRNGKey(seed))
    acc = {k: np.asarray(v) for k, v in acc.items()}
    label, valid = np.asarray(label), np.asarray(valid)
    start_tilt_deg = np.degrees(np.asarray(start_tilt))
    success = acc["success"] > 0

    def row(i) -> dict:
        times = acc["time_to_stand"][i & success]
        drops, wins = int(i.sum()), int((i & success).sum())
        return {
            "drops": drops,
            "successes": wins,
            "success": wins / drops if drops else float("nan"),
            "success_95": success_interval(wins, drops) if drops else None,
            "time_to_stand_mean_s": float(times.mean()) if times.size else float("nan"),
            "time_to_stand_median_s": float(np.median(times)) if times.size else float("nan"),
            "time_to_stand_p90_s": float(np.percentile(times, 90)) if times.size else float("nan"),
            "overlap_step_share": float(acc["overlap_steps"][i].sum() / (n_steps * max(i.sum(), 1))),
            "guarded_step_share": float(acc["guarded_steps"][i].sum() / (n_steps * max(i.sum(), 1))),
            "max_motor_speed_rps": float(acc["max_motor_speed"][i].max()) if i.any() else float("nan"),
            # failures that end the episode on the back (tilt above ON_BACK_TILT_RAD), where the
            # legs cannot turn the robot over (robots/quadson/getup_reach.py)
            "failures_on_back": int((i & ~success & (acc["final_tilt"] > ON_BACK_TILT_RAD)).sum()),
        }

    if starts == "topples":
        rows = [{"start_class": "toppled", **row(label == TOPPLED_CLASS)}]
    else:
        rows = [{"start_class": c, **row(label == k)} for k, c in enumerate(CLASSES)]
    edges = START_TILT_BINS_DEG
    total = {
        "ground": ground,
        **row(np.ones(drops, bool)),
        "non_finite_resets": int(acc["nan_reset"].sum()),
        "starts_without_valid_pose": int((~valid).sum()),
        # every start, by its tilt at the drop: [low, high) deg, the last bin closed
        "by_start_tilt": [
            {
                "start_tilt_deg": [lo, hi],
                **{k: r[k] for k in ("drops", "successes", "failures_on_back")},
            }
            for lo, hi in zip(edges[:-1], edges[1:], strict=True)
            for r in [row((start_tilt_deg >= lo) & ((start_tilt_deg < hi) | (hi == edges[-1])))]
        ],
    }
    return rows, total
