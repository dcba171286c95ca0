"""Config overrides: typed, dotted, and loud on typos."""

import jax
import ml_collections
import numpy as np
import pytest

from quadson_mjx import compat
from quadson_mjx.config import apply_overrides, conform, from_json, to_json


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


@pytest.mark.parametrize(
    "override, key",
    [
        ("reward.forward_sigma=0", "env.reward.forward_sigma"),
        ("reward.tracking_sigma=-1", "env.reward.tracking_sigma"),
        ("terrain=moon", "env.terrain"),
        ("gait=hop", "env.gait"),
        ("ctrl_dt=0", "env.ctrl_dt"),
        ("gait_ramp_s=0", "env.gait_ramp_s"),
        ("command_range.vx=(0.5, -0.5)", "env.command_range.vx"),
        ("randomization.friction=(0, 1)", "env.randomization.friction"),
        ("reward.weights.torque_l2=1e999", "env.reward.weights.torque_l2"),
        ("noise.rpy=-0.1", "env.noise.rpy"),
        ("gait_scale.cycle_s=0", "env.gait_scale.cycle_s"),
        ("gait_scale.step_length_m=-1", "env.gait_scale.step_length_m"),
        ("yaw_error_tau_s=-1", "env.yaw_error_tau_s"),
        # the yaw error integrates the commanded yaw rate's error from the gyro: sensors and a command
        ("yaw_error_tau_s=1", "env.yaw_error_tau_s > 0 needs env.observation=sensors"),
        ("observe_servo_latency=true", "env.observe_servo_latency needs env.observation=sensors"),
        ("sensor.servo_latency_error_s=-0.001", "env.sensor.servo_latency_error_s"),
        ("reward.velocity_ema_s=0", "env.reward.velocity_ema_s"),
        # the moving average takes dt / tau of each control step's velocity: at most all of it
        ("reward.velocity_ema_s=0.01", "env.reward.velocity_ema_s must be >= ctrl_dt"),
    ],
)
def test_env_config_values_out_of_range_are_errors_naming_the_key_regression(override, key):
    # Regression (issue 13, item 4): these were accepted (forward_sigma=0 divides by zero in the
    # reward kernel; terrain=moon failed later in the model builder with a traceback).
    from quadson_mjx.env_config import check_env_config, env_config

    cfg = apply_overrides(env_config(), [override])
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        check_env_config(cfg)
    check_env_config(env_config(command_tracking=True, randomize=True, pushes=True, terrain="rough"))


def test_conform_checks_types_and_keys_against_the_factory():
    ref = _cfg().env
    good = {
        "reward": {"forward_target": 1, "weights": {"lateral_l2": -0.8}},
        "terrain": "flat",
        "push": False,
        "num_legs": 4,
        "range": [0, 1.5],
    }
    cfg = conform(good, ref, "env.", "f.json")
    assert cfg.range == (0.0, 1.5) and cfg.reward.forward_target == 1.0
    for data, message in (
        ({**good, "num_legs": "4"}, "env.num_legs"),
        ({**good, "extra": 1}, "env.extra"),
        ({k: v for k, v in good.items() if k != "push"}, "env.push' is missing"),
        ({**good, "range": [0, 1, 2]}, "env.range"),
        ({**good, "reward": 3}, "env.reward"),
    ):
        with pytest.raises(ValueError, match=message):
            conform(data, ref, "env.", "f.json")


def test_overrides_leave_the_given_config_alone_regression():
    # Regression: config_flags' DEFINE_config_dict mutates the ConfigDict it is given; apply_overrides
    # hands it a copy, so the caller's config (a task's, a loaded run's) keeps its values.
    cfg = _cfg()
    before = to_json(cfg)
    out = apply_overrides(cfg, ["env.terrain=rough", "env.range=(0, 2)", "env.push=true"])
    assert to_json(cfg) == before and cfg.is_locked
    assert out.env.terrain == "rough" and out.is_locked
    with pytest.raises(AttributeError):
        out.env.new_key = 1  # locked: a typo cannot add a key


