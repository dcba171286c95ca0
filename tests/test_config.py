"""Config overrides: typed, dotted, and loud on typos."""

import jax
import ml_collections
import numpy as np
import pytest

from quadson_mjx import compat
from quadson_mjx.config import apply_overrides, from_json, to_json


def _cfg():
    cfg = ml_collections.ConfigDict(
        {
            "env": {
                "reward": {"forward_target": 0.5, "weights": {"lateral_l2": -0.8}},
                "terrain": "flat",
                "push": False,
                "num_legs": 4,
                "range": (0.0, 1.0),
            }
        }
    )
    cfg.lock()
    return cfg


def test_override_sets_typed_values():
    cfg = apply_overrides(
        _cfg(),
        [
            "--env.reward.forward_target=0.4",
            "env.terrain=rough",
            "--env.push=true",
            "env.num_legs=3",
            "env.range=(0, 2)",
            "env.reward.weights.lateral_l2=-1",
        ],
    )
    assert cfg.env.reward.forward_target == 0.4
    assert cfg.env.terrain == "rough"
    assert cfg.env.push is True
    assert cfg.env.num_legs == 3
    assert cfg.env.range == (0.0, 2.0)
    assert cfg.env.reward.weights.lateral_l2 == -1.0 and isinstance(cfg.env.reward.weights.lateral_l2, float)


def test_unknown_key_names_the_key_and_suggests():
    with pytest.raises(
        ValueError, match=r"unknown config key 'env.reward.forwad_target'.*env.reward.forward_target"
    ):
        apply_overrides(_cfg(), ["--env.reward.forwad_target=0.4"])


@pytest.mark.parametrize(
    "override, message",
    [
        ("env.num_legs=2.5", "env.num_legs"),
        ("env.push=3", "env.push"),
        ("env.range=(1,2,3)", "env.range"),
        ("env.reward.forward_target=fast", "env.reward.forward_target"),
        ("env.terrain", "key.sub=value"),
    ],
)
def test_bad_values_raise_naming_the_key(override, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(_cfg(), [override])


def test_json_round_trip():
    cfg = apply_overrides(_cfg(), ["env.terrain=rough"])
    back = from_json(to_json(cfg))
    assert back.env.terrain == "rough" and back.env.reward.forward_target == 0.5


def test_device_put_replicated_shim_layout():
    # Reference: the removed jax.device_put_replicated(x, devices) returned x stacked once per device.
    tree = {"a": np.arange(6.0).reshape(2, 3), "b": np.float32(2.0)}
    devices = jax.local_devices()
    out = compat._device_put_replicated(tree, devices)
    assert out["a"].shape == (len(devices), 2, 3)
    np.testing.assert_array_equal(np.asarray(out["a"][0]), tree["a"])
    assert out["b"].shape == (len(devices),)
    compat.patch_brax()
    assert callable(jax.device_put_replicated)


def test_network_sizes_take_any_depth():
    from quadson_mjx.training import ppo_config

    cfg = apply_overrides(ppo_config("gpu"), ["policy_hidden=(256, 128)", "value_hidden=64"])
    assert cfg.policy_hidden == (256, 128) and cfg.value_hidden == (64,)
    for bad in ("policy_hidden=()", "policy_hidden=(64, 0)", "policy_hidden=(64.5,)"):
        with pytest.raises(ValueError, match="policy_hidden"):
            apply_overrides(ppo_config("gpu"), [bad])
