"""Fine-tuning a policy whose observation or action has grown since it was trained (--init-from a
run of env.obs_history=1 into a run of obs_history=3, a critic without a ground scan into one with
env.critic_scan_points=n, an actor into one that observes the servos' measured latency
(env.observe_servo_latency), or a policy into one with the gait's two actions (env.gait_action)).

The new observation holds every entry of the old one plus earlier ticks of some of them
("gyro@-1", obs_spec.lagged), the servos' measured latency, the last action's two new components
(GROWN_WITH_ACTIONS) and, for the critic, the ground scan. The widened networks read the old
entries with their trained weights and the new ones with zero weights, so at the start of the
fine-tune they compute exactly what the source's did. The observation normaliser gives each
earlier tick the statistics of its current tick (the same signal a tick later), each cell of the
ground scan the statistics of the source's ground under the four feet pooled (POOLED_FROM: the
same quantity, the ground at a point less the ground under the base, at points near the base), the
measured servo latency the statistics of the source critic's actuation latency (FROM_CRITIC: the
same value with a calibration's error), and the new action components the old ones' pooled. New
actions get zero weights and a zero mean, so their mode (0) leaves the gait as it was
(output_columns). Any other difference between the observations (an entry dropped, renamed,
resized, or new and neither of those) is refused: a weight of zero would not be a neutral start
for it, and its normaliser statistics would be made up.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from quadson_mjx.obs_spec import Spec, unlagged
from quadson_mjx.training.networks import POLICY_OBS_KEY, VALUE_OBS_KEY

# a new entry -> the source's entry whose rows' statistics, pooled, each of its values starts with
POOLED_FROM = {"ground_scan": "ground_under_feet"}
# a new entry -> (entry, component) of the source's critic observation whose row's statistics it
# starts with, in either network: the latency the robot measures is the latency the critic saw
FROM_CRITIC = {"servo_latency": ("physics", 3)}
# entries that grow with the action (env.gait_action adds two actions): the source's components
# come first, the new ones take the source entry's statistics pooled and zero weights
GROWN_WITH_ACTIONS = ("last_action",)


class Source(NamedTuple):
    """Where one entry of the new observation comes from."""

    rows: slice  # the rows of the old observation it takes its statistics from
    own: bool  # True: it is that entry of the old observation (its weights kept); False: new
    size: int  # its number of values (a pooled entry's differs from its rows')
    pooled: bool  # every value takes the rows' statistics pooled (POOLED_FROM); else row by row
    critic: bool = False  # rows of the source's critic observation (FROM_CRITIC), not this network's


def row_sources(old: Spec, new: Spec, old_critic: Spec | None = None) -> list[Source]:
    """For each entry of `new` in order, its Source: an entry of `old` itself, an earlier tick of
    one (row by row), a POOLED_FROM entry, or a FROM_CRITIC row of old_critic (the source's critic
    observation). ValueError naming the entries when `new` is not `old` plus such entries."""
    old_rows = old.slices()
    old_entries = {x.name: x for x in old.entries}
    critic_rows = old_critic.slices() if old_critic is not None else {}
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
        elif POOLED_FROM.get(e.name) in old_rows:
            sources.append(Source(old_rows[POOLED_FROM[e.name]], False, e.size, True))
            continue
        elif e.name in FROM_CRITIC and FROM_CRITIC[e.name][0] in critic_rows and e.size == 1:
            row = critic_rows[FROM_CRITIC[e.name][0]].start + FROM_CRITIC[e.name][1]
            sources.append(Source(slice(row, row + 1), False, 1, False, True))
            continue
        else:
            unknown.append(e.name)
            continue
        was = old_entries[e.name if own else base]
        grown = base in GROWN_WITH_ACTIONS and e.components[: was.size] == was.components
        if rows.stop - rows.start < e.size and grown:  # the source's actions, then the new ones
            sources += [Source(rows, own, was.size, False), Source(rows, False, e.size - was.size, True)]
            continue
        if rows.stop - rows.start != e.size:
            raise ValueError(
                f"entry {e.name} has {e.size} values here, {rows.stop - rows.start} in the source"
            )
        sources.append(Source(rows, own, e.size, False))
    if unknown:
        raise ValueError(
            f"this run observes {', '.join(unknown)}, which the source did not: only earlier ticks of the "
            "source's entries (a longer env.obs_history), the measured servo latency and the critic's "
            "ground scan can be added"
        )
    return sources


def _count(count) -> float:
    """The normaliser's sample count as a number (brax keeps it as a 64-bit {"hi", "lo"} pair)."""
    if isinstance(count, dict):
        return float(np.asarray(count["hi"], np.float64) * 2.0**32 + np.asarray(count["lo"], np.float64))
    return float(np.asarray(count))


