"""--init-from into a longer observation history or a critic with a ground scan
(training/widen.py): the widened networks compute what the source's did, the normaliser's
statistics of an earlier tick are its current tick's, a scan cell's are the source's ground under
the feet pooled, and every other change of the observation is refused."""

from pathlib import Path

import jax
import numpy as np
import pytest
from brax.training.agents.ppo import networks as ppo_networks

from quadson_mjx import obs_spec, training
from quadson_mjx.config import apply_overrides
from quadson_mjx.envs import make_env
from quadson_mjx.training.widen import init_params_for, output_columns, row_sources, widen_params

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "results" / "tiles_swing_h200"  # a committed run: obs_history 1, asymmetric critic


def _widen(override: str):
    """The committed tiles policy's final checkpoint widened into a run with env `override` ->
    (source env, this env, ppo config, source params, widened params, widened_from)."""
    src_cfg, ppo_cfg = training.load_run_config(SOURCE)
    src_env = make_env(src_cfg)
    env = make_env(apply_overrides(src_cfg, [override]))
    ckpt, _ = training.latest_checkpoint(SOURCE)
    params, widened_from = init_params_for(ckpt, SOURCE, env, env.config, ppo_cfg)
    source = training.load_checkpoint(ckpt, src_env.observation_size, src_env.action_size, ppo_cfg)
    return src_env, env, ppo_cfg, source, params, widened_from


@pytest.fixture(scope="module")
def widened():
    """The committed tiles policy's final checkpoint widened into a run of obs_history 3."""
    return _widen("obs_history=3")


def _observations(src_env, env, rng):
    """A batch of the source's observations (random values), and this run's: the same entries
    (an entry grown by actions: in its first values) with random values in the new ones."""
    old, new = {}, {}
    for key, s_old, s_new in (
        ("state", src_env.obs_spec, env.obs_spec),
        ("privileged_state", src_env.critic_spec, env.critic_spec),
    ):
        x_old = rng.normal(size=(16, s_old.size)).astype(np.float32)
        x_new = rng.normal(size=(16, s_new.size)).astype(np.float32)
        for name, rows in s_old.slices().items():  # an entry grown by actions: its first values
            start = s_new.slices()[name].start
            x_new[:, start : start + rows.stop - rows.start] = x_old[:, rows]
        old[key], new[key] = x_old, x_new
    return old, new


def _same_outputs(src_env, env, ppo_cfg, source, params):
    """The widened networks' actions and values against the source's on the same observations (new
    entries random): equal up to float32 rounding. -> (the new observations, the key)."""
    old_obs, new_obs = _observations(src_env, env, np.random.default_rng(0))
    nets_old = training.make_networks(src_env.observation_size, src_env.action_size, ppo_cfg)
    nets_new = training.make_networks(env.observation_size, env.action_size, ppo_cfg)
    act_old = jax.jit(ppo_networks.make_inference_fn(nets_old)(source, deterministic=True))
    act_new = jax.jit(ppo_networks.make_inference_fn(nets_new)(params, deterministic=True))
    key = jax.random.PRNGKey(0)
    a_old, a_new = act_old(old_obs, key)[0], act_new(new_obs, key)[0]
    np.testing.assert_allclose(np.asarray(a_new), np.asarray(a_old), rtol=0, atol=1e-6)
    v_old = nets_old.value_network.apply(source[0], source[2], old_obs)
    v_new = nets_new.value_network.apply(params[0], params[2], new_obs)
    np.testing.assert_allclose(np.asarray(v_new), np.asarray(v_old), rtol=1e-6, atol=1e-5)
    return new_obs, key


def test_widened_networks_compute_what_the_source_did(widened):
    src_env, env, ppo_cfg, source, params, widened_from = widened
    assert widened_from == {"obs_history": 1}
    assert env.obs_spec.size == src_env.obs_spec.size + 2 * 42  # two earlier ticks of 3 + 3 + 12 + 12 + 12
    new_obs, key = _same_outputs(src_env, env, ppo_cfg, source, params)
    nets_new = training.make_networks(env.observation_size, env.action_size, ppo_cfg)
    a_new = ppo_networks.make_inference_fn(nets_new)(params, deterministic=True)(new_obs, key)[0]
    # and the earlier ticks do reach the networks once their weights move: not a dead input
    moved = jax.tree.map(lambda x: x, params)
    kernel = np.array(moved[1]["params"]["hidden_0"]["kernel"])
    kernel[env.obs_spec.slices()["gyro@-2"]] = 0.1
    moved[1]["params"]["hidden_0"]["kernel"] = kernel
    a_moved = ppo_networks.make_inference_fn(nets_new)(moved, deterministic=True)(new_obs, key)[0]
    assert float(np.max(np.abs(np.asarray(a_moved) - np.asarray(a_new)))) > 1e-3


