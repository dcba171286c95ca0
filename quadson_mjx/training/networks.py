"""brax's PPO networks for a PPO config: the policy distribution's factory and the parameter template
a checkpoint restores into."""

from __future__ import annotations

import jax
import numpy as np

from quadson_mjx.training.presets import POLICY_DISTRIBUTIONS

# the keys of a dictionary observation (LocomotionEnv with asymmetric_critic): the actor reads
# "state", the critic "privileged_state" (brax PPO's policy_obs_key and value_obs_key)
POLICY_OBS_KEY, VALUE_OBS_KEY = "state", "privileged_state"


def make_networks(obs_size, action_size: int, ppo_cfg):
    """brax's PPO networks for `ppo_cfg.policy_distribution` (see ppo_config). obs_size: the env's
    observation_size, an int or, for an asymmetric actor-critic, {"state": (actor,),
    "privileged_state": (critic,)}: the policy network then reads "state" and the value network
    "privileged_state" (each through its own observation normaliser)."""
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
    if isinstance(obs_size, dict):
        extra.update(policy_obs_key=POLICY_OBS_KEY, value_obs_key=VALUE_OBS_KEY)
    return ppo_networks.make_ppo_networks(
        obs_size,
        action_size,
        preprocess_observations_fn=normalize,
        policy_hidden_layer_sizes=tuple(ppo_cfg.policy_hidden),
        value_hidden_layer_sizes=tuple(ppo_cfg.value_hidden),
        **extra,
    )


def params_template(obs_size, action_size: int, ppo_cfg):
    """Freshly initialised (normaliser, policy, value) params: the structure a checkpoint restores
    into (a dictionary observation has one normaliser state per key)."""
    from brax.training.acme import running_statistics, specs

    nets = make_networks(obs_size, action_size, ppo_cfg)
    key_p, key_v = jax.random.split(jax.random.PRNGKey(0))
    if isinstance(obs_size, dict):
        shapes = {k: specs.Array(tuple(v), np.dtype("float32")) for k, v in obs_size.items()}
    else:
        shapes = specs.Array((obs_size,), np.dtype("float32"))
    normalizer = running_statistics.init_state(shapes)
    return (normalizer, nets.policy_network.init(key_p), nets.value_network.init(key_v))
