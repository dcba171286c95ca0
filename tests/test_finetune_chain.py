"""A run and its fine-tune in one command (`--finetune.env.KEY=V`, cli/finetune.py), the fine-tune's
programs compiled ahead by a second process (training/precompile.py), and the command's refusals.

The chain runs as a user runs it: `python -m quadson_mjx.cli.train` in a process of its own (the
persistent compilation cache and the signal handlers are process-wide), on the CPU.
"""

import json
import os
import shutil
import subprocess
import sys

import jax
import numpy as np
import pytest
from flax.serialization import msgpack_restore
from mcap.reader import make_reader

from quadson_mjx import training
from quadson_mjx.cli import train as train_cli

# two training epochs of one training step each, evaluations at 0, 64 and 128 steps
RUN = ["--preset", "test", "--env.episode_length_s=0.2", "--ppo.num_timesteps=128", "--ppo.num_evals=3"]
TUNE = ["--finetune.env.sim_dt=0.0025", "--finetune.ppo.learning_rate=0.0003"]


def _train(args, cwd):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "quadson_mjx.cli.train", *args]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def _last_metrics(run_dir):
    with open(run_dir / "train.mcap", "rb") as f:
        records = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/train/metrics"])]
    return records[-1]["progress"]


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """The run and its fine-tune, trained by one command with a fresh compilation cache."""
    root = tmp_path_factory.mktemp("chain")
    done = _train([*RUN, "--run-dir", "run", "--compile-cache", "xla", *TUNE], root)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return root, done.stdout