@pytest.mark.parametrize(
    "override, words",
    [
        ("env.num_legs=2.5", ["'env.num_legs'", "2.5"]),
        ("env.push=maybe", ["'env.push' takes true/false", "maybe"]),
        ("env.range=(1, 2, 3)", ["'env.range' takes 2 values, got 3"]),
        ("env.range=0.5", ["'env.range' takes 2 values, got 1"]),  # config_flags reads 0.5 as (0.5,)
        ("env.range=(0, 'a')", ["'env.range'", "(0, 'a')"]),
        ("env.range=(0, True)", ["'env.range'"]),  # a bool is no number here
        ("env.reward.forward_target=fast", ["'env.reward.forward_target'", "fast"]),
    ],
)
def test_config_flags_errors_are_one_line_naming_the_key(override, words):
    with pytest.raises(ValueError) as e:
        apply_overrides(_cfg(), ["env.terrain=rough", override, "env.num_legs=3"])
    message = str(e.value)
    assert "\n" not in message and all(w in message for w in words), message


def test_unknown_key_among_several_is_named_with_the_prefix():
    # config_flags alone answers a bare AttributeError "'ax'"
    with pytest.raises(ValueError, match=r"^unknown config key 'ppo.env.ax'; did you mean ppo.env.range\?$"):
        apply_overrides(_cfg(), ["env.terrain=rough", "env.ax=1"], prefix="ppo.")


def test_tuple_elements_take_the_defaults_types():
    cfg = apply_overrides(_cfg(), ["env.range=(0, 2)"])
    assert cfg.env.range == (0.0, 2.0) and all(type(v) is float for v in cfg.env.range)
    cfg = apply_overrides(_cfg(), ["env.range=0.5,1"])  # config_flags' tuple syntax without brackets
    assert cfg.env.range == (0.5, 1.0)


def test_later_override_of_a_key_wins():
    assert apply_overrides(_cfg(), ["env.num_legs=2", "env.num_legs=3"]).env.num_legs == 3


def test_a_loaded_configs_lists_stay_lists():
    # a config read back from JSON holds lists, which config_flags does not override
    cfg = from_json('{"range": [0.0, 1.0], "hidden": [64, 64], "n": 1}')
    out = apply_overrides(cfg, ["range=(0.5, 2)", "n=2"])
    assert out.range == [0.5, 2.0] and out.hidden == [64, 64] and out.n == 2
    assert cfg.range == [0.0, 1.0]


def test_non_finite_values_parse_and_the_env_check_refuses_them():
    from quadson_mjx.env_config import check_env_config, env_config

    for text in ("nan", "inf", "-inf"):
        cfg = apply_overrides(env_config(), [f"reward.forward_target={text}"])
        with pytest.raises(ValueError, match=r"env\.reward\.forward_target must be finite"):
            check_env_config(cfg)


def test_compat_refuses_an_untested_brax_or_jax(monkeypatch):
    compat.check_versions()  # the installed ones are the tested ones
    for brax_version, jax_version in (("0.14.2", "0.10.2"), ("0.14.2", "0.11.2"), ("0.14.2", "0.11.9")):
        compat.check_versions(brax_version, jax_version)
    for brax_version, jax_version in (("0.14.1", "0.10.2"), ("0.15.0", "0.11.2"), ("0.14.2", "0.10.1"), ("0.14.2", "0.12.0")):  # fmt: skip
        with pytest.raises(ImportError, match=r"^quadson_mjx.compat is tested with brax 0.14.2 and jax 0.10.2-0.11.x; found") as e:  # fmt: skip
            compat.check_versions(brax_version, jax_version)
        assert f"brax {brax_version} and jax {jax_version}" in str(e.value) and "\n" not in str(e.value)
    monkeypatch.setattr(jax, "__version__", "0.9.0")  # the installed jax's own string
    with pytest.raises(ImportError, match="found brax .* and jax 0.9.0: install the pinned versions"):
        compat.check_versions()
