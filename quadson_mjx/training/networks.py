"""brax's PPO networks for a PPO config: the policy distribution's factory and the parameter template
a checkpoint restores into."""

from __future__ import annotations

import jax
import numpy as np

from quadson_mjx.training.presets import POLICY_DISTRIBUTIONS


def make_networks(obs_size: int, action_size: int, ppo_cfg):
    """brax's PPO networks for `ppo_cfg.policy_distribution` (see ppo_config)."""
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import networks as ppo_networks

    kind = ppo_cfg.policy_distribution
    if kind not in POLICY_DISTRIBUTIONS:
        raise ValueError(f"ppo.policy_distribution is {kind!r}; choose from {list(POLICY_DISTRIBUTIONS)}")
    extra = {}
    if kind == "gait_normal":
        extra = {
            "distribution_type": "normal",
            "noise_std_type": "log",  # std = exp(param): stays positive whatever the update
            "init_noise_std": float(ppo_cfg.init_noise_std),
            "mean_kernel_init_fn": jax.nn.initializers.constant,
            "mean_kernel_init_kwargs": {"value": 0.0},
        }
    normalize = running_statistics.normalize if ppo_cfg.normalize_observations else (lambda x, y: x)
    return ppo_networks.make_ppo_networks(
        obs_size,
        action_size,
        preprocess_observations_fn=normalize,
        policy_hidden_layer_sizes=tuple(ppo_cfg.policy_hidden),
        value_hidden_layer_sizes=tuple(ppo_cfg.value_hidden),
        **extra,
    )


def params_template(obs_size: int, action_size: int, ppo_cfg):
    """Freshly initialised (normaliser, policy, value) params: the structure a checkpoint restores into."""
    from brax.training.acme import running_statistics, specs

    nets = make_networks(obs_size, action_size, ppo_cfg)
    key_p, key_v = jax.random.split(jax.random.PRNGKey(0))
    normalizer = running_statistics.init_state(specs.Array((obs_size,), np.dtype("float32")))
    return (normalizer, nets.policy_network.init(key_p), nets.value_network.init(key_v))
