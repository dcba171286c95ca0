"""Wrapping the environment for brax training: vmap (or domain randomization), episode limit with
truncation, and an auto-reset that resamples each episode's command, latency and push timer. An
episode the environment ends at the stone field's edge (`metrics["off_field"]`) is a truncation too.

brax's own AutoResetWrapper restarts a finished episode from the batch's first state, which would
give an environment the same velocity command forever. Ours restarts from the first physics state
(cheap: no reset computed every step) but draws new episode randomness with `env.episode_info`.

On the tiled ground (env.terrain="tiles") an episode restarts somewhere else: every step, the robots
whose episode ended get their next level from the curriculum (terrain_tiles.curriculum_levels on the
distance they covered along their commands against the distance the commands asked for over the
whole episode, so a fall counts the time it cut off) and a fresh start on their tile column at that
level (`env.reset_on_tile`, computed for every robot and kept where done: a kinematics pass and an
observation, no physics step). `info["tile_result"]` keeps each robot's last finished episode:
1 a success (no fall and at least SUCCESS_SHARE of the commanded distance), 0 not.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from brax.envs.base import State, Wrapper
from brax.envs.wrappers import training as brax_training

from quadson_mjx import terrain_tiles
from quadson_mjx.randomize import randomization_fn

SUCCESS_SHARE = 0.8  # a tile episode succeeds with no fall and this share of its commanded distance


class ResamplingAutoReset(Wrapper):
    """Resets done environments to their first physics state with fresh per-episode randomness (on
    the tiled ground: to a fresh start on their tile at the curriculum's level). episode_length:
    control steps of an episode (the tiled ground's commanded distance counts to its end)."""

    def __init__(self, env, episode_length: int | None = None):
        super().__init__(env)
        self._episode_length = episode_length

    def reset(self, rng: jax.Array) -> State:
        check_batch(self.env.unwrapped, rng.shape[0])
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
            if current.ndim == 0 or current.shape[0] != done.shape[0]:
                return current  # Warp's buffers shared by all worlds (contacts), refilled every step
            mask = jnp.reshape(done, done.shape + (1,) * (current.ndim - done.ndim))
            return jnp.where(mask, first, current)

        if self.env.unwrapped.tiles is not None:
            return self._respawn_on_tiles(state, done, where_done)
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

    def reset_on_tiles(self, rng: jax.Array, tile_type, level) -> State:
        """reset (rng: (N, 2) keys) with every robot on the tile the arrays tile_type and level
        (N,) give instead of a random one (an evaluation per tile, a benchmark per type)."""
        state = self.reset(rng)
        n = rng.shape[0]
        tile_type = jnp.broadcast_to(jnp.asarray(tile_type, jnp.int32), (n,))
        level = jnp.broadcast_to(jnp.asarray(level, jnp.int32), (n,))
        keys = jax.vmap(lambda k: jax.random.fold_in(k, 2))(rng)
        fresh = self._vmap_unwrapped(lambda e, k, t, lv: e.reset_on_tile(k, t, lv), keys, tile_type, level)
        info = {**state.info, **fresh.info}
        info["first_pipeline_state"] = fresh.pipeline_state
        info["first_obs"] = fresh.obs
        return state.replace(pipeline_state=fresh.pipeline_state, obs=fresh.obs, info=info)

    def _respawn_on_tiles(self, state: State, done, where_done) -> State:
        env = self.env.unwrapped
        cfg = env.config.tiles
        info = dict(state.info)
        keys = jax.vmap(lambda k: jax.random.split(k, 3))(info["reset_rng"])
        cmd_speed = jnp.linalg.norm(info["command"][:, :2], axis=-1)
        left = self._episode_length - info["steps"] if self._episode_length else 0.0
        commanded = info["tile_commanded_m"] + cmd_speed * jnp.maximum(left, 0.0) * env.ctrl_dt
        progress = info["tile_progress_m"]
        fell = state.metrics["fall"] > 0
        level = info["tile_level"]
        if cfg.curriculum:
            level = terrain_tiles.curriculum_levels(
                level,
                progress,
                commanded,
                keys[0, 2],
                env.tiles.levels,
                cfg.curriculum_up,
                cfg.curriculum_down,
                fell,
            )
        success = ~fell & ((progress >= SUCCESS_SHARE * commanded) | (commanded <= 0))
        fresh = self._vmap_unwrapped(
            lambda e, k, t, lv: e.reset_on_tile(k, t, lv), keys[:, 0], info["tile_type"], level
        )
        for k, v in fresh.info.items():
            info[k] = where_done(v, info[k])
        info["tile_result"] = jnp.where(done, success.astype(jnp.float32), state.info["tile_result"])
        info["reset_rng"] = keys[:, 1]
        pipeline_state = jax.tree.map(where_done, fresh.pipeline_state, state.pipeline_state)
        obs = jax.tree.map(where_done, fresh.obs, state.obs)
        return state.replace(pipeline_state=pipeline_state, obs=obs, info=info)

    def _vmap_unwrapped(self, fn, *args):
        """vmap fn(unwrapped env, *row) over the batch, each row with its own randomized model when
        a DomainRandomizationVmapWrapper is in the chain (as brax's reset and step see it)."""
        e = self.env
        while not isinstance(e, brax_training.DomainRandomizationVmapWrapper) and hasattr(e, "env"):
            e = e.env
        if not isinstance(e, brax_training.DomainRandomizationVmapWrapper):
            return jax.vmap(lambda *a: fn(self.env.unwrapped, *a))(*args)

        def one(sys, *row):
            with e.v_env_fn(sys) as v_env:
                return fn(v_env, *row)

        return jax.vmap(one, in_axes=[e._in_axes] + [0] * len(args))(e._sys_v, *args)


def check_batch(env, n: int) -> None:
    """Raises ValueError when a batch of n worlds is more than env (unwrapped) may step at once
    (env.max_worlds: under MJX's Warp implementation, what its contact buffer holds)."""
    limit = getattr(env, "max_worlds", None)
    if limit is not None and n > limit:
        raise ValueError(
            f"{n} worlds in one batch, but env.warp_max_worlds is {limit} (Warp's contact buffer is "
            f"sized for that many); set env.warp_max_worlds >= {n}"
        )


def wrap_for_training(env, episode_length: int, action_repeat: int = 1, randomization_fn=None):
    """The `wrap_env_fn` for `brax.training.agents.ppo.train`."""
    if randomization_fn is None:
        env = brax_training.VmapWrapper(env)
    else:
        env = brax_training.DomainRandomizationVmapWrapper(env, randomization_fn)
    env = brax_training.EpisodeWrapper(env, episode_length, action_repeat)
    return ResamplingAutoReset(env, episode_length)


def wrap_for_evaluation(env, cfg, n: int, seed: int, steps: int):
    """n copies of env for an evaluation of `steps` steps, in the training wrappers (no episode ends
    within them): each on its own model randomized over cfg.randomization (keys from seed + 1) when
    cfg.randomize, else all on the nominal model."""
    rand = None
    if cfg.randomize:
        rand = functools.partial(
            randomization_fn(cfg.randomization, env.base_body),
            rng=jax.random.split(jax.random.PRNGKey(seed + 1), n),
        )
    return wrap_for_training(env, steps + 1, randomization_fn=rand)
