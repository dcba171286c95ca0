"""PPO hyperparameters: the presets (gpu, cpu, test), their checks, the keys added since runs were
published, and what brax derives from them (devices, steps per epoch)."""

from __future__ import annotations

import math

import jax
import ml_collections

from quadson_mjx.config import LAYER_SIZE_KEYS, Rule

# The main job's settings on a GPU (`python train/ppo_mjx.py` with no task and no flag, or
# --task QuadsonFlat): 2048 environments with the preset's 8 minibatches, so 4x its gradient steps
# per sample, reach 0.45 m/s in a quarter of the preset's environment steps (8.0M against 32.8M,
# benchmarks/results/ppo_settings_h200_b); half the unroll (10 steps: an update every 20,480
# samples) reaches it at 6M (benchmarks/results/ppo_settings_h200_c). Evaluations at 0, 6, 12 and
# 18M steps. First runs on one NVIDIA H100 (empty compilation cache) on JAX: 139.0 and 135.0 s,
# 0.45 m/s at 92.4 and 89.7 s (benchmarks/results/time_to_policy_h100_kept.json); the 24M-step,
# 20-step unroll settings before: 134.7-159.9 s, 0.45 m/s at 81.7-126.9 s in five runs. On Warp
# (main_job_env): see there.
MAIN_JOB = {
    "num_envs": 2048,
    "batch_size": 256,
    "unroll_length": 10,
    "num_timesteps": 18_000_000,
    "num_evals": 4,
}


def main_job_env(env_cfg, devices: int) -> tuple[object, str]:
    """The main job's env on a GPU -> (env_cfg, a line saying which MJX implementation it runs on):
    MJX's Warp implementation on one GPU when warp-lang is installed (the `warp` extra), else JAX.
    First runs on one NVIDIA H100, empty compilation and kernel caches: Warp 111.3 and 109.5 s, 0.45
    m/s at 73.0 and 71.7 s; JAX 145.3 and 138.9 s, 0.45 m/s at 98.7 and 92.2 s, in the same calls
    (benchmarks/results/time_to_policy_h100_warp_build.json). On several GPUs it stays on JAX (Warp
    across devices is not measured here). `--env.impl=jax` or `=warp` overrides it."""
    from quadson_mjx import warp_notice
    from quadson_mjx.config import apply_overrides

    if devices > 1:
        return env_cfg, f"env.impl=jax: the main job on {devices} devices runs on MJX's JAX implementation"
    try:
        warp_notice.require_warp()
    except ValueError:
        return env_cfg, (
            "env.impl=jax: warp-lang is not installed (pip install -e '.[warp]' for MJX's faster "
            "Warp implementation)"
        )
    warp_cfg = apply_overrides(env_cfg, ["impl=warp"])
    return warp_cfg, "env.impl=warp: the main job runs on MJX's Warp implementation"


