"""PPO training end to end on CPU with the 'test' preset: finite metrics, the MCAP log, checkpoints,
Ctrl-C, resume, inference from a checkpoint, and config errors."""

import io
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mcap.reader import make_reader

from quadson_mjx import training
from quadson_mjx.config import apply_overrides, to_json
from quadson_mjx.env_config import env_config

ROOT = Path(__file__).resolve().parents[1]


def _small_env():
    return apply_overrides(env_config(), ["episode_length_s=0.2"])


RUN = ["num_evals=3", "num_timesteps=192"]  # 2 epochs of 128 steps (test preset: 64 per training step)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """The reference for a resumed run: the same config trained in one go."""
    run_dir = tmp_path_factory.mktemp("reference")
    evals = {}
    _, params, _ = training.train(
        _small_env(),
        apply_overrides(training.ppo_config("test"), RUN),
        run_dir,
        progress_stream=io.StringIO(),
        on_eval=lambda step, record: evals.__setitem__(step, record),
    )
    return evals, params


def _first_metrics_chunk(path):
    """(offset, length) of the chunk holding the first /train/metrics message."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metrics = [c for c in summary.channels.values() if c.topic == "/train/metrics"][0]
        first = min(
            (c for c in summary.chunk_indexes if metrics.id in c.message_index_offsets),
            key=lambda c: c.chunk_start_offset,
        )
    return first.chunk_start_offset, first.chunk_length


@pytest.fixture(scope="module")
def interrupted_then_resumed(tmp_path_factory):
    """A run stopped by Ctrl-C after its first evaluation; one byte of its log's first metrics
    record flipped; then resumed to the end."""
    run_dir = tmp_path_factory.mktemp("run")
    ppo_cfg = apply_overrides(training.ppo_config("test"), RUN)
    evals = []

    def stop_after_first(step, record):
        evals.append((step, record))
        if step > 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        training.train(
            _small_env(), ppo_cfg, run_dir, on_eval=stop_after_first, progress_stream=io.StringIO()
        )
    log = run_dir / "train.mcap"
    interrupted = {
        "evals": list(evals),
        "checkpoint": training.latest_checkpoint(run_dir),
        "log": log.read_bytes(),
    }
    offset, length = _first_metrics_chunk(log)
    damaged = bytearray(interrupted["log"])
    damaged[offset + length - 5] ^= 0x5A  # in the chunk's compressed bytes
    log.write_bytes(bytes(damaged))
    interrupted.update(damaged_log=bytes(damaged), damaged_offset=offset)
    resumed_evals = {}
    out = io.StringIO()
    _, params, metrics = training.train(
        None,
        None,
        run_dir,
        resume=True,
        progress_stream=out,
        on_eval=lambda step, record: resumed_evals.__setitem__(step, record),
    )
    interrupted.update(resumed_evals=resumed_evals, resume_output=out.getvalue())
    return run_dir, interrupted, metrics, params


def test_interrupted_run_keeps_a_checkpoint_and_a_complete_log(interrupted_then_resumed, tmp_path):
    run_dir, interrupted, _, _ = interrupted_then_resumed
    path, step = interrupted["checkpoint"]
    assert 0 < step < 192 and path.exists()
    log = tmp_path / "interrupted.mcap"
    log.write_bytes(interrupted["log"])
    with open(log, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # closed cleanly: the summary is there
        assert summary is not None
        events = [json.loads(m.data)["event"] for _, c, m in reader.iter_messages(topics=["/train/log"])]
    assert events == ["start", "interrupted"]


def test_resumed_run_finishes_with_finite_metrics_and_full_log(interrupted_then_resumed):
    run_dir, interrupted, metrics, _ = interrupted_then_resumed
    assert metrics["progress/step"] >= 192
    for key in ("eval/episode_reward", "eval/avg_episode_length", "eval/episode_reward/forward_velocity_exp"):
        assert math.isfinite(metrics[key]), key
    with open(run_dir / "train.mcap", "rb") as f:
        reader = make_reader(f)
        msgs = [(c.topic, json.loads(m.data)) for _, c, m in reader.iter_messages()]
        meta = {m.name for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    events = [m["event"] for t, m in msgs if t == "/train/log"]
    assert events == ["start", "interrupted", "resume", "finished"]  # the killed run's messages kept
    steps = [m["progress"]["step"] for t, m in msgs if t == "/train/metrics"]
    # step 0's record was in the damaged chunk; the resumed run's re-evaluation of step 128 is not
    # logged twice
    assert steps == [128, 256]
    assert {"env_config", "ppo_config", "versions"} <= meta and "quadson.xml" in attachments
    _, last = [(t, m) for t, m in msgs if t == "/train/metrics"][-1]
    assert "episode_reward" in last["eval"] and "env_steps_per_s" in last["progress"]


def test_resume_after_a_damaged_log_record_keeps_every_original_regression(interrupted_then_resumed):
    # Regression (issue 13, item 1): resume rewrote the log from the damaged record on (losing the
    # intact evaluation and the "interrupted" event after it) and deleted the original.
    run_dir, interrupted, _, _ = interrupted_then_resumed
    kept = run_dir / "train.before_resume_1.mcap"
    assert kept.read_bytes() == interrupted["damaged_log"]  # the original, byte for byte
    with open(run_dir / "train.mcap", "rb") as f:
        msgs = [(c.topic, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages()]
    resume = [m for t, m in msgs if t == "/train/log" and m["event"] == "resume"][0]
    assert resume["kept_log"] == kept.name and resume["step"] == 128
    assert f"offset {interrupted['damaged_offset']}" in resume["damaged_records"]
    assert (
        "kept the previous log as train.before_resume_1.mcap (1 damaged records"
        in interrupted["resume_output"]
    )
    before = [m["progress"]["step"] for t, m in msgs if t == "/train/metrics"]
    assert 128 in before  # the evaluation after the damaged record survived


def test_resumed_run_loads_its_programs_from_the_persistent_cache_regression(interrupted_then_resumed):
    # Regression: the first program traced in a process held a dead constant (array_api_compat's
    # jnp.empty(0)) and jax's traces depended on what ran before, so a second training in one
    # process lowered its programs to other cache keys and compiled them again (the resume here:
    # 24 s and 15 s). conftest.py turns the persistent cache on for programs of over 1 s.
    _, interrupted, _, _ = interrupted_then_resumed
    line = [ln for ln in interrupted["resume_output"].splitlines() if "XLA compilations" in ln][0]
    hits = int(re.search(r"\((\d+) from the cache\)", line).group(1))
    slow = [float(s) for s in re.findall(r"jit\([^)]*\) ([0-9.]+) s", line)]
    assert hits >= 2 and max(slow) < 5.0, line  # the training epoch and the evaluation, loaded


def test_resumed_run_continues_the_uninterrupted_curve_exactly_regression(
    interrupted_then_resumed, uninterrupted
):
    # Regression (issue 13, item 7): resume restarted Adam's moments (and reseeded the run), so its
    # curve left the uninterrupted one. With the whole training state restored (moments, step
    # count, keys, environments) the resumed run is the same computation: on the CPU, XLA is
    # deterministic, so its later evaluation and final parameters equal the reference bit for bit.
    run_dir, interrupted, _, params = interrupted_then_resumed
    ref_evals, ref_params = uninterrupted
    resumed = interrupted["resumed_evals"]
    assert sorted(resumed) == [128, 256] and sorted(ref_evals) == [0, 128, 256]
    for key in ("eval/episode_reward", "eval/avg_episode_length", "eval/episode_forward_speed"):
        assert resumed[256][key] == ref_evals[256][key], key
        # the resumed run's first evaluation re-evaluates the checkpoint with the same key
        assert resumed[128][key] == dict(interrupted["evals"])[128][key] == ref_evals[128][key], key
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(ref_params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (
        training.training_state_path(run_dir, 128).exists() and training.env_state_path(run_dir, 128).exists()
    )
    assert "restoring the whole training state" in interrupted["resume_output"]


def test_checkpoint_loads_for_inference(interrupted_then_resumed):
    run_dir, _, _, params = interrupted_then_resumed
    policy, env_cfg, ppo_cfg, loaded = training.load_policy(run_dir)
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(loaded), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    obs = jnp.zeros(29)
    action, _ = policy(obs, jax.random.PRNGKey(0))
    assert action.shape == (12,) and bool(jnp.all(jnp.abs(action) <= 1.0))
    assert env_cfg.episode_length_s == pytest.approx(0.2) and ppo_cfg.preset == "test"


def test_init_from_starts_a_new_run_from_the_source_parameters(interrupted_then_resumed, tmp_path):
    """Fine-tuning: the new run's step-0 checkpoint is the source's newest parameters bit for bit,
    its configs carry the overrides, and config.json and the log name the source and its hash."""
    source, *_ = interrupted_then_resumed
    src_ckpt, src_step = training.latest_checkpoint(source)
    env_cfg, ppo_cfg = training.load_run_config(source)
    env_cfg = apply_overrides(env_cfg, ["reward.weights.termination=-5"])
    ppo_cfg = apply_overrides(ppo_cfg, ["num_timesteps=128", "num_evals=2"])
    child = tmp_path / "child"
    out = io.StringIO()
    _, params, metrics = training.train(env_cfg, ppo_cfg, child, progress_stream=out, init_from=source)
    assert f"init from {src_ckpt}" in out.getvalue() and math.isfinite(metrics["eval/episode_reward"])
    tmpl = training.params_template(29, 12, ppo_cfg)  # what a fresh run's networks are
    start = training.load_checkpoint(child / "checkpoints" / "step_000000000000.msgpack", 29, 12, ppo_cfg)
    want = training.load_checkpoint(src_ckpt, 29, 12, ppo_cfg)
    for a, b in zip(jax.tree.leaves(start), jax.tree.leaves(want), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert jax.tree.structure(start) == jax.tree.structure(tmpl)
    saved = json.loads((child / "config.json").read_text())
    sha = training.checksum_path(src_ckpt).read_text().split()[0]
    assert saved["init_from"] == {
        "run": str(source),
        "checkpoint": src_ckpt.name,
        "step": src_step,
        "sha256": sha,
    }
    assert saved["env"]["reward"]["weights"]["termination"] == -5.0
    with open(child / "train.mcap", "rb") as f:
        logged = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/train/log"])]
    assert logged[0]["event"] == "start" and json.loads(logged[0]["init_from"])["sha256"] == sha
    # the parameters moved on from the source's after a training epoch
    trained = training.load_checkpoint(training.latest_checkpoint(child)[0], 29, 12, ppo_cfg)
    assert not all(
        np.array_equal(a, b) for a, b in zip(jax.tree.leaves(trained), jax.tree.leaves(want), strict=True)
    )


def test_init_from_refuses_other_networks_and_leaves_no_run(interrupted_then_resumed, tmp_path):
    source, *_ = interrupted_then_resumed
    env_cfg, ppo_cfg = training.load_run_config(source)
    ppo_cfg = apply_overrides(ppo_cfg, ["policy_hidden=16,16"])
    with pytest.raises(ValueError, match="does not fit this run's networks"):
        training.train(env_cfg, ppo_cfg, tmp_path / "other", progress_stream=io.StringIO(), init_from=source)
    assert not (tmp_path / "other").exists()
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        training.train(env_cfg, ppo_cfg, tmp_path / "other", init_from=tmp_path)
    with pytest.raises(ValueError, match="starts a new run"):
        training.train(None, None, source, resume=True, init_from=source)


def test_script_init_from_bad_inputs_exit_2_in_one_line(interrupted_then_resumed, tmp_path):
    source, *_ = interrupted_then_resumed
    cases = [
        (["--init-from", str(tmp_path / "none")], "is not a run directory"),
        (["--init-from", str(source), "--gait", "bound"], "remove --gait"),
        (["--init-from", str(source), "--resume", str(source)], "give one of them"),
        (["--init-from", str(source), "--env.reward.forwad_target=1"], "env.reward.forwad_target"),
        (["--init-from", str(source / "config.json")], "neither a run directory nor"),
    ]
    for args, words in cases:
        out = subprocess.run(
            [sys.executable, str(ROOT / "train" / "ppo_mjx.py"), "--run-dir", str(tmp_path / "R"), *args],
            capture_output=True,
            text=True,
            timeout=300,
        )
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(lines) == 1 and words in lines[0], (args, out.stderr)
        assert not (tmp_path / "R").exists()


def _learning_rates(records):
    """step -> the learning rate brax reports for the training epoch before that evaluation (its
    mean over the epoch's minibatch steps)."""
    return {step: r["training/learning_rate"] for step, r in records.items() if "training/learning_rate" in r}


def test_constant_learning_rate_schedule_keeps_the_rate(uninterrupted):
    evals, _ = uninterrupted
    rates = _learning_rates(evals)
    assert len(rates) == 2 and all(
        r == pytest.approx(training.ppo_config("test").learning_rate) for r in rates.values()
    )


def test_adaptive_kl_schedule_moves_the_rate_and_resumes_with_it(tmp_path):
    """ppo.learning_rate_schedule=adaptive_kl: with desired_kl far below any KL the rate divides by
    1.5 at each minibatch step whose KL is above 0 (all but the first of an epoch's: its policy is
    the one that collected the data) until learning_rate_range's floor, set to lr0 / 1.5^2. The test
    preset's epoch is 2 training steps x 2 minibatches: epoch 1 runs at lr0, lr0, lr0 / 1.5 and the
    floor, epoch 2 at the floor throughout (a fresh start at lr0 would not reach it), also
    after a resume between the two: the rate is part of the saved training state. Far above any KL,
    the rate multiplies instead, up to the range's ceiling lr0 x 1.5^2."""
    base = apply_overrides(training.ppo_config("test"), RUN)
    lr0 = base.learning_rate
    shrink = apply_overrides(
        base,
        ["learning_rate_schedule=adaptive_kl", "desired_kl=1e-9", f"learning_rate_range={lr0 / 2.25},{lr0}"],
    )
    evals = {}

    def stop_after_first(step, record):
        evals[step] = record
        if step > 0:
            raise KeyboardInterrupt

    run_dir = tmp_path / "shrink"
    with pytest.raises(KeyboardInterrupt):
        training.train(_small_env(), shrink, run_dir, on_eval=stop_after_first, progress_stream=io.StringIO())
    resumed = {}
    training.train(
        None, None, run_dir, resume=True, progress_stream=io.StringIO(), on_eval=resumed.__setitem__
    )
    ((step1, r1),) = _learning_rates(evals).items()
    step2, r2 = max(_learning_rates(resumed).items())
    assert step2 > step1
    assert lr0 / 2.25 < r1 < lr0  # it came down during the first epoch
    assert r2 == pytest.approx(lr0 / 2.25, rel=1e-6)  # and stays at the floor after the resume
    grow = apply_overrides(
        base,
        ["learning_rate_schedule=adaptive_kl", "desired_kl=5.0", f"learning_rate_range={lr0},{lr0 * 2.25}"],
    )
    evals.clear()
    training.train(
        _small_env(), grow, tmp_path / "grow", on_eval=evals.__setitem__, progress_stream=io.StringIO()
    )
    (_, r1), (_, r2) = sorted(_learning_rates(evals).items())
    assert lr0 < r1 < lr0 * 2.25 and r2 == pytest.approx(lr0 * 2.25, rel=1e-6)


def test_training_without_evaluations_trains_the_same_policy(uninterrupted, tmp_path, monkeypatch):
    """ppo.run_evals=false (brax's run_evals): no evaluation episodes and no evaluator built, so
    brax's evaluator, made to fail here, is never constructed. The checkpoints are written at the
    same steps, the records and progress lines carry the training losses, and the policy is the
    one trained with evaluations, bit for bit (on the CPU XLA is deterministic; the evaluations
    draw from their own key), also when the run is stopped after its first epoch and resumed."""
    from brax.training import acting

    def no_evaluator(*args, **kwargs):
        raise AssertionError("brax's evaluator was constructed")

    monkeypatch.setattr(acting.Evaluator, "__init__", no_evaluator)
    ref_evals, ref_params = uninterrupted
    records, out = {}, io.StringIO()

    def stop_after_first(step, record):
        records[step] = record
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        training.train(
            _small_env(),
            apply_overrides(training.ppo_config("test"), [*RUN, "run_evals=false"]),
            tmp_path,
            progress_stream=out,
            on_eval=stop_after_first,
        )
    _, params, metrics = training.train(
        None, None, tmp_path, resume=True, progress_stream=out, on_eval=records.__setitem__
    )
    assert sorted(records) == [128, 256] and sorted(ref_evals) == [0, 128, 256]
    for step, record in records.items():
        assert not any(k.startswith("eval/") for k in record), step
        assert math.isfinite(record["training/total_loss"])
        assert record["training/total_loss"] == ref_evals[step]["training/total_loss"]
    assert re.search(r"256/192 steps .*\| loss [0-9.]+ \|", out.getvalue())
    assert [step for _, step in training.list_checkpoints(tmp_path)] == [0, 128, 256]
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(ref_params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert metrics["training/total_loss"] == records[256]["training/total_loss"]


def test_resume_of_a_finished_run_is_refused(interrupted_then_resumed):
    run_dir, *_ = interrupted_then_resumed
    with pytest.raises(ValueError, match="already trained"):
        training.train(None, None, run_dir, resume=True)
    out = subprocess.run(
        [sys.executable, str(ROOT / "train" / "ppo_mjx.py"), "--resume", str(run_dir)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2 and "already trained" in out.stderr and "Traceback" not in out.stderr


def test_missing_and_corrupt_checkpoints_are_clear_errors(tmp_path, interrupted_then_resumed):
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        training.latest_checkpoint(tmp_path)
    with pytest.raises(FileNotFoundError, match="not a run directory"):
        training.load_run_config(tmp_path)
    run_dir, *_ = interrupted_then_resumed
    path, _ = training.latest_checkpoint(run_dir)
    bad = tmp_path / "bad.msgpack"
    bad.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    with pytest.raises(ValueError, match="corrupt"):
        training.load_checkpoint(bad, 29, 12, training.ppo_config("test"))
    state = training.training_state_path(run_dir, 128)
    (tmp_path / "checkpoints").mkdir()
    bad_state = training.training_state_path(tmp_path, 128)
    bad_state.write_bytes(state.read_bytes()[:100])
    with pytest.raises(ValueError, match=f"{bad_state}.*corrupt.*move it away"):
        training._load_npz(bad_state, 128)
    with pytest.raises(ValueError, match="holds step 128, not 256"):
        training._load_npz(state, 256)


def test_new_run_refuses_a_non_empty_directory(tmp_path):
    (tmp_path / "something").write_text("x")
    with pytest.raises(FileExistsError, match="not empty"):
        training.train(_small_env(), training.ppo_config("test"), tmp_path)


def _script(run_dir, *args) -> list[str]:
    """Command line of the training script with the test preset in run_dir."""
    return [
        sys.executable,
        str(ROOT / "train" / "ppo_mjx.py"),
        "--preset",
        "test",
        "--run-dir",
        str(run_dir),
        *args,
    ]


def test_script_rejects_a_bad_override_key_naming_it(tmp_path):
    out = subprocess.run(
        _script(tmp_path / "r", "--env.reward.forwad_target=0.4"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode != 0
    assert "env.reward.forwad_target" in out.stderr and "reward.forward_target" in out.stderr
    assert not (tmp_path / "r").exists()


def test_unknown_preset_is_an_error():
    with pytest.raises(ValueError, match="unknown ppo preset"):
        training.ppo_config("huge")


def test_gait_normal_policy_starts_as_the_gait():
    # The untrained gait_normal policy's mean action is exactly zero (the gait unchanged) for any
    # observation, and its exploration noise is init_noise_std; brax's tanh_normal is not zero.
    from brax.training.agents.ppo import networks as ppo_networks

    obs = jax.random.normal(jax.random.PRNGKey(1), (16, 29)) * 3.0
    for kind, zero in (("gait_normal", True), ("tanh_normal", False)):
        cfg = apply_overrides(
            training.ppo_config("test"), [f"policy_distribution={kind}", "init_noise_std=0.2"]
        )
        nets = training.make_networks(29, 12, cfg)
        params = training.params_template(29, 12, cfg)
        mean = ppo_networks.make_inference_fn(nets)(params, deterministic=True)(obs, None)[0]
        assert bool(jnp.all(mean == 0.0)) is zero
        if zero:
            loc, scale = nets.policy_network.apply(params[0], params[1], obs)
            np.testing.assert_allclose(np.asarray(scale), 0.2, rtol=1e-6)
            sample = ppo_networks.make_inference_fn(nets)(params, deterministic=False)(
                jnp.zeros((4096, 29)), jax.random.PRNGKey(2)
            )[0]
            assert float(jnp.std(sample)) == pytest.approx(0.2, rel=0.05)  # no tanh squashing


def test_ppo_config_errors_name_the_key():
    base = training.ppo_config("test")
    for override, key in (
        ("policy_distribution=beta", "ppo.policy_distribution"),
        ("multi_device=nccl", "ppo.multi_device"),
        ("num_envs=0", "ppo.num_envs"),
        ("max_devices=-1", "ppo.max_devices"),
        ("batch_size=3", "ppo.batch_size * ppo.num_minibatches"),
        # issue 13, item 4: accepted before, then trained on nonsense or failed deep in XLA
        ("learning_rate=-1", "ppo.learning_rate"),
        ("learning_rate=1e999", "ppo.learning_rate"),
        ("discounting=2", "ppo.discounting"),
        ("gae_lambda=-1", "ppo.gae_lambda"),
        ("max_grad_norm=-1", "ppo.max_grad_norm"),
        ("episode_length=-5", "ppo.episode_length"),
        ("clipping_epsilon=0", "ppo.clipping_epsilon"),
        ("learning_rate_schedule=cosine", "ppo.learning_rate_schedule"),
        ("desired_kl=0", "ppo.desired_kl"),
        ("learning_rate_range=0.01,0.001", "ppo.learning_rate_range"),
    ):
        with pytest.raises(ValueError, match=key.replace("*", r"\*")):
            training.check_ppo_config(apply_overrides(base, [override]))
    adaptive = ["learning_rate_schedule=adaptive_kl", "learning_rate=0.02"]  # above the range's 1e-2
    with pytest.raises(ValueError, match=r"ppo\.learning_rate=0\.02 must lie in ppo\.learning_rate_range"):
        training.check_ppo_config(apply_overrides(base, adaptive))
    training.check_ppo_config(apply_overrides(base, adaptive[1:]))  # a constant rate has no range
    cfg = apply_overrides(base, ["policy_distribution=gait_normal", "init_noise_std=0.0"])
    with pytest.raises(ValueError, match="init_noise_std"):
        training.check_ppo_config(cfg)
    for preset in ("gpu", "cpu", "test"):
        training.check_ppo_config(training.ppo_config(preset))


def test_run_configs_written_before_new_keys_still_load(tmp_path):
    # tests/data/legacy_run/config.json is the config of the policy this project published first
    # (before policy_distribution, the device keys and deterministic_eval existed). It loads with
    # the values that reproduce that run, its networks restore a checkpoint, and it exports.
    legacy = ROOT / "tests" / "data" / "legacy_run" / "config.json"
    data = json.loads(legacy.read_text())
    assert "policy_distribution" not in data["ppo"]
    run = tmp_path / "legacy"
    run.mkdir()
    (run / "config.json").write_text(legacy.read_text())
    _, ppo_cfg = training.load_run_config(run)
    assert ppo_cfg.policy_distribution == "tanh_normal" and ppo_cfg.deterministic_eval is False
    assert json.loads(to_json(ppo_cfg)) == {**training.PPO_KEYS_ADDED, **data["ppo"]}
    training.save_checkpoint(run, 8, training.params_template(29, 12, ppo_cfg))
    policy, *_ = training.load_policy(run)
    assert policy(jnp.zeros(29), None)[0].shape == (12,)
    data["ppo"]["policy_hiden"] = [8]
    (run / "config.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="policy_hiden"):
        training.load_run_config(run)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda text, data: text[: len(text) // 2], "not valid JSON"),
        (lambda text, data: json.dumps({"env": data["env"]}), "lacks its 'env' or 'ppo' section"),
        (
            lambda text, data: json.dumps({**data, "ppo": _without(data["ppo"], "learning_rate")}),
            "ppo.learning_rate' is missing",
        ),
        (lambda text, data: json.dumps({**data, "ppo": {**data["ppo"], "num_envs": "many"}}), "ppo.num_envs"),
        (
            lambda text, data: json.dumps({**data, "ppo": {**data["ppo"], "discounting": 2.0}}),
            "ppo.discounting",
        ),
        (lambda text, data: json.dumps({**data, "env": {**data["env"], "terrain": "moon"}}), "env.terrain"),
        (
            lambda text, data: json.dumps(
                {**data, "env": {**data["env"], "reward": {**data["env"]["reward"], "forward_sigma": 0}}}
            ),
            "env.reward.forward_sigma",
        ),
    ],
)
def test_damaged_run_config_is_an_error_naming_the_file_and_key_regression(tmp_path, damage, message):
    # Regression (issue 13, item 4): a corrupt or incomplete config.json ended in a KeyError or
    # JSONDecodeError traceback that named neither the file nor the key.
    legacy = (ROOT / "tests" / "data" / "legacy_run" / "config.json").read_text()
    (tmp_path / "config.json").write_text(damage(legacy, json.loads(legacy)))
    with pytest.raises(ValueError, match=message) as info:
        training.load_run_config(tmp_path)
    assert str(tmp_path / "config.json") in str(info.value)


def _without(d, key):
    return {k: v for k, v in d.items() if k != key}


@pytest.mark.parametrize(
    "args, key",
    [
        (["--ppo.episode_length=-5"], "ppo.episode_length"),
        (["--env.terrain=moon"], "env.terrain"),
    ],
)
def test_script_bad_values_exit_2_naming_the_key_regression(tmp_path, args, key):
    # Regression (issue 13, item 4): episode_length=-5 failed deep in XLA, terrain=moon in the model
    # builder, both with a traceback. Now: exit 2, one line naming the key, nothing written.
    out = subprocess.run(_script(tmp_path / "r", *args), capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr[-2000:]
    assert key in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "r").exists()


def test_script_resume_of_a_damaged_config_exits_2_naming_the_file_regression(tmp_path):
    run = tmp_path / "r"
    run.mkdir()
    (run / "config.json").write_text('{"env": {"terrain": "fl')
    out = subprocess.run(
        [sys.executable, str(ROOT / "train" / "ppo_mjx.py"), "--resume", str(run)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert str(run / "config.json") in out.stderr and "not valid JSON" in out.stderr


def test_sigterm_ends_the_script_like_ctrl_c(tmp_path):
    # A scheduler's SIGTERM must leave what Ctrl-C leaves: a closed log and a resumable checkpoint.
    # It is sent as GNU timeout sends it, to the process and then to its process group: one request,
    # so the run stops at its next safe point, not at once. (The two often reach the process as one;
    # test_the_same_signal_twice_at_once_is_one_request covers the case where they do not.)
    import os
    import signal
    import time

    run = tmp_path / "r"
    proc = subprocess.Popen(
        _script(run, "--env.episode_length_s=0.2", *[f"--ppo.{o}" for o in RUN]),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_script_env(),
        start_new_session=True,  # its own process group, as under timeout
    )
    deadline = time.monotonic() + 300
    while not (run / "checkpoints" / "latest").exists():
        assert proc.poll() is None and time.monotonic() < deadline, "no checkpoint before exit/timeout"
        time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    os.killpg(proc.pid, signal.SIGTERM)
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 130, out[-2000:]
    assert "--resume" in out
    assert out.count("SIGTERM: stopping at the next safe point") == 1, out[-2000:]
    assert "second SIGTERM" not in out, out[-2000:]
    with open(run / "train.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        events = [json.loads(m.data)["event"] for _, c, m in reader.iter_messages(topics=["/train/log"])]
    assert events == ["start", "interrupted"]
    training.latest_checkpoint(run)  # resumable


def _script_env():
    """Environment of a script subprocess: the test session's persistent compilation cache."""
    import os

    cache = ROOT / ".pytest_cache" / "jax_compilation"
    return {
        **os.environ,
        "JAX_COMPILATION_CACHE_DIR": str(cache),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "1",
    }


def _events(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None  # closed cleanly
        return [json.loads(m.data)["event"] for _, c, m in reader.iter_messages(topics=["/train/log"])]


def test_signal_before_the_first_checkpoint_stops_and_resumes_regression(tmp_path):
    # Regression (issue 13, item 3): Ctrl-C during the first compilation printed "Continue with
    # --resume", but resume failed (no checkpoint) and a rerun refused the directory; a signal
    # during XLA compilation could also be swallowed (the run trained to the end). Now the signal
    # is deferred to the next safe point, the run stops (exit 130) and --resume starts it over.
    import signal
    import time

    run = tmp_path / "r"
    proc = subprocess.Popen(
        _script(run, "--env.episode_length_s=0.2", *[f"--ppo.{o}" for o in RUN]),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_script_env(),
    )
    deadline = time.monotonic() + 300
    while not (run / "train.mcap").exists():  # the run has started: configs written, compiling next
        assert proc.poll() is None and time.monotonic() < deadline, "the run did not start"
        time.sleep(0.2)
    time.sleep(1.0)  # into brax's first compilations
    assert not (run / "checkpoints" / "latest").exists()  # before the first checkpoint
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 130 and "Traceback" not in out, out[-3000:]
    assert f"--resume {run}" in out
    assert _events(run / "train.mcap") == ["start", "interrupted"]
    done = subprocess.run(
        [sys.executable, str(ROOT / "train" / "ppo_mjx.py"), "--resume", str(run)],
        capture_output=True,
        text=True,
        timeout=600,
        env=_script_env(),
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    assert _events(run / "train.mcap") == ["start", "interrupted", "resume", "finished"]
    assert (run / "train.before_resume_1.mcap").exists()
    assert training.latest_checkpoint(run)[1] == 256
    assert "stopping at the next safe point" in out and "from step 0 (no checkpoint yet)" in out