def widen_statistics(
    mean, summed_variance, std, count: float, eps: float, sources: list[Source], critic=None
):
    """The normaliser's (mean, summed_variance, std) for the new observation from the old one's
    (brax's Welford statistics over `count` samples, std = sqrt(summed_variance / count + eps)):
    row by row from each Source's rows (a critic Source's from `critic`, the source critic's
    (mean, summed_variance, std)), or for a pooled one the statistics of all its rows' values
    together (the variance includes the spread of the rows' means) in each of its values."""
    mean, summed_variance, std = (np.asarray(x) for x in (mean, summed_variance, std))
    parts = []
    for src in sources:
        if src.critic:
            parts.append([np.asarray(x)[src.rows] for x in critic])
            continue
        if not src.pooled:
            parts.append([x[src.rows] for x in (mean, summed_variance, std)])
            continue
        m_rows = mean[src.rows].astype(np.float64)
        m = m_rows.mean()
        variance = np.mean(summed_variance[src.rows] / count) + np.mean(np.square(m_rows - m))
        sd = np.clip(np.sqrt(variance + eps), 1e-6, 1e6)  # as running_statistics.update computes it
        parts.append([np.full(src.size, v, mean.dtype) for v in (m, variance * count, sd)])
    return [np.concatenate([p[i] for p in parts], axis=0) for i in range(3)]


def first_layer_rows(kernel, sources: list[Source]) -> np.ndarray:
    """A first layer's kernel (old observation size, width) for the new observation: each old
    entry's trained rows, zeros for every new entry's."""
    kernel = np.asarray(kernel)
    parts = [
        kernel[src.rows] if src.own else np.zeros((src.size,) + kernel.shape[1:], kernel.dtype)
        for src in sources
    ]
    return np.concatenate(parts, axis=0)


def output_columns(kernel, bias, old_actions: int, new_actions: int):
    """The policy's output layer (width, 2 x old_actions) and bias for new_actions >= old_actions
    actions: brax's tanh-normal parameters are [loc (A), scale (A)]; each new action gets zero
    weights and a zero loc bias (its mode tanh(0) = 0: env.gait_action's scales at 1, the gait as
    it was), and the mean of the trained scale biases (an exploration like the others')."""
    kernel, bias = np.asarray(kernel), np.asarray(bias)
    if kernel.shape[-1] != 2 * old_actions or new_actions < old_actions:
        raise ValueError(f"the policy's output has {kernel.shape[-1]} values, not 2 x {old_actions} actions")
    extra = new_actions - old_actions
    loc_k, scale_k = np.split(kernel, 2, axis=-1)
    loc_b, scale_b = np.split(bias, 2)
    zeros_k = np.zeros(kernel.shape[:-1] + (extra,), kernel.dtype)
    kernel = np.concatenate([loc_k, zeros_k, scale_k, zeros_k], axis=-1)
    new_b = np.full(extra, scale_b.mean(), bias.dtype)
    bias = np.concatenate([loc_b, np.zeros(extra, bias.dtype), scale_b, new_b])
    return kernel, bias