def test_earlier_ticks_take_their_current_ticks_statistics(widened):
    src_env, env, _, source, params, _ = widened
    for key, s_old, s_new in (
        ("state", src_env.obs_spec, env.obs_spec),
        ("privileged_state", src_env.critic_spec, env.critic_spec),
    ):
        for field in ("mean", "std", "summed_variance"):
            old, new = np.asarray(getattr(source[0], field)[key]), np.asarray(getattr(params[0], field)[key])
            for name, rows in s_new.slices().items():
                want = old[s_old.slices()[obs_spec.unlagged(name)]]
                np.testing.assert_array_equal(new[rows], want, err_msg=f"{key} {field} {name}")
        kernel = np.asarray(params[1 if key == "state" else 2]["params"]["hidden_0"]["kernel"])
        for name, rows in s_new.slices().items():
            if "@-" in name:
                assert not np.any(kernel[rows]), name
    assert jax.tree.all(jax.tree.map(np.array_equal, params[0].count, source[0].count))
    assert jax.tree.structure(params) == jax.tree.structure(
        training.params_template(env.observation_size, env.action_size, widened[2])
    )


def _spec(history=1, yaw_error=False):
    return obs_spec.sensor_observation(("fl", "fr"), ("m0", "m1"), 4, history, True, yaw_error)


def test_only_earlier_ticks_can_be_added():
    sources = row_sources(_spec(1), _spec(3))
    assert [src.own for src in sources].count(False) == 10  # 2 ticks x 5 history entries
    assert not any(src.pooled for src in sources)
    with pytest.raises(ValueError, match="observes yaw_error, which the source did not"):
        row_sources(_spec(1), _spec(1, yaw_error=True))
    with pytest.raises(ValueError, match="lacks the source's gravity@-1"):
        row_sources(_spec(2), _spec(1))
    resized = obs_spec.sensor_observation(("fl", "fr"), ("m0", "m1", "m2"), 4, 3, True)
    with pytest.raises(ValueError, match="entry motor_pos has 3 values here, 2 in the source"):
        row_sources(_spec(1), resized)
    with pytest.raises(ValueError, match="dictionary observation"):
        widen_params(None, {"state": _spec(1)}, {"state": _spec(3)}, None)


@pytest.fixture(scope="module")
def scanned():
    """The committed tiles policy's final checkpoint widened into a run whose critic also sees a
    5 x 5 ground scan."""
    return _widen("critic_scan_points=5")


def test_a_critic_scan_added_starts_where_the_source_was(scanned):
    src_env, env, ppo_cfg, source, params, widened_from = scanned
    assert widened_from == {"critic_scan_points": 0}
    assert env.obs_spec == src_env.obs_spec
    assert env.critic_spec.size == src_env.critic_spec.size + 25
    new_obs, _ = _same_outputs(src_env, env, ppo_cfg, source, params)
    scan = env.critic_spec.slices()["ground_scan"]
    assert not np.any(np.asarray(params[2]["params"]["hidden_0"]["kernel"])[scan])
    # the scan reaches the value network once its weights move: not a dead input
    nets = training.make_networks(env.observation_size, env.action_size, ppo_cfg)
    moved = jax.tree.map(lambda x: x, params)
    kernel = np.array(moved[2]["params"]["hidden_0"]["kernel"])
    kernel[scan] = 0.1
    moved[2]["params"]["hidden_0"]["kernel"] = kernel
    v = nets.value_network.apply(params[0], params[2], new_obs)
    v_moved = nets.value_network.apply(moved[0], moved[2], new_obs)
    assert float(np.max(np.abs(np.asarray(v_moved) - np.asarray(v)))) > 1e-3
    # the scan's statistics by hand from the source's ground under the four feet (mean and std as
    # stored): their values pooled, so the variance is the mean of theirs plus their means' spread
    feet = src_env.critic_spec.slices()["ground_under_feet"]
    m = np.asarray(source[0].mean["privileged_state"], np.float64)[feet]
    sd = np.asarray(source[0].std["privileged_state"], np.float64)[feet]
    want_mean = m.mean()
    want_std = np.sqrt(np.mean(sd**2) + np.mean((m - want_mean) ** 2))
    got_mean = np.asarray(params[0].mean["privileged_state"])[scan]
    got_std = np.asarray(params[0].std["privileged_state"])[scan]
    np.testing.assert_allclose(got_mean, np.full(25, want_mean), rtol=1e-5)
    np.testing.assert_allclose(got_std, np.full(25, want_std), rtol=1e-4)
    assert want_std > sd.min()  # not one foot's statistics
    # the statistics brax derives from them on its next update agree with the std given
    count = float(params[0].count.hi) * 2.0**32 + float(params[0].count.lo)  # brax's 64-bit count
    sv = np.asarray(params[0].summed_variance["privileged_state"], np.float64)[scan]
    np.testing.assert_allclose(np.sqrt(sv / count), got_std, rtol=1e-4)
    # every entry the source had keeps its statistics
    for name, rows in src_env.critic_spec.slices().items():
        for field in ("mean", "std", "summed_variance"):
            old = np.asarray(getattr(source[0], field)["privileged_state"])[rows]
            new = np.asarray(getattr(params[0], field)["privileged_state"])[env.critic_spec.slices()[name]]
            np.testing.assert_array_equal(new, old, err_msg=f"{field} {name}")