def ppo_config(preset: str = "gpu", main_job: bool = False) -> ml_collections.ConfigDict:
    """PPO hyperparameters. Presets: "gpu" (the real job on one GPU), "cpu" (a small run that
    finishes in minutes on a CPU and still learns), "test" (a few iterations, for tests).
    main_job: with "gpu", the main job's settings (MAIN_JOB) instead of the preset's."""
    base = {
        "num_timesteps": 80_000_000,
        # An evaluation (and checkpoint) every 16M steps: each one runs 128 episodes of 938 sequential
        # steps, 2.74 s on one H100, while 16M training steps take 21.5 s (748k steps/s); with 11,
        # the 10 after the first spent 27 s of a 248 s main job (benchmarks/results_time_to_policy_h100_evals6.json)
        "num_evals": 6,
        "num_envs": 8192,
        "num_eval_envs": 128,
        "episode_length": 0,  # 0: the env config's episode length (18.75 s)
        "unroll_length": 20,
        # 8 minibatches of 1024 envs x 20 steps: the same 163,840 samples per update as 32 x 256,
        # in 4x fewer, larger gradient steps (the small MLPs leave a GPU idle between kernels;
        # measured on one H100: 594k env steps/s against 460k), with twice the learning rate.
        "batch_size": 1024,
        "num_minibatches": 8,
        "num_updates_per_batch": 4,
        "learning_rate": 6e-4,
        # "constant": learning_rate throughout. "adaptive_kl": brax's adaptive schedule (rsl_rl's, as
        # legged_gym and mjlab train their quadrupeds): after every minibatch step the rate is
        # divided by 1.5 when the policy's mean KL divergence from the one that collected the data
        # is above 2 x desired_kl and multiplied by 1.5 when it is below desired_kl / 2, within
        # learning_rate_range; learning_rate is where it starts. Its current value is part of the
        # saved training state, so a resumed run continues with it.
        "learning_rate_schedule": "constant",
        "desired_kl": 0.01,
        "learning_rate_range": (1e-5, 1e-2),
        "entropy_cost": 1e-2,
        "discounting": 0.97,
        "gae_lambda": 0.95,
        "clipping_epsilon": 0.2,
        "max_grad_norm": 1.0,
        "reward_scaling": 1.0,
        "normalize_observations": True,
        "policy_hidden": (128, 128, 128, 128),
        "value_hidden": (256, 256, 256, 256, 256),
        # "tanh_normal": brax's default (tanh-squashed Gaussian, mean and scale from the MLP with
        # random weights, so the untrained policy already pushes every foot off the gait).
        # "gait_normal": a Gaussian whose mean layer starts at zero, so the untrained policy is the
        # gait itself, with a learned state-independent std starting at init_noise_std (used only
        # here). Either way the env clips actions to [-1, 1].
        "policy_distribution": "tanh_normal",
        "init_noise_std": 0.3,
        # Local GPUs to train on (0: all). Several: brax splits the envs and the batch evenly and
        # all-reduces gradients. "sharded_jit" compiles brax's per-device functions as one jit over
        # the devices, of every process in a multi-process run (compat.pmap_as_sharded_jit; jax's
        # own pmap crashes XLA on jax 0.11.2 with two GPUs); "pmap" keeps jax's pmap.
        "max_devices": 0,
        "multi_device": "sharded_jit",
        # Evaluations (the logged eval/* metrics) run the policy's mean action, as deployment does;
        # False samples from the policy as in training (brax's default).
        "deterministic_eval": True,
        # False: no evaluation episodes while training (brax's run_evals=False), so neither their
        # programs (the evaluator's reset and its episode unroll, about 30 s of compilation on the
        # joystick task) nor their runs (2.5 s each at a 4 ms step, 4.7 s at 2 ms, on one H200).
        # The num_evals points still write their checkpoints and log the training epoch's losses;
        # a policy is then judged by quadson-policy-eval or the like after training.
        "run_evals": True,
        "seed": 0,
    }
    presets = {
        "gpu": {},
        "cpu": {
            # 2 min 40 s on 2 cores (measured). Starts from the gait (gait_normal, small exploration
            # noise): random initial offsets make the robot fall, and learning not to fall from
            # there takes more samples than a CPU gives in minutes (README: Results).
            "policy_distribution": "gait_normal",
            "init_noise_std": 0.1,
            "num_timesteps": 600_000,
            "num_evals": 6,
            "num_envs": 128,
            "num_eval_envs": 32,
            "episode_length": 250,
            "batch_size": 128,
            "num_minibatches": 8,
            "learning_rate": 3e-4,
            "policy_hidden": (64, 64),
            "value_hidden": (128, 128),
        },
        "test": {
            "num_timesteps": 2 * 4 * 8 * 2,
            "num_evals": 2,
            "num_envs": 4,
            "num_eval_envs": 2,
            "episode_length": 10,
            "unroll_length": 8,
            "batch_size": 4,
            "num_minibatches": 2,
            "num_updates_per_batch": 1,
            "policy_hidden": (8,),
            "value_hidden": (8,),
        },
    }
    if preset not in presets:
        raise ValueError(f"unknown ppo preset {preset!r}; choose from {list(PRESETS)}")
    main = MAIN_JOB if main_job and preset == "gpu" else {}
    cfg = ml_collections.ConfigDict({**base, **presets[preset], **main, "preset": preset})
    cfg.lock()
    return cfg


def local_devices_to_use(cfg) -> int:
    """This process's devices brax trains on: all local ones, or ppo.max_devices of them."""
    n = jax.local_device_count()
    return min(n, cfg.max_devices) if cfg.max_devices else n


PRESETS = ("gpu", "cpu", "test")

# Every PPO key's allowed values (config.Rule). Upper bounds are far beyond any preset, there to
# catch a typo's order of magnitude: a learning rate above 1 diverges at once, 2^24 environments
# do not fit one GPU (the estimate in loop.py refuses what does not fit this machine's memory).
# A new key without an entry fails tests/test_training_hardening.py.
PPO_RULES: dict[str, Rule] = {
    "num_timesteps": Rule("int", 1, 10**12, "steps"),
    "num_evals": Rule("int", 1, 10_000),
    "num_envs": Rule("int", 1, 2**24),
    "num_eval_envs": Rule("int", 1, 2**20),
    "episode_length": Rule("int", 0, 10**6, "steps (0: the env's episode length)"),
    "unroll_length": Rule("int", 1, 10_000, "steps"),
    "batch_size": Rule("int", 1, 2**24),
    "num_minibatches": Rule("int", 1, 4096),
    "num_updates_per_batch": Rule("int", 1, 1000),
    "learning_rate": Rule("number", 0.0, 1.0, lo_open=True),
    "learning_rate_schedule": Rule("name"),
    "desired_kl": Rule("number", 0.0, 10.0, lo_open=True),
    "learning_rate_range": Rule("pair", 0.0, 1.0, lo_open=True),
    "entropy_cost": Rule("number", 0.0, 10.0),
    "discounting": Rule("number", 0.0, 1.0, lo_open=True),
    "gae_lambda": Rule("number", 0.0, 1.0),
    "clipping_epsilon": Rule("number", 0.0, 10.0, lo_open=True),
    "max_grad_norm": Rule("number", 0.0, 1e6, "(the gradient clipping norm)", lo_open=True),
    "reward_scaling": Rule("number", 0.0, 1e6, lo_open=True),
    "normalize_observations": Rule("bool"),
    "policy_hidden": Rule("vector", 1, 65536, "units per layer"),
    "value_hidden": Rule("vector", 1, 65536, "units per layer"),
    "policy_distribution": Rule("name"),
    "init_noise_std": Rule("number", 0.0, 10.0, lo_open=True),
    "max_devices": Rule("int", 0, 4096, "(0: all)"),
    "multi_device": Rule("name"),
    "deterministic_eval": Rule("bool"),
    "run_evals": Rule("bool"),
    "seed": Rule("int", 0, 2**31 - 1),
    "preset": Rule("name"),
}