def widen_params(params, old: dict[str, Spec], new: dict[str, Spec], template, actions=None):
    """(normaliser, policy, value) params of networks that read the observations `old` ({obs key:
    Spec}, brax's dictionary observation: "state" for the policy, "privileged_state" for the value
    network) -> the same params for networks that read `new`, restored into `template` (the new
    networks' fresh params, networks.params_template). actions: (the source's action size, this
    run's) when the policy gives more actions (output_columns; a tanh-normal policy). ValueError
    (row_sources) when `new` is not `old` plus earlier ticks of its entries and pooled entries."""
    from flax import serialization

    if set(old) != {POLICY_OBS_KEY, VALUE_OBS_KEY} or set(new) != set(old):
        raise ValueError("widening needs a dictionary observation (an asymmetric actor-critic) on both sides")
    state = serialization.to_state_dict(params)
    sources = {k: row_sources(old[k], new[k], old[VALUE_OBS_KEY]) for k in old}
    norm = state["0"]
    count = _count(norm["count"])  # Welford's statistics (brax's default; the EMA mode is not used)
    eps = float(np.asarray(norm.get("std_eps", 0.0)))
    critic = tuple(np.asarray(norm[s][VALUE_OBS_KEY]) for s in ("mean", "summed_variance", "std"))
    for k in old:
        norm["mean"][k], norm["summed_variance"][k], norm["std"][k] = widen_statistics(
            norm["mean"][k], norm["summed_variance"][k], norm["std"][k], count, eps, sources[k], critic
        )
    for index, key in (("1", POLICY_OBS_KEY), ("2", VALUE_OBS_KEY)):
        first = state[index]["params"]["hidden_0"]
        first["kernel"] = first_layer_rows(first["kernel"], sources[key])
    if actions is not None and actions[0] != actions[1]:
        layers = state["1"]["params"]
        last = layers[max(layers, key=lambda name: int(name.rpartition("_")[2]))]
        last["kernel"], last["bias"] = output_columns(last["kernel"], last["bias"], *actions)
    return serialization.from_state_dict(template, state)


# the env config keys a widening may change, with the value a config without the key has
WIDENED_KEYS = {
    "obs_history": 1,
    "critic_scan_points": 0,
    "observe_servo_latency": False,
    "gait_action": False,
}


def init_params_for(ckpt, source_run, env, env_cfg, ppo_cfg):
    """-> (params of checkpoint `ckpt` of run `source_run` for this run's networks, {key: the
    source's value} of the WIDENED_KEYS that differ when the networks were widened (else {})).
    env: this run's environment, env_cfg its config. ValueError when the checkpoint does not fit:
    other networks, another observation, a shorter history, a ground scan removed or resized, the
    gait actions removed."""
    from quadson_mjx import compat
    from quadson_mjx.envs import make_env
    from quadson_mjx.training.checkpoints import load_checkpoint
    from quadson_mjx.training.networks import params_template
    from quadson_mjx.training.runs import load_run_config

    src_cfg, _ = load_run_config(source_run)
    changed = {
        k: src_cfg.get(k, default)
        for k, default in WIDENED_KEYS.items()
        if src_cfg.get(k, default) != env_cfg.get(k, default)
    }
    if not changed:
        return load_checkpoint(ckpt, env.observation_size, env.action_size, ppo_cfg), {}
    with compat.mjx_local_device():
        src_env = make_env(src_cfg)
    if src_env.critic_spec is None or env.critic_spec is None:
        named = " and ".join(f"env.{k}" for k in changed)
        raise ValueError(
            f"another {named} than the source's can only be widened for an asymmetric actor-critic"
        )
    old = {POLICY_OBS_KEY: src_env.obs_spec, VALUE_OBS_KEY: src_env.critic_spec}
    new = {POLICY_OBS_KEY: env.obs_spec, VALUE_OBS_KEY: env.critic_spec}
    actions = (src_env.action_size, env.action_size)
    if actions[0] != actions[1] and ppo_cfg.policy_distribution != "tanh_normal":
        raise ValueError(
            f"more actions than the source's ({actions[0]} -> {actions[1]}) can only be added to a "
            f"tanh_normal policy, not {ppo_cfg.policy_distribution}"
        )
    params = load_checkpoint(ckpt, src_env.observation_size, src_env.action_size, ppo_cfg)
    template = params_template(env.observation_size, env.action_size, ppo_cfg)
    return widen_params(params, old, new, template, actions), {k: int(v) for k, v in changed.items()}
