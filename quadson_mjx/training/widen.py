"""Fine-tuning a policy with a longer observation history than it was trained with (--init-from a
run of env.obs_history=1 into a run of obs_history=3).

The new observation holds every entry of the old one plus earlier ticks of some of them
("gyro@-1", obs_spec.lagged). The widened networks read the old entries with their trained
weights and the new ones with zero weights, so at the start of the fine-tune they compute exactly
what the source's did; the observation normaliser gives each earlier tick the statistics of its
current tick (the same signal a tick later). Any other difference between the observations (an
entry dropped, renamed, resized, or new and not an earlier tick of an old one) is refused: a
weight of zero would not be a neutral start for it, and its normaliser statistics would be made up.
"""

from __future__ import annotations

import numpy as np

from quadson_mjx.obs_spec import Spec, unlagged
from quadson_mjx.training.networks import POLICY_OBS_KEY, VALUE_OBS_KEY


def row_sources(old: Spec, new: Spec) -> list[tuple[slice, bool]]:
    """For each entry of `new` in order: (the rows of `old` it takes its statistics from, whether
    it is an entry of `old` itself (True) or an earlier tick of one (False)). ValueError naming the
    entries when `new` is not `old` plus earlier ticks of its entries."""
    old_rows = old.slices()
    new_names = {e.name for e in new.entries}
    dropped = [e.name for e in old.entries if e.name not in new_names]
    if dropped:
        raise ValueError(f"this run's observation lacks the source's {', '.join(dropped)}")
    sources, unknown = [], []
    for e in new.entries:
        base = unlagged(e.name)
        if e.name in old_rows:
            rows, own = old_rows[e.name], True
        elif base != e.name and base in old_rows:
            rows, own = old_rows[base], False
        else:
            unknown.append(e.name)
            continue
        if rows.stop - rows.start != e.size:
            raise ValueError(
                f"entry {e.name} has {e.size} values here, {rows.stop - rows.start} in the source"
            )
        sources.append((rows, own))
    if unknown:
        raise ValueError(
            f"this run observes {', '.join(unknown)}, which the source did not: only earlier ticks of the "
            "source's entries (a longer env.obs_history) can be added"
        )
    return sources


def widen_rows(x: np.ndarray, sources, own_only: bool) -> np.ndarray:
    """The rows of x (old size, ...) rearranged for the new observation: each entry's own rows, and
    for an earlier tick either its current tick's rows (own_only False: normaliser statistics) or
    zeros (own_only True: a first layer's weights)."""
    x = np.asarray(x)
    parts = [x[rows] if own or not own_only else np.zeros_like(x[rows]) for rows, own in sources]
    return np.concatenate(parts, axis=0)


def widen_params(params, old: dict[str, Spec], new: dict[str, Spec], template):
    """(normaliser, policy, value) params of networks that read the observations `old` ({obs key:
    Spec}, brax's dictionary observation: "state" for the policy, "privileged_state" for the value
    network) -> the same params for networks that read `new`, restored into `template` (the new
    networks' fresh params, networks.params_template). ValueError (row_sources) when `new` is not
    `old` plus earlier ticks of its entries."""
    from flax import serialization

    if set(old) != {POLICY_OBS_KEY, VALUE_OBS_KEY} or set(new) != set(old):
        raise ValueError("widening needs a dictionary observation (an asymmetric actor-critic) on both sides")
    state = serialization.to_state_dict(params)
    sources = {k: row_sources(old[k], new[k]) for k in old}
    norm = state["0"]
    for field in ("mean", "std", "summed_variance"):
        norm[field] = {k: widen_rows(v, sources[k], own_only=False) for k, v in norm[field].items()}
    for index, key in (("1", POLICY_OBS_KEY), ("2", VALUE_OBS_KEY)):
        first = state[index]["params"]["hidden_0"]
        first["kernel"] = widen_rows(first["kernel"], sources[key], own_only=True)
    return serialization.from_state_dict(template, state)


def init_params_for(ckpt, source_run, env, env_cfg, ppo_cfg):
    """-> (params of checkpoint `ckpt` of run `source_run` for this run's networks, the source's
    obs_history when they were widened to this run's longer one (else None)). env: this run's
    environment, env_cfg its config. ValueError when the checkpoint does not fit: other networks,
    another observation, a shorter history."""
    from quadson_mjx import compat
    from quadson_mjx.envs import make_env
    from quadson_mjx.training.checkpoints import load_checkpoint
    from quadson_mjx.training.networks import params_template
    from quadson_mjx.training.runs import load_run_config

    src_cfg, _ = load_run_config(source_run)
    if src_cfg.get("obs_history", 1) == env_cfg.get("obs_history", 1):
        return load_checkpoint(ckpt, env.observation_size, env.action_size, ppo_cfg), None
    with compat.mjx_local_device():
        src_env = make_env(src_cfg)
    if src_env.critic_spec is None or env.critic_spec is None:
        raise ValueError(
            "another env.obs_history than the source's can only be widened for an asymmetric actor-critic"
        )
    old = {POLICY_OBS_KEY: src_env.obs_spec, VALUE_OBS_KEY: src_env.critic_spec}
    new = {POLICY_OBS_KEY: env.obs_spec, VALUE_OBS_KEY: env.critic_spec}
    params = load_checkpoint(ckpt, src_env.observation_size, src_env.action_size, ppo_cfg)
    template = params_template(env.observation_size, env.action_size, ppo_cfg)
    return widen_params(params, old, new, template), int(src_cfg.obs_history)
