"""Wrapping the environment for brax training: vmap (or domain randomization), episode limit with
truncation, and an auto-reset that resamples each episode's command, latency and push timer. An
episode the environment ends at the stone field's edge (`metrics["off_field"]`) is a truncation too.

brax's own AutoResetWrapper restarts a finished episode from the batch's first state, which would
give an environment the same velocity command forever. Ours restarts from the first physics state
(cheap: no reset computed every step) but draws new episode randomness with `env.episode_info`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.base import State, Wrapper
from brax.envs.wrappers import training as brax_training


class ResamplingAutoReset(Wrapper):
    """Resets done environments to their first physics state with fresh per-episode randomness."""

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        state.info["first_pipeline_state"] = state.pipeline_state
        state.info["first_obs"] = state.obs
        state.info["first_info"] = {k: state.info[k] for k in self.env.unwrapped.restart_info}
        state.info["reset_rng"] = jax.vmap(lambda k: jax.random.fold_in(k, 1))(rng)
        return state

    def step(self, state: State, action: jax.Array) -> State:
        if "steps" in state.info:
            state.info["steps"] = jnp.where(state.done, 0, state.info["steps"])
        state = state.replace(done=jnp.zeros_like(state.done))
        state = self.env.step(state, action)
        done = state.done.astype(bool)
        if "truncation" in state.info and "off_field" in state.metrics:
            # the edge of the stone field ends an episode that did not fail: PPO bootstraps its value
            info = dict(state.info)
            info["truncation"] = jnp.where(state.metrics["off_field"] > 0, 1.0, info["truncation"])
            state = state.replace(info=info)

        def where_done(first, current):
            mask = jnp.reshape(done, done.shape + (1,) * (current.ndim - done.ndim))
            return jnp.where(mask, first, current)

        keys = jax.vmap(jax.random.split)(state.info["reset_rng"])
        fresh = jax.vmap(self.env.unwrapped.episode_info)(keys[:, 0])
        info = dict(state.info)
        info["reset_rng"] = keys[:, 1]
        for k, v in fresh.items():
            info[k] = where_done(v, info[k])
        for k, v in info["first_info"].items():
            info[k] = where_done(v, info[k])
        info["last_action"] = jnp.where(done[:, None], 0.0, info["last_action"])
        first = state.info["first_pipeline_state"]
        pipeline_state = jax.tree.map(where_done, first, state.pipeline_state)
        obs = jax.tree.map(where_done, state.info["first_obs"], state.obs)
        obs = self.env.unwrapped.with_command(obs, info["command"])
        return state.replace(pipeline_state=pipeline_state, obs=obs, info=info)


def wrap_for_training(env, episode_length: int, action_repeat: int = 1, randomization_fn=None):
    """The `wrap_env_fn` for `brax.training.agents.ppo.train`."""
    if randomization_fn is None:
        env = brax_training.VmapWrapper(env)
    else:
        env = brax_training.DomainRandomizationVmapWrapper(env, randomization_fn)
    env = brax_training.EpisodeWrapper(env, episode_length, action_repeat)
    return ResamplingAutoReset(env)
