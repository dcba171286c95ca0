"""How well trained policies track commands, measured the way the joystick targets are stated: many
environments in MJX, each holding one command of a sweep for a whole trial, RMS of the vx, vy and
yaw-rate errors over every control step after each episode's first second (not smoothed), and the
share of environments that fell.

A policy that observes the simulator's base velocity (the "true_state" observation) can be fed
another velocity instead, as a robot without a state estimator would: `velocity_source` "zero" (the
entries set to 0) or "command" (the commanded vx, vy as the estimate, 0 vertical).

    rows = evaluate([("results/policy_h100_joystick", "true"), ("runs/new", "true")],
                    commands, terrain="rough", seconds=20.0, replicas=4)

A policy is a run directory (its newest checkpoint) or one of its checkpoint files
(RUN/checkpoints/step_*.msgpack, checked against its checksum), as for --init-from.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import rollout as R
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import with_added_keys
from quadson_mjx.obs_spec import VELOCITY_SOURCES
from quadson_mjx.training import init_point, load_policy

SETTLE_S = 1.0  # the first second of every episode is left out of the RMS


def fed_velocity(policy, env, source: str):
    """policy(obs, key) with its observation's base_lin_vel entry replaced by `source` (VELOCITY_SOURCES);
    the policy itself for "true". Raises ValueError for a policy without that entry."""
    if source not in VELOCITY_SOURCES:
        raise ValueError(f"velocity source {source!r}; choose from {VELOCITY_SOURCES}")
    if source == "true":
        return policy
    slices = env.obs_spec.slices()
    if "base_lin_vel" not in slices:
        raise ValueError("this policy observes no base velocity: only the velocity source 'true' applies")
    vel, cmd = slices["base_lin_vel"], slices["command"]

    def fed(obs, key):
        if source == "zero":
            estimate = jnp.zeros(obs.shape[:-1] + (3,), obs.dtype)
        else:
            command = obs[..., cmd]
            estimate = jnp.concatenate([command[..., :2], jnp.zeros_like(command[..., :1])], axis=-1)
        return policy(obs.at[..., vel].set(estimate), key)

    return fed


def eval_config(env_cfg, terrain: str, overrides=()):
    """A run's env config as evaluated: on `terrain`, with the evaluation's overrides ("KEY=VALUE")."""
    return apply_overrides(with_added_keys(env_cfg), [f"terrain={terrain}", *overrides], prefix="env.")


def load_source(source):
    """load_policy of a run directory (its newest checkpoint) or of one of its checkpoint files."""
    path = Path(source)
    if path.is_file():
        run_dir, checkpoint, _ = init_point(path)
        return load_policy(run_dir, checkpoint=checkpoint)
    return load_policy(path)


def tracking_sums(traj, ctrl_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """A host Trajectory [T, B] -> (B, 3) summed squared errors of vx, vy [m/s] and yaw rate [rad/s]
    against the command, and (B,) the steps they sum: every step past the first SETTLE_S seconds
    of its episode, the step that ends an episode left out."""
    measured = np.stack([traj.lin_vel[..., 0], traj.lin_vel[..., 1], traj.ang_vel[..., 2]], -1)
    keep = (traj.episode_step * ctrl_dt > SETTLE_S) & ~traj.done  # (T, B)
    sq = np.sum(np.where(keep[..., None], np.square(measured - traj.command), 0.0), axis=0)
    return sq, keep.sum(axis=0)


def evaluate_one(
    run_dir,
    commands: np.ndarray,
    terrain: str,
    seconds: float,
    velocity_source: str = "true",
    seed: int = 0,
    overrides=(),
) -> dict:
    """One policy (run_dir: a run directory or a checkpoint file of one) over commands (N, 3) (vx
    [m/s], vy [m/s], yaw rate [rad/s]; one environment each, its own randomized model when the
    run's config randomizes; pushes as configured) on `terrain`
    for `seconds`, its env config with `overrides` ("KEY=VALUE", the evaluation's conditions:
    cli.conditions). -> a row: per-axis RMS over the kept steps, falls (environments that fell at
    least once / N), off_field (environments that reached the stone field's edge, a truncation),
    and per-command RMS and falls."""
    policy, env_cfg, _, _ = load_source(run_dir)
    cfg = eval_config(env_cfg, terrain, overrides)
    env = LocomotionEnv(cfg)
    policy = fed_velocity(policy, env, velocity_source)
    n_envs, n_steps = len(commands), int(round(seconds / env.ctrl_dt))
    sq = np.zeros((n_envs, 3))
    kept = np.zeros(n_envs)
    fell = np.zeros(n_envs, bool)
    off = np.zeros(n_envs, bool)
    t0 = time.monotonic()
    for _, traj in R.run(
        env,
        R.policy_controller(policy),
        jax.random.PRNGKey(seed),
        n_envs,
        n_steps,
        segment_steps=250,
        command=np.asarray(commands, np.float32),
        randomize=bool(cfg.randomize),
    ):
        sq_seg, kept_seg = tracking_sums(traj, env.ctrl_dt)
        sq += sq_seg
        kept += kept_seg
        fell |= traj.fall.any(axis=0)
        off |= traj.off_field.any(axis=0)
    rms = np.sqrt(sq.sum(axis=0) / max(kept.sum(), 1))
    per_cmd = np.sqrt(sq / np.maximum(kept, 1)[:, None])
    return {
        "run": str(run_dir),
        "observation": cfg.observation,
        "velocity_source": velocity_source,
        "terrain": terrain,
        "overrides": list(overrides),
        "envs": n_envs,
        "seconds": seconds,
        "rms_vx": float(rms[0]),
        "rms_vy": float(rms[1]),
        "rms_yaw_rate": float(rms[2]),
        "falls": int(fell.sum()),
        "fall_share": float(fell.mean()),
        "off_field": int(off.sum()),
        "wall_s": round(time.monotonic() - t0, 1),
        "per_command": [
            {
                "command": [float(c) for c in commands[i]],
                "rms": [float(v) for v in per_cmd[i]],
                "fell": bool(fell[i]),
            }
            for i in range(n_envs)
        ],
    }


def evaluate(
    policies,
    commands,
    terrains=("flat", "rough"),
    seconds: float = 20.0,
    replicas: int = 1,
    seed: int = 0,
    overrides=(),
):
    """policies: [(run_dir, velocity_source)], commands (N, 3) each repeated `replicas` times ->
    rows of evaluate_one for every policy x terrain (the same commands, seeds and overrides for all)."""
    cmds = np.repeat(np.asarray(commands, np.float32), replicas, axis=0)
    return [
        evaluate_one(run, cmds, terrain, seconds, source, seed, overrides)
        for terrain in terrains
        for run, source in policies
    ]