def check_ppo_config(cfg) -> None:
    """Raises ValueError naming the key for a value brax would reject late or misread silently:
    a key without a rule in PPO_RULES, numbers out of range or not finite in float32, sizes that do
    not split over the devices, unknown names."""
    for key, value in cfg.items():
        rule = PPO_RULES.get(key)
        if rule is None:
            raise ValueError(f"ppo.{key} has no range in presets.PPO_RULES (a new key needs one)")
        rule.check(f"ppo.{key}", value)
    for key in LAYER_SIZE_KEYS:
        if not 1 <= len(cfg[key]) <= 64 or not all(isinstance(v, int) for v in cfg[key]):
            raise ValueError(f"ppo.{key} must be 1 to 64 layer sizes (integers), got {cfg[key]!r}")
    if cfg.preset not in PRESETS:
        raise ValueError(f"ppo.preset is {cfg.preset!r}; choose from {list(PRESETS)}")
    if cfg.policy_distribution not in POLICY_DISTRIBUTIONS:
        raise ValueError(
            f"ppo.policy_distribution is {cfg.policy_distribution!r}; choose from {list(POLICY_DISTRIBUTIONS)}"
        )
    if cfg.learning_rate_schedule not in LEARNING_RATE_SCHEDULES:
        raise ValueError(
            f"ppo.learning_rate_schedule is {cfg.learning_rate_schedule!r}; choose from {list(LEARNING_RATE_SCHEDULES)}"
        )
    lo, hi = cfg.learning_rate_range
    if cfg.learning_rate_schedule == "adaptive_kl" and not lo <= cfg.learning_rate <= hi:
        raise ValueError(
            f"ppo.learning_rate={cfg.learning_rate} must lie in ppo.learning_rate_range ({lo}, {hi}), "
            "where the adaptive_kl schedule keeps it"
        )
    if cfg.multi_device not in ("sharded_jit", "pmap"):
        raise ValueError(f"ppo.multi_device is {cfg.multi_device!r}; choose 'sharded_jit' or 'pmap'")
    devices = local_devices_to_use(cfg) * jax.process_count()
    for key in ("num_envs", "batch_size"):
        if cfg[key] % devices:
            raise ValueError(f"ppo.{key}={cfg[key]} does not split evenly over {devices} devices")
    if (cfg.batch_size * cfg.num_minibatches) % cfg.num_envs:
        raise ValueError(
            f"ppo.batch_size * ppo.num_minibatches = {cfg.batch_size * cfg.num_minibatches} must be a multiple "
            f"of ppo.num_envs = {cfg.num_envs} (brax collects whole unrolls of every env)"
        )


POLICY_DISTRIBUTIONS = ("tanh_normal", "gait_normal")
# ppo.learning_rate_schedule -> brax's ppo.train(learning_rate_schedule=...)
LEARNING_RATE_SCHEDULES = {"constant": None, "adaptive_kl": "ADAPTIVE_KL"}


def epoch_steps(ppo_cfg) -> tuple[int, int]:
    """-> (environment steps per training epoch, epochs) of brax PPO for `ppo_cfg`: brax splits
    num_timesteps into max(num_evals - 1, 1) epochs of whole training steps, rounding up."""
    per_train_step = ppo_cfg.batch_size * ppo_cfg.unroll_length * ppo_cfg.num_minibatches
    epochs = max(ppo_cfg.num_evals - 1, 1)
    return math.ceil(ppo_cfg.num_timesteps / (epochs * per_train_step)) * per_train_step, epochs


# PPO keys added after runs were already published, with the value that reproduces what those runs
# did: a run directory saved before a key existed is read with it (load_run_config).
PPO_KEYS_ADDED = {
    "policy_distribution": "tanh_normal",
    "init_noise_std": 0.3,
    "max_devices": 0,
    "multi_device": "sharded_jit",
    "deterministic_eval": False,
    "learning_rate_schedule": "constant",
    "desired_kl": 0.01,
    "learning_rate_range": [1e-5, 1e-2],  # as config.json holds it
    "run_evals": True,
}