@pytest.fixture(scope="module")
def latency_aware():
    """The committed tiles policy's final checkpoint widened into a run whose actor (and so its
    critic) also observes the servos' measured latency."""
    return _widen("observe_servo_latency=true")


def test_the_measured_servo_latency_starts_with_the_critics_latency_statistics(latency_aware):
    src_env, env, ppo_cfg, source, params, widened_from = latency_aware
    assert widened_from == {"observe_servo_latency": 0}
    assert env.obs_spec.size == src_env.obs_spec.size + 1
    assert env.obs_spec.entries[-1].name == "servo_latency"
    _same_outputs(src_env, env, ppo_cfg, source, params)
    # the source critic's actuation latency: physics' fourth component
    row = src_env.critic_spec.slices()["physics"].start + 3
    assert src_env.critic_spec.names[row] == "physics.actuation_latency"
    for key, spec, net in (("state", env.obs_spec, 1), ("privileged_state", env.critic_spec, 2)):
        rows = spec.slices()["servo_latency"]
        for field in ("mean", "std", "summed_variance"):
            want = np.asarray(getattr(source[0], field)["privileged_state"])[row : row + 1]
            got = np.asarray(getattr(params[0], field)[key])[rows]
            np.testing.assert_array_equal(got, want, err_msg=f"{key} {field}")
        assert not np.any(np.asarray(params[net]["params"]["hidden_0"]["kernel"])[rows])
    # trained with 0-20 ms uniform: a mean near 10 ms, a std near 20 ms / sqrt(12)
    mean = float(np.asarray(source[0].mean["privileged_state"])[row])
    std = float(np.asarray(source[0].std["privileged_state"])[row])
    assert 0.008 < mean < 0.012 and 0.004 < std < 0.008, (mean, std)


