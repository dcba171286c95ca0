"""PPO training end to end on CPU with the 'test' preset: finite metrics, the MCAP log, checkpoints,
Ctrl-C, resume, inference from a checkpoint, and config errors."""

import json
import math
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mcap.reader import make_reader

from quadson_mjx import training
from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import env_config

ROOT = Path(__file__).resolve().parents[1]


def _small_env():
    return apply_overrides(env_config(), ["episode_length_s=0.2"])


@pytest.fixture(scope="module")
def interrupted_then_resumed(tmp_path_factory):
    """A run stopped by Ctrl-C after its first evaluation, then resumed to the end."""
    run_dir = tmp_path_factory.mktemp("run")
    ppo_cfg = apply_overrides(training.ppo_config("test"), ["num_evals=3", "num_timesteps=192"])
    evals = []

    def stop_after_first(step, record):
        evals.append((step, record))
        if step > 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        training.train(_small_env(), ppo_cfg, run_dir, on_eval=stop_after_first)
    interrupted = {
        "evals": list(evals),
        "checkpoint": training.latest_checkpoint(run_dir),
        "log": (run_dir / "train.mcap").read_bytes(),
    }
    _, params, metrics = training.train(None, None, run_dir, resume=True)
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
    assert steps == sorted(steps) and steps[-1] >= 192
    n_before = len(interrupted["evals"])
    assert len(steps) >= n_before + 1
    assert {"env_config", "ppo_config", "versions"} <= meta and "quadson.xml" in attachments
    _, last = [(t, m) for t, m in msgs if t == "/train/metrics"][-1]
    assert "episode_reward" in last["eval"] and "env_steps_per_s" in last["progress"]


def test_checkpoint_loads_for_inference(interrupted_then_resumed):
    run_dir, _, _, params = interrupted_then_resumed
    policy, env_cfg, ppo_cfg, loaded = training.load_policy(run_dir)
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(loaded), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    obs = jnp.zeros(29)
    action, _ = policy(obs, jax.random.PRNGKey(0))
    assert action.shape == (12,) and bool(jnp.all(jnp.abs(action) <= 1.0))
    assert env_cfg.episode_length_s == pytest.approx(0.2) and ppo_cfg.preset == "test"


def test_resume_of_a_finished_run_is_refused(interrupted_then_resumed):
    run_dir, *_ = interrupted_then_resumed
    with pytest.raises(ValueError, match="already trained"):
        training.train(None, None, run_dir, resume=True)


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


def test_new_run_refuses_a_non_empty_directory(tmp_path):
    (tmp_path / "something").write_text("x")
    with pytest.raises(FileExistsError, match="not empty"):
        training.train(_small_env(), training.ppo_config("test"), tmp_path)


def test_script_rejects_a_bad_override_key_naming_it(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            str(ROOT / "train" / "ppo_mjx.py"),
            "--preset",
            "test",
            "--run-dir",
            str(tmp_path / "r"),
            "--env.reward.forwad_target=0.4",
        ],
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
