"""Run by tests/test_multi_device.py with two host CPU devices (XLA_FLAGS set by the caller).

1. compat.pmap_as_sharded_jit against jax.pmap on a function with collectives and a donated input.
2. PPO ('test' preset) on both devices through training.train, recording the collectives in each
   compiled sharded function and how often the training epoch compiled.
Prints one JSON line.
"""

import json
import logging
import re
import sys

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import compat, training
from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import env_config

COLLECTIVES = ("all-gather", "all-reduce", "all-to-all", "collective-permute", "reduce-scatter")


def semantics() -> float:
    def f(x, w):
        y = jnp.tanh(x @ w)
        return {
            "y": y,
            "mean": jax.lax.pmean(y, "d"),
            "sum": jax.lax.psum(jnp.sum(y), "d"),
            "min": jax.lax.pmin(x, "d"),
            "max": jax.lax.pmax(x, "d"),
        }

    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 5, 3)).astype(np.float32)
    w = rng.normal(size=(2, 3, 4)).astype(np.float32)
    want = jax.pmap(f, axis_name="d")(x, w)
    got = compat.pmap_as_sharded_jit(f, axis_name="d", donate_argnums=(0,))(jnp.asarray(x), w)
    assert got["y"].sharding.spec == jax.sharding.PartitionSpec(compat.PMAP_AXIS)
    return max(
        float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
        for a, b in zip(jax.tree.leaves(want), jax.tree.leaves(got), strict=True)
    )


def main(run_dir: str) -> None:
    out = {"devices": jax.local_device_count(), "max_diff_vs_pmap": semantics(), "collectives": {}}
    jit = jax.jit

    def spying_jit(fun, **kw):  # compat's jit over the device mesh: record what XLA made of it
        compiled = jit(fun, **kw)
        if "in_shardings" not in kw:
            return compiled

        def call(*args):
            name = getattr(fun, "__name__", "?")
            if name not in out["collectives"]:
                text = compiled.lower(*args).compile().as_text()
                out["collectives"][name] = {
                    c: len(re.findall(rf"\b{c}(-start)?\(", text)) for c in COLLECTIVES
                }
            return compiled(*args)

        return call

    compat.jax.jit = spying_jit
    messages = []
    handler = logging.Handler(level=logging.WARNING)
    handler.emit = lambda record: messages.append(record.getMessage())
    logging.getLogger("jax").addHandler(handler)
    ppo = apply_overrides(training.ppo_config("test"), ["num_evals=3", "num_timesteps=256"])
    env = apply_overrides(env_config(), ["episode_length_s=0.2"])
    counted = []  # the training log's own count of XLA compilations, at each evaluation
    with jax.log_compiles(True):
        _, _, metrics = training.train(
            env, ppo, run_dir, on_eval=lambda step, record: counted.append(record["progress/xla_compiles"])
        )
    out["xla_compiles_at_evals"] = counted
    out["xla_compiles_logged"] = sum(m.startswith("Finished XLA compilation") for m in messages)
    out["training_epoch_compiles"] = sum(m.startswith("Compiling jit(training_epoch)") for m in messages)
    out["evaluation_compiles"] = sum(m.startswith("Compiling jit(generate_eval_unroll)") for m in messages)
    out["finished"] = metrics["progress/step"] >= 256
    out["checkpoint_step"] = training.latest_checkpoint(run_dir)[1]
    out["eval"] = {k: metrics[k] for k in ("eval/episode_reward", "eval/avg_episode_length")}
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