def test_gait_actions_added_leave_the_gait_as_it_was():
    """The committed tiles policy widened into a run with env.gait_action: two more actions (the
    gait's step length and frequency scales) whose mode is 0 (scale 1) and whose exploration is the
    trained actions' mean; the source's 12 actions and its value unchanged, whatever the new
    last_action components read; those take the source's last_action statistics pooled."""
    src_env, env, ppo_cfg, source, params, widened_from = _widen("gait_action=true")
    assert widened_from == {"gait_action": 0} and (src_env.action_size, env.action_size) == (12, 14)
    assert env.obs_spec.size == src_env.obs_spec.size + 2
    assert env.critic_spec.size == src_env.critic_spec.size + 2
    old_obs, new_obs = _observations(src_env, env, np.random.default_rng(1))  # a12, a13 random
    nets_old = training.make_networks(src_env.observation_size, src_env.action_size, ppo_cfg)
    nets_new = training.make_networks(env.observation_size, env.action_size, ppo_cfg)
    key = jax.random.PRNGKey(0)
    a_old = ppo_networks.make_inference_fn(nets_old)(source, deterministic=True)(old_obs, key)[0]
    a_new = ppo_networks.make_inference_fn(nets_new)(params, deterministic=True)(new_obs, key)[0]
    np.testing.assert_allclose(np.asarray(a_new)[:, :12], np.asarray(a_old), rtol=0, atol=1e-6)
    assert not np.any(np.asarray(a_new)[:, 12:])  # tanh(0): both scales at 1
    v_old = nets_old.value_network.apply(source[0], source[2], old_obs)
    v_new = nets_new.value_network.apply(params[0], params[2], new_obs)
    np.testing.assert_allclose(np.asarray(v_new), np.asarray(v_old), rtol=1e-6, atol=1e-5)
    out_old = source[1]["params"]["hidden_4"]
    out_new = params[1]["params"]["hidden_4"]
    bias_old, bias_new = np.asarray(out_old["bias"]), np.asarray(out_new["bias"])
    assert bias_new.shape == (28,) and not np.any(np.asarray(out_new["kernel"])[:, [12, 13, 26, 27]])
    np.testing.assert_array_equal(bias_new[[12, 13]], 0.0)
    np.testing.assert_allclose(bias_new[[26, 27]], bias_old[12:].mean(), rtol=1e-6)
    np.testing.assert_array_equal(bias_new[14:26], bias_old[12:])
    rows_old = src_env.obs_spec.slices()["last_action"]
    rows_new = env.obs_spec.slices()["last_action"]
    m_old = np.asarray(source[0].mean["state"], np.float64)[rows_old]
    m_new = np.asarray(params[0].mean["state"])[rows_new]
    np.testing.assert_array_equal(m_new[:12], m_old.astype(np.float32))
    np.testing.assert_allclose(m_new[12:], m_old.mean(), rtol=1e-5)
    assert not np.any(
        np.asarray(params[1]["params"]["hidden_0"]["kernel"])[rows_new.start + 12 : rows_new.stop]
    )


def test_output_columns_by_hand_and_refusals():
    """Two actions with [loc, scale] columns (a, b | c, d) grown to three: (a, b, 0 | c, d, 0), loc
    bias 0 and scale bias the mean of the trained ones; an output that is not 2 x the action count,
    or fewer actions than the source's, is refused. A gait_normal policy cannot gain actions."""
    kernel = np.array([[1.0, 2.0, 3.0, 4.0]])
    k, b = output_columns(kernel, np.array([0.1, 0.2, -1.0, -3.0]), 2, 3)
    np.testing.assert_array_equal(k, [[1.0, 2.0, 0.0, 3.0, 4.0, 0.0]])
    np.testing.assert_allclose(b, [0.1, 0.2, 0.0, -1.0, -3.0, -2.0])
    for old, new in ((3, 4), (2, 1)):
        with pytest.raises(ValueError, match="the policy's output has 4 values"):
            output_columns(kernel, np.zeros(4), old, new)
    src_cfg, ppo_cfg = training.load_run_config(SOURCE)
    ppo_cfg = apply_overrides(ppo_cfg, ["policy_distribution=gait_normal"])
    env = make_env(apply_overrides(src_cfg, ["gait_action=true"]))
    ckpt, _ = training.latest_checkpoint(SOURCE)
    with pytest.raises(ValueError, match="can only be added to a tanh_normal policy, not gait_normal"):
        init_params_for(ckpt, SOURCE, env, env.config, ppo_cfg)


def test_a_scan_cannot_be_resized_or_dropped():
    legs = ("fl", "fr", "rl", "rr")
    actor = _spec(1)
    five, seven = (obs_spec.privileged_observation(legs, actor, n) for n in (5, 7))
    none = obs_spec.privileged_observation(legs, actor, 0)
    assert [src.pooled for src in row_sources(none, five)][-1]
    with pytest.raises(ValueError, match="entry ground_scan has 49 values here, 25 in the source"):
        row_sources(five, seven)
    with pytest.raises(ValueError, match="lacks the source's ground_scan"):
        row_sources(five, none)


def test_train_refuses_another_observation_and_leaves_no_run(tmp_path):
    """Through train(): an observation the source's cannot be widened into (a longer history, and a
    yaw-error entry besides) is one ValueError naming the checkpoint, before the run directory is
    made."""
    src_cfg, ppo_cfg = training.load_run_config(SOURCE)
    env_cfg = apply_overrides(src_cfg, ["yaw_error_tau_s=0.5", "obs_history=2"])
    with pytest.raises(ValueError, match=r"does not fit this run's networks: .*observes yaw_error"):
        training.train(env_cfg, ppo_cfg, tmp_path / "child", init_from=SOURCE)
    assert not (tmp_path / "child").exists()