@pytest.mark.slow  # about 100 s on 2 cores: the run, the compiling process beside it, the fine-tune
def test_the_finetune_starts_from_the_runs_end_with_its_configs_changed_as_asked(chain):
    root, _ = chain
    run, tune = root / "run", root / "run_finetune"
    saved = json.loads((run / "config.json").read_text())
    assert saved["finetune"] == {
        "overrides": ["--env.sim_dt=0.0025", "--ppo.learning_rate=0.0003"],
        "run_dir": "run_finetune",
    }
    tuned = json.loads((tune / "config.json").read_text())
    final, final_step = training.latest_checkpoint(run)
    assert final_step == 128
    assert tuned["init_from"]["run"] == "run" and tuned["init_from"]["checkpoint"] == final.name
    # the run's configs but for the two keys asked for (the same overrides through --init-from)
    expected_env = {**saved["env"], "sim_dt": 0.0025}
    expected_ppo = {**saved["ppo"], "learning_rate": 0.0003}
    assert tuned["env"] == expected_env and tuned["ppo"] == expected_ppo
    # its step-0 checkpoint holds the run's final parameters
    start = msgpack_restore((tune / "checkpoints" / "step_000000000000.msgpack").read_bytes())
    end = msgpack_restore(final.read_bytes())
    assert jax.tree.structure(start) == jax.tree.structure(end)
    for a, b in zip(jax.tree.leaves(start), jax.tree.leaves(end), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_the_finetune_loads_every_program_from_the_cache_the_second_process_filled(chain):
    root, stdout = chain
    log = (root / "run" / "finetune_compile.log").read_text()
    assert "compiled in" in log.splitlines()[-1], log[-2000:]
    assert "compiling ahead: compiled in" in stdout
    progress = _last_metrics(root / "run_finetune")
    assert progress["xla_compiles"] > 0
    assert progress["xla_cache_hits"] == progress["xla_compiles"], progress  # the training epoch too
    # the run itself compiled its own programs afresh (the cache was empty)
    assert _last_metrics(root / "run")["xla_cache_hits"] < _last_metrics(root / "run")["xla_compiles"]


@pytest.mark.slow
def test_resume_of_a_run_stopped_before_its_finetune_trains_the_finetune(chain, tmp_path):
    root, _ = chain
    shutil.copytree(root / "run", tmp_path / "run")
    shutil.copytree(root / "xla", tmp_path / "xla")
    done = _train(["--resume", "run", "--compile-cache", "xla"], tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "run has trained all its steps: on to its fine-tune" in done.stdout
    tuned = json.loads((tmp_path / "run_finetune" / "config.json").read_text())
    assert tuned["env"]["sim_dt"] == 0.0025 and tuned["init_from"]["step"] == 128
    assert training.latest_checkpoint(tmp_path / "run_finetune")[1] == 128
    # everything done: a further resume has nothing left and says so
    again = _train(["--resume", "run", "--compile-cache", "xla"], tmp_path)
    assert again.returncode == 2 and "already trained 128 of 128 steps" in again.stderr


@pytest.mark.parametrize(
    "argv, says",
    [
        ([*RUN, "--finetune.env.no_such_key=1"], "no_such_key"),
        ([*RUN, "--finetune.env.sim_dt=0.003"], "sim_dt"),  # 20 ms is not a whole number of 3 ms steps
        ([*RUN, "--finetune.seed=1"], "--finetune.KEY=V takes env. and ppo. keys: --finetune.seed=1"),
        ([*RUN, "--finetune-run-dir", "x"], "--finetune-run-dir is the run directory of a fine-tune"),
        ([*RUN, "--run-dir", "a", "--finetune-run-dir", "a", *TUNE], "a run directory of its own"),
        ([*RUN, "--compile-only", "--run-dir", "x"], "--compile-only builds a new run's programs"),
        ([*RUN, "--compile-only", *TUNE], "remove --finetune.env.sim_dt=0.0025"),
        ([*RUN, "--compile-only", "--no-compile-cache"], "--compile-only: no compilation cache"),
    ],
)
def test_a_bad_finetune_or_compile_only_request_is_one_line_before_anything_trains(
    argv, says, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    assert train_cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err, err
    assert not any(tmp_path.iterdir())  # no run directory was made


def test_resume_refuses_finetune_overrides(tmp_path, capsys):
    (tmp_path / "config.json").write_text("{}")
    assert train_cli.main(["--resume", str(tmp_path), "--finetune.ppo.learning_rate=0.001"]) == 2
    assert "remove --finetune.ppo.learning_rate=0.001" in capsys.readouterr().err


def test_compile_only_compiles_the_training_epoch_and_stops_before_running_it():
    calls = []

    def training_epoch(x):  # the name brax PPO's epoch has
        calls.append("traced")
        return x * 2.0

    def other(x):
        return x + 1.0

    original = jax.pmap
    with training.compile_only():
        epoch = jax.pmap(training_epoch)
        with pytest.raises(training.Compiled) as done:
            epoch(np.ones((1, 3), np.float32))
        np.testing.assert_array_equal(jax.pmap(other)(np.ones((1, 3), np.float32)), 2.0)
    assert jax.pmap is original
    assert calls == ["traced"] and done.value.seconds >= 0.0
    np.testing.assert_array_equal(jax.pmap(training_epoch)(np.ones((1, 3), np.float32)), 2.0)


def test_a_failed_or_slow_compiling_process_is_one_line_and_the_chain_goes_on(tmp_path):
    """The compiling process's failure or a wait past its limit is reported, never raised: the
    fine-tune then compiles its programs itself."""
    missing = tmp_path / "no_run"
    failed = training.Precompile(missing, [], str(tmp_path / "xla"), tmp_path / "failed.log")
    line = failed.finish(timeout_s=300)
    assert line.startswith("compiling ahead failed (exit 2): ") and str(missing) in line, line
    assert "\n" not in line
    slow = training.Precompile(missing, [], str(tmp_path / "xla"), tmp_path / "slow.log")
    line = slow.finish(timeout_s=0.01)  # python's start alone takes longer
    assert line.startswith("compiling ahead: still running after 0 s, stopped"), line
    assert slow.process.poll() is not None  # stopped, not left behind
