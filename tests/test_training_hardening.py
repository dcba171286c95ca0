"""Training's answers to bad inputs and faults: every config key has a range (checked in float32),
a diverging run stops before writing a non-finite checkpoint, run directories are locked, every
checkpoint carries a checksum checked on load (resume falls back to the newest intact one), the
second Ctrl-C during compilation exits at once, and the training command answers a bad input with
one line and exit status 2."""

import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from mcap.reader import make_reader

from quadson_mjx import tasks, training
from quadson_mjx.cli import train as cli_train
from quadson_mjx.config import _flat_keys, apply_overrides, rule_for, to_json
from quadson_mjx.env_config import ENV_RULES, check_env_config, env_config
from quadson_mjx.errors import UsageError
from quadson_mjx.training import guards, monitor

ROOT = Path(__file__).resolve().parents[1]
# test preset, 3 epochs of 64 steps: evaluations at steps 0, 64, 128, 192
RUN = ["num_evals=4", "num_timesteps=192"]
OBS, ACT = 29, 12  # Quadson's true_state observation and action sizes


def _small_env():
    return apply_overrides(env_config(), ["episode_length_s=0.2"])


def _ppo(*extra):
    return apply_overrides(training.ppo_config("test"), [*RUN, *extra])


# --- every key has a range --------------------------------------------------------------------


def _env_variants():
    yield env_config()
    yield env_config(command_tracking=True, randomize=True, pushes=True, terrain="rough", joystick=True)
    for name in tasks.task_names():
        yield tasks.make_task_config(name)


def test_every_env_key_has_a_range_and_the_defaults_are_inside():
    # A key added without a rule fails here (and check_env_config refuses a config holding it).
    for cfg in _env_variants():
        for key in _flat_keys(cfg):
            rule = rule_for(ENV_RULES, key)
            assert rule is not None, f"env.{key} has no rule in env_config.ENV_RULES"
            assert rule.lo <= rule.hi, key
            rule.check(f"env.{key}", cfg[key] if "." not in key else _get(cfg, key))
        check_env_config(cfg)


def test_every_ppo_key_has_a_range_and_the_presets_are_inside():
    for preset in training.PRESETS:
        cfg = training.ppo_config(preset)
        for key in cfg:
            assert key in training.PPO_RULES, f"ppo.{key} has no rule in presets.PPO_RULES"
            assert training.PPO_RULES[key].lo <= training.PPO_RULES[key].hi, key
        training.check_ppo_config(cfg)


def test_a_key_without_a_rule_is_refused():
    import ml_collections

    cfg = env_config().to_dict()
    cfg["reward"]["weights"]["new_term"] = -1.0  # a group with a wildcard rule takes new terms
    check_env_config(ml_collections.ConfigDict(cfg))
    cfg["new_knob"] = 1.0
    with pytest.raises(ValueError, match=r"env\.new_knob has no range"):
        check_env_config(ml_collections.ConfigDict(cfg))
    ppo = training.ppo_config("test").to_dict()
    ppo["new_knob"] = 1
    with pytest.raises(ValueError, match=r"ppo\.new_knob has no range"):
        training.check_ppo_config(ml_collections.ConfigDict(ppo))


def _get(cfg, dotted):
    for part in dotted.split("."):
        cfg = cfg[part]
    return cfg


@pytest.mark.parametrize(
    "override, message",
    [
        # the library accepted each of these (issue: "Library config checks accept ...")
        (
            "command_resample_s=(8, 4)",
            r"env\.command_resample_s must be a \(low, high\) range with low <= high",
        ),
        ("command_zero_prob=2", r"env\.command_zero_prob must be a number in \[0, 1\]"),
        ("termination.min_height_m=-5", r"env\.termination\.min_height_m must be a number in \[0, 2\] m"),
        ("action_scale_m=100", r"env\.action_scale_m must be a number in \[0, 0.2\] m"),
        ("episode_length_s=1e12", r"env\.episode_length_s must be a number in \(0, 3600\] s"),
        ("reward.weights.torque_l2=1e300", r"env\.reward\.weights\.torque_l2 must be finite in float32"),
        ("reward.weights.torque_l2=-2e4", r"env\.reward\.weights\.torque_l2 must be a number in \[-10000"),
        (
            "ctrl_dt=0.021",
            r"env\.ctrl_dt must be a whole multiple of the physics timestep 0.004 s \(quadson's model\)",
        ),
        (
            "sim_dt=0.003",
            r"env\.ctrl_dt must be a whole multiple of the physics timestep 0.003 s \(env\.sim_dt\)",
        ),
        ("sim_dt=0.5", r"env\.sim_dt"),
        ("randomization.latency_s=(0.2, 0.1)", r"env\.randomization\.latency_s must be a \(low, high\)"),
        ("sensor.gyro_noise_rps=-1", r"env\.sensor\.gyro_noise_rps"),
        ("obs_history=17", r"env\.obs_history must be an integer in \[1, 16\]"),
    ],
)
def test_regression_env_values_out_of_range_refused(override, message):
    with pytest.raises(ValueError, match=message):
        check_env_config(apply_overrides(env_config(), [override]))


@pytest.mark.parametrize(
    "override, message",
    [
        # 1e300 is finite in float64 (the check passed) and inf in float32 (what trains)
        ("learning_rate=1e300", r"ppo\.learning_rate must be finite in float32.*1e\+300 overflows to inf"),
        ("learning_rate=2.0", r"ppo\.learning_rate must be a number in \(0, 1\]"),
        ("preset=foo", r"ppo\.preset is 'foo'; choose from \['gpu', 'cpu', 'test'\]"),
        ("entropy_cost=1e39", r"ppo\.entropy_cost must be finite in float32"),
        ("num_envs=100000000", r"ppo\.num_envs must be an integer in \[1, 16777216\]"),
        ("seed=-1", r"ppo\.seed must be an integer in \[0, 2147483647\]"),
    ],
)
def test_regression_ppo_values_out_of_range_refused(override, message):
    with pytest.raises(ValueError, match=message):
        training.check_ppo_config(apply_overrides(training.ppo_config("test"), [override]))


# --- the training command: one line, exit status 2 --------------------------------------------


@pytest.fixture
def run_main(monkeypatch, capsys):
    """Calls the training command in this process: -> (exit status, stderr). SIGTERM's handler,
    which main sets, is put back."""
    previous = signal.getsignal(signal.SIGTERM)

    def run(*argv, cache=None):
        status = cli_train.main(
            [*(["--compile-cache", str(cache)] if cache else ["--no-compile-cache"]), *argv]
        )
        return status, capsys.readouterr().err

    yield run
    signal.signal(signal.SIGTERM, previous)


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    "args, words",
    [
        (["--ppo.learning_rate=1e300", "--ppo.num_timesteps=192", "--ppo.num_evals=4"], "ppo.learning_rate"),
        (["--ppo.preset=foo"], "ppo.preset is 'foo'"),
        (["--env.ctrl_dt=0.021"], "env.ctrl_dt must be a whole multiple"),
        (["--env.command_zero_prob=2"], "env.command_zero_prob"),
        (["--env.reward.forwad_target=1"], "unknown config key 'env.reward.forwad_target'"),
        (["--ppo.num_envs=many"], "ppo.num_envs"),
        (["--bogus"], "unrecognised arguments: --bogus"),
        (["--terrain", "moon"], "argument --terrain: invalid choice"),
    ],
)
def test_regression_bad_inputs_give_one_line_and_exit_2_and_no_run_dir(run_main, tmp_path, args, words):
    run = tmp_path / "R"
    status, err = run_main("--preset", "test", "--run-dir", str(run), *args)
    assert status == 2 and words in _one_line(err)
    assert not run.exists()  # refused before the run directory was created


def test_regression_unknown_preset_flag_and_task_conflict_are_one_line(run_main, tmp_path):
    status, err = run_main("--preset", "huge", "--run-dir", str(tmp_path / "R"))
    assert status == 2 and "unknown ppo preset 'huge'" in _one_line(err)
    status, err = run_main("--task", "QuadsonFlat", "--robot", "quadson", "--run-dir", str(tmp_path / "R"))
    assert status == 2 and "--task QuadsonFlat names the robot" in _one_line(err)


def test_regression_warp_batch_larger_than_its_buffers_is_one_line(run_main, tmp_path):
    """Under Warp the contact buffer is sized for env.warp_max_worlds worlds: a run whose batch is
    larger is refused in one line before a run directory is made."""
    status, err = run_main(
        "--preset", "test", "--run-dir", str(tmp_path / "R"), "--env.impl=warp", "--env.warp_max_worlds=1"
    )
    line = _one_line(err)
    assert status == 2 and "env.warp_max_worlds=1 is fewer worlds than" in line
    assert "set --env.warp_max_worlds=" in line
    assert not (tmp_path / "R").exists()


def test_regression_warp_getup_on_the_stones_is_one_line(run_main, tmp_path):
    """The get-up task on a height field under Warp turns worlds non-finite
    (benchmarks/warp_getup_ground.py): refused in one line before a run directory is made."""
    status, err = run_main(
        "--preset", "test", "--run-dir", str(tmp_path / "R"), "--task", "QuadsonGetupRough", "--env.impl=warp"
    )
    line = _one_line(err)
    assert status == 2 and "env.impl=warp cannot run the get-up task on env.terrain=rough" in line
    assert line.endswith("use env.impl=jax") and not (tmp_path / "R").exists()


def test_warp_on_a_rough_walking_task_asks_for_mjx_collider_in_one_line(run_main, tmp_path):
    """The walking tasks on rough ground collide the feet with MJX's JAX implementation's one-contact
    collider (env.hfield_foot_contacts=1), which Warp does not have: refused in one line that says
    what to add, before a run directory is made."""
    status, err = run_main(
        "--preset",
        "test",
        "--run-dir",
        str(tmp_path / "R"),
        "--task",
        "QuadsonJoystickRough",
        "--env.impl=warp",
    )
    line = _one_line(err)
    assert status == 2 and "env.hfield_foot_contacts=1 needs env.impl=jax" in line
    assert line.endswith("add env.hfield_foot_contacts=4") and not (tmp_path / "R").exists()


def test_regression_read_only_run_dir_and_compile_cache_are_one_line(run_main, tmp_path, monkeypatch):
    # As root, chmod does not stop writes: a path below a regular file (ENOTDIR) stands for a
    # place that cannot be written, and os.access answering no for a read-only folder.
    afile = tmp_path / "afile"
    afile.write_text("x")
    status, err = run_main("--preset", "test", "--run-dir", str(afile / "R"))
    assert status == 2 and "is a file, not a folder" in _one_line(err)
    status, err = run_main("--preset", "test", "--run-dir", str(tmp_path / "R"), cache=afile / "cache")
    assert status == 2 and "compile cache" in _one_line(err) and not (tmp_path / "R").exists()
    read_only = tmp_path / "ro"
    read_only.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == read_only else real_access(p, mode))
    status, err = run_main("--preset", "test", "--run-dir", str(read_only / "R"))
    assert status == 2 and f"{read_only} is not writable (read-only?)" in _one_line(err)


def test_regression_unwritable_compile_cache_is_one_line(tmp_path, capsys, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(UsageError, match="compile cache .*cannot create it.*--no-compile-cache"):
        training.enable_compilation_cache(afile / "cache")
    read_only = tmp_path / "ro"
    read_only.mkdir()
    monkeypatch.setattr(os, "access", lambda p, mode: False)
    with pytest.raises(UsageError, match="compile cache .* is not writable"):
        training.enable_compilation_cache(read_only)


# --- memory -----------------------------------------------------------------------------------


def test_regression_too_many_envs_is_one_line_with_a_hint(run_main, tmp_path):
    # 10 million environments: about 29 kB of state each (jax.eval_shape of reset), at least twice:
    # 0.57 TB, more than any machine this runs on; refused before compiling, no run dir left.
    run = tmp_path / "R"
    args = ["--ppo.num_envs=10000000", "--ppo.batch_size=10000000", "--ppo.num_minibatches=1"]
    status, err = run_main("--preset", "test", "--run-dir", str(run), *args)
    line = _one_line(err)
    assert status == 2 and "ppo.num_envs=10,000,000 needs at least" in line and "lower --ppo.num_envs" in line
    assert not run.exists()


def test_xla_resource_exhausted_becomes_one_line(tmp_path, monkeypatch):
    # What XLA raises when an allocation fails while running (after the estimate passed).
    from brax.training.agents.ppo import train as ppo

    def exhausted(**kwargs):
        raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 9.1GiB.")

    monkeypatch.setattr(ppo, "train", exhausted)
    with pytest.raises(guards.OutOfMemory, match=r"out of memory with ppo.num_envs=4.*lower --ppo.num_envs"):
        training.train(_small_env(), _ppo(), tmp_path / "R", progress_stream=io.StringIO())
    assert _events(tmp_path / "R" / "train.mcap")[-1].startswith("failed: RuntimeError: RESOURCE_EXHAUSTED")
    assert training.lock_holder(tmp_path / "R") is None  # released


def test_memory_estimate_refuses_what_does_not_fit(monkeypatch):
    from quadson_mjx.env import LocomotionEnv

    env = LocomotionEnv(_small_env())
    monkeypatch.setattr(guards, "memory_bytes", lambda devices: (10**9, "a 1 GB test device"))
    guards.check_memory(env, 1000, 1)  # ~60 MB
    with pytest.raises(guards.OutOfMemory, match=r"a 1 GB test device has 1.0 GB"):
        guards.check_memory(env, 100_000, 1)


# --- a diverging run ---------------------------------------------------------------------------


def _events(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None  # closed cleanly
        return [json.loads(m.data)["event"] for _, c, m in reader.iter_messages(topics=["/train/log"])]


def test_regression_nan_parameters_stop_training_at_the_first_non_finite_evaluation(tmp_path, monkeypatch):
    # The run (learning rate 1e300: inf in float32, refused by the config check now) trained
    # every epoch to NaN parameters, wrote NaN checkpoints and pointed `latest` at one. Here the
    # first training epoch's parameters are made NaN as an infinite learning rate makes them (fault
    # injected after brax's compiled epoch, so the programs are tests/test_training.py's, from the
    # compilation cache): the evaluation after it stops the run, nothing non-finite is written and
    # `latest` names the step-0 checkpoint.
    from quadson_mjx import compat

    wrap = compat.BraxTrainingState._wrap

    def poisoned_wrap(self, epoch_fn):
        def epoch(training_state, env_state, keys):
            out = epoch_fn(training_state, env_state, keys)
            nan_params = jax.tree.map(lambda x: x * np.float32("nan"), out[0].params)
            return (out[0].replace(params=nan_params), *out[1:])

        return wrap(self, epoch)

    monkeypatch.setattr(compat.BraxTrainingState, "_wrap", poisoned_wrap)
    run = tmp_path / "R"
    ppo_cfg = apply_overrides(training.ppo_config("test"), ["num_evals=3", "num_timesteps=192"])
    with pytest.raises(training.TrainingDiverged) as info:
        training.train(_small_env(), ppo_cfg, run, progress_stream=io.StringIO())
    message = str(info.value)
    assert "training diverged at evaluation 1 of 2 (after training epoch 1, step 128)" in message
    assert "non-finite training state .params" in message and "the last finite one: step 0" in message
    assert len(message.splitlines()) == 1
    path, step = training.latest_checkpoint(run)
    assert step == 0 and training.verify_checkpoint(path)
    written = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert written == ["latest", "step_000000000000.msgpack", "step_000000000000.msgpack.sha256"]
    params = training.load_checkpoint(path, OBS, ACT, ppo_cfg)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(params))
    events = _events(run / "train.mcap")
    assert events[0] == "start" and events[-1].startswith("failed: TrainingDiverged")
    assert training.lock_holder(run) is None


def test_non_finite_losses_and_reward_are_found():
    metrics = {"training/total_loss": 1.0, "training/v_loss": np.inf, "training/sps": 5.0}
    assert guards.non_finite_metrics(metrics) == ["training/v_loss"]
    assert guards.non_finite_metrics({"eval/episode_reward": np.float32("nan")}) == ["eval/episode_reward"]
    assert guards.non_finite({"a": np.ones(2), "b": np.array([1.0, np.nan]), "n": np.arange(3)}) == ["['b']"]


def test_save_checkpoint_refuses_non_finite_parameters(tmp_path):
    params = training.params_template(OBS, ACT, _ppo())
    bad = jax.tree.map(lambda x: x * np.nan, params)
    with pytest.raises(ValueError, match="refusing to write a checkpoint at step 64: non-finite"):
        training.save_checkpoint(tmp_path, 64, bad)
    assert not (tmp_path / "checkpoints").exists() or not any((tmp_path / "checkpoints").iterdir())


# --- checksums, fallback, damaged files ---------------------------------------------------------


def _fake_run(run: Path, steps=(0, 64, 128)) -> Path:
    """A run directory as train writes it (config.json, checkpoints at `steps`), without training."""
    run.mkdir(parents=True, exist_ok=True)
    data = {"env": json.loads(to_json(_small_env())), "ppo": json.loads(to_json(_ppo())), "versions": {}}
    (run / "config.json").write_text(json.dumps(data))
    params = training.params_template(OBS, ACT, _ppo())
    for step in steps:
        training.save_checkpoint(run, step, jax.tree.map(lambda x, s=step: x + s, params))
    return run


def _flip(path: Path, at: float = 0.5, n: int = 4) -> None:
    data = bytearray(path.read_bytes())
    i = int(len(data) * at)
    for k in range(n):
        data[i + k] ^= 0xFF
    path.write_bytes(bytes(data))


def test_checksum_file_is_sha256sum_format(tmp_path):
    run = _fake_run(tmp_path / "R", steps=(64,))
    path = run / "checkpoints" / "step_000000000064.msgpack"
    digest, name = training.checksum_path(path).read_text().split()
    assert digest == hashlib.sha256(path.read_bytes()).hexdigest() and name == path.name
    assert training.verify_checkpoint(path) is True


def test_regression_flipped_bytes_in_a_checkpoint_are_named_on_load(tmp_path):
    # Four flipped bytes exported silently with a changed weight. load_checkpoint (what resume,
    # export and rollout call) now refuses the file, naming it.
    run = _fake_run(tmp_path / "R")
    path, _ = training.latest_checkpoint(run)
    _flip(path)
    with pytest.raises(training.CheckpointDamaged, match=f"{path} is damaged: its SHA-256 is"):
        training.load_checkpoint(path, OBS, ACT, _ppo())
    with pytest.raises(training.CheckpointDamaged, match="is damaged"):
        training.load_policy(run)


def test_regression_resume_without_latest_uses_the_newest_checkpoint(tmp_path):
    # Deleting checkpoints/latest made resume start over from step 0 and rewrite the checkpoints.
    run = _fake_run(tmp_path / "R")
    (run / "checkpoints" / "latest").unlink()
    notes = []
    start, ckpt = training.resume_point(run, _ppo(), notes)
    assert start == 128 and ckpt.name == "step_000000000128.msgpack"
    assert "has no checkpoints/latest" in notes[0]
    assert training.latest_checkpoint(run)[1] == 128


def test_regression_damaged_newest_checkpoint_resumes_from_the_previous_good_one(tmp_path):
    run = _fake_run(tmp_path / "R")
    _flip(run / "checkpoints" / "step_000000000128.msgpack")
    notes = []
    start, ckpt = training.resume_point(run, _ppo(), notes)
    assert start == 64 and ckpt.name == "step_000000000064.msgpack"
    assert "step_000000000128.msgpack is damaged" in notes[0]
    _flip(run / "checkpoints" / "step_000000000064.msgpack")
    start, ckpt = training.resume_point(run, _ppo(), notes)
    assert (start, ckpt) == (0, None)  # only step 0 left: a fresh start reproduces it


def test_regression_old_checkpoints_without_a_checksum_load_with_a_notice(tmp_path, capsys, monkeypatch):
    run = _fake_run(tmp_path / "R", steps=(64,))
    path = run / "checkpoints" / "step_000000000064.msgpack"
    training.checksum_path(path).unlink()
    monkeypatch.setattr("quadson_mjx.training.checkpoints._unverified_notice_given", False)
    for _ in range(2):
        assert training.verify_checkpoint(path) is False
        training.load_checkpoint(path, OBS, ACT, _ppo())
    err = capsys.readouterr().err
    assert err.count("has no checksum file") == 1  # once per process
    assert "has no checksum file step_000000000064.msgpack.sha256 " in err  # names the file it looked for


def test_committed_runs_still_load():
    # The run directories under results/ were written before checksums: they load unverified.
    runs = sorted(p.parent for p in (ROOT / "results").rglob("config.json"))
    assert runs
    for run in runs:
        env_cfg, ppo_cfg = training.load_run_config(run)
        path, step = training.latest_checkpoint(run)
        assert step > 0 and training.verify_checkpoint(path) in (True, False)


def test_regression_truncated_state_files_are_one_line_with_the_right_advice(tmp_path):
    run = tmp_path / "R"
    (run / "checkpoints").mkdir(parents=True)
    leaves = [np.ones(3, np.float32)]
    for kind, path in (
        ("training", training.training_state_path(run, 64)),
        ("env", training.env_state_path(run, 64)),
    ):
        from quadson_mjx.training.checkpoints import _save_npz

        _save_npz(path, leaves, 64)
        np.testing.assert_array_equal(training._load_npz(path, 64, kind)[0], leaves[0])
        path.write_bytes(path.read_bytes()[:100])
        with pytest.raises(ValueError) as info:
            training._load_npz(path, 64, kind)
        message = str(info.value)
        assert len(message.splitlines()) == 1 and str(path) in message and "is damaged" in message
        if kind == "env":  # not the optimiser-state advice
            assert "optimiser" not in message and "environments restarting" in message
        else:
            assert "optimiser's moments restart" in message


def test_regression_truncated_state_files_on_resume_are_one_line(run_main, tmp_path):
    from quadson_mjx.training.checkpoints import _save_npz

    run = _fake_run(tmp_path / "R")
    config = (run / "config.json").read_bytes()
    for path, words in (
        (training.training_state_path(run, 128), "optimiser's moments restart"),
        (training.env_state_path(run, 128), "environments restarting from the run's initial states"),
    ):
        _save_npz(path, [np.ones(3, np.float32)], 128)
        path.write_bytes(path.read_bytes()[:100])
        status, err = run_main("--resume", str(run))
        line = _one_line(err)
        assert status == 2 and str(path) in line and words in line
        path.unlink()
        training.checksum_path(path).unlink()
        if "env_state" not in path.name:  # the env state is read only beside a training state
            _save_npz(path, [np.ones(3, np.float32)], 128)
    assert (run / "config.json").read_bytes() == config  # refused before anything was rewritten
    assert training.lock_holder(run) is None


@pytest.mark.parametrize(
    "edit",
    [
        lambda text: text[: len(text) // 3],
        lambda text: json.dumps({**json.loads(text), "env": 5}),
        lambda text: json.dumps({**json.loads(text), "ppo": {**json.loads(text)["ppo"], "preset": ["x"]}}),
        lambda text: text.replace('"reward": {', '"reward": 3, "reward_": {'),
        lambda text: json.dumps(
            {**json.loads(text), "ppo": {**json.loads(text)["ppo"], "learning_rate": 1e300}}
        ),
    ],
)
def test_regression_hand_edited_config_is_one_line(run_main, tmp_path, edit):
    run = _fake_run(tmp_path / "R")
    config = run / "config.json"
    config.write_text(edit(config.read_text()))
    with pytest.raises(ValueError, match=str(config)):
        training.load_run_config(run)
    status, err = run_main("--resume", str(run))
    assert status == 2 and str(config) in _one_line(err)


# --- the run directory's lock ------------------------------------------------------------------


def test_regression_second_trainer_refused_naming_the_holder_without_touching_config(run_main, tmp_path):
    run = _fake_run(tmp_path / "R")
    before = (run / "config.json").read_bytes()
    with training.run_dir_lock(run):
        assert training.lock_holder(run) == os.getpid()
        status, err = run_main("--preset", "test", "--run-dir", str(run), "--ppo.policy_hidden=16")
        assert status == 2 and f"is in use by process {os.getpid()}" in _one_line(err)
        status, err = run_main("--resume", str(run))
        assert status == 2 and f"in use by process {os.getpid()}" in _one_line(err)
        with pytest.raises(training.RunDirInUse, match=f"in use by process {os.getpid()}"):
            training.train(None, None, run, resume=True, progress_stream=io.StringIO())
        with pytest.raises(training.RunDirInUse):
            training.train(_small_env(), _ppo(), run, progress_stream=io.StringIO())
    assert (run / "config.json").read_bytes() == before
    assert training.lock_holder(run) is None
    training.check_new_run_dir(tmp_path / "empty")  # a lock file alone does not make a dir taken
    (tmp_path / "empty").mkdir()
    with training.run_dir_lock(tmp_path / "empty"):
        pass
    training.check_new_run_dir(tmp_path / "empty")


def test_lock_is_released_when_its_process_dies(tmp_path):
    code = (
        "import sys, time\nfrom quadson_mjx.training.runs import run_dir_lock\n"
        "with run_dir_lock(sys.argv[1]):\n    print('locked', flush=True)\n    time.sleep(120)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        assert training.lock_holder(tmp_path) == proc.pid
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert training.lock_holder(tmp_path) is None
    with training.run_dir_lock(tmp_path):
        assert training.lock_holder(tmp_path) == os.getpid()


# --- signals -----------------------------------------------------------------------------------


def test_second_signal_calls_the_emergency_exit_at_once(monkeypatch):
    # The watcher thread reads the signals from the wakeup fd, so it acts even while the main
    # thread is busy in C (an XLA compilation); here the main thread only waits.
    exits, closed = [], []
    done = threading.Event()

    def fake_exit(status):
        exits.append(status)
        done.set()

    monkeypatch.setattr(os, "_exit", fake_exit)
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the suite runs in the background
    stop = monitor.SignalStop(emergency=closed.append)
    with stop.installed():
        os.kill(os.getpid(), signal.SIGINT)
        deadline = time.monotonic() + 10
        while stop.signum is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert stop.signum == signal.SIGINT and not exits
        with pytest.raises(training.StopRequested):
            stop.check()
        os.kill(os.getpid(), signal.SIGTERM)
        assert done.wait(10)
    assert exits == [130] and closed == ["second SIGTERM"]
    assert signal.getsignal(signal.SIGINT) is before


def test_the_same_signal_twice_at_once_is_one_request(monkeypatch):
    # GNU timeout sends its signal to the command and then to the command's process group: the
    # trainer got SIGTERM twice, microseconds apart, and stopped at once instead of at the safe
    # point. A repeat of the same signal within same_request_s counts once; a repeat after it, or
    # another signal, is a second request (hand-stepped clock, no real signals).
    exits, closed = [], []
    monkeypatch.setattr(os, "_exit", exits.append)
    now = [100.0]
    stop = monitor.SignalStop(emergency=closed.append, clock=lambda: now[0])
    stop._on_signal(signal.SIGTERM)
    now[0] += 1e-5  # the process group's copy
    stop._on_signal(signal.SIGTERM)
    assert stop.signum == signal.SIGTERM and stop.signals == 1 and not exits
    now[0] += stop.same_request_s  # a person's second kill
    stop._on_signal(signal.SIGTERM)
    assert exits == [130] and closed == ["second SIGTERM"]

    exits.clear(), closed.clear()
    other = monitor.SignalStop(emergency=closed.append, clock=lambda: now[0])
    other._on_signal(signal.SIGTERM)
    other._on_signal(signal.SIGINT)  # another signal at the same instant: a second request
    assert exits == [130] and closed == ["second SIGINT"]


def _script(*args):
    return [
        sys.executable,
        str(ROOT / "train" / "ppo_mjx.py"),
        "--preset",
        "test",
        "--no-compile-cache",
        *args,
    ]


@pytest.fixture(scope="module")
def contested_run(tmp_path_factory):
    """The issue's two reproductions on one trainer (one compilation, no cache): a second trainer
    started on its directory while it compiles, with another network size; then two SIGINTs 0.5 s
    apart, still during the first compilations."""
    run = tmp_path_factory.mktemp("contested") / "D"
    first = subprocess.Popen(
        _script("--run-dir", str(run), "--env.episode_length_s=0.2", *[f"--ppo.{o}" for o in RUN]),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    result = {"run": run, "pid": first.pid}
    try:
        deadline = time.monotonic() + 120
        while not (run / "train.mcap").exists():  # configs written, compiling next
            assert first.poll() is None and time.monotonic() < deadline, "the first run did not start"
            time.sleep(0.1)
        result["config"] = (run / "config.json").read_bytes()
        result["second"] = subprocess.run(
            _script("--run-dir", str(run), "--ppo.policy_hidden=16"),
            capture_output=True,
            text=True,
            timeout=120,
        )
        result["config_after"] = (run / "config.json").read_bytes()
        result["latest_before_signals"] = (run / "checkpoints" / "latest").exists()
    finally:
        first.send_signal(signal.SIGINT)
        time.sleep(0.5)
        t0 = time.monotonic()
        first.send_signal(signal.SIGINT)
        result["out"], _ = first.communicate(timeout=60)
        result["exit_s"] = time.monotonic() - t0
    result["returncode"] = first.returncode
    return result


# A process that has stopped its run and now exits through a slow clean-up, as jax's at exit: the
# signal arrives while that clean-up runs. "guard" installs the script's handler, "none" does not.
_SLOW_EXIT = """
import atexit, signal, sys, time
from quadson_mjx.cli.train import exit_at_once_on_another_signal
def slow_clean_up():
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20.0:
        sum(range(1000))
atexit.register(slow_clean_up)
if sys.argv[1] == "guard":
    exit_at_once_on_another_signal()
else:  # Python's own Ctrl-C handler, as in a terminal: a suite started in the background (`&`)
    signal.signal(signal.SIGINT, signal.default_int_handler)  # passes SIGINT on ignored
print("exiting", flush=True)
sys.exit(130)
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_regression_a_signal_during_the_exit_after_a_stop_ends_it_at_once(signum):
    # The two-Ctrl-C test once failed on a fast machine: the first signal stopped the run at its
    # safe point, the second came during the interpreter's exit (jax's clean-up, about 2 s) and was
    # printed as a KeyboardInterrupt traceback. Now the script exits at once with one line.
    def run(mode):
        p = subprocess.Popen(
            [sys.executable, "-c", _SLOW_EXIT, mode],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        assert p.stdout.readline().strip() == "exiting"
        time.sleep(0.5)  # inside the clean-up
        t0 = time.monotonic()
        p.send_signal(signum)
        out, err = p.communicate(timeout=60)
        return p.returncode, err, time.monotonic() - t0

    code, err, seconds = run("guard")
    assert code == 130 and seconds < 5, (code, seconds, err)
    assert "Traceback" not in err
    assert err.strip().splitlines() == [f"second {signum.name}: stopped at once"]
    if signum == signal.SIGINT:  # without the handler: the traceback this test is about
        _, err, _ = run("none")
        assert "Traceback" in err and "KeyboardInterrupt" in err


def test_regression_two_trainers_on_one_directory(contested_run):
    # The second trainer overwrote config.json (its config said [16], its checkpoints [8]) and died
    # with a FileExistsError. Now it refuses with one line naming the first one's pid.
    second = contested_run["second"]
    assert second.returncode == 2, second.stderr[-2000:]
    assert f"in use by process {contested_run['pid']}" in _one_line(second.stderr)
    assert contested_run["config_after"] == contested_run["config"]


def test_regression_second_sigint_during_compilation_exits_130_and_stays_resumable(contested_run):
    # Two Ctrl-C during the first compilation ended in a segfault (exit 139, two of two tries).
    run, out = contested_run["run"], contested_run["out"]
    assert not contested_run["latest_before_signals"]  # still before the first checkpoint
    code = contested_run["returncode"]
    assert contested_run["exit_s"] < 10  # at once, not after the compilation
    assert "Traceback" not in out
    if code == -signal.SIGINT:
        # The first signal's stop completed within the 0.5 s between the signals (its last line
        # printed), and the second came in the interpreter's last moments, after Python had reset
        # SIGINT to the system's default (seen once in CI); a shell shows 130 for this death too.
        assert "Continue from step 0 (no checkpoint yet)" in out, out[-3000:]
    else:
        assert code == 130 and "second SIGINT: stopped at once" in out, out[-3000:]
    assert _events(run / "train.mcap") == ["start", "interrupted"]
    assert training.lock_holder(run) is None
    _, ppo_cfg = training.load_run_config(run)
    assert training.resume_point(run, ppo_cfg) == (0, None)  # resumable: it starts over from step 0
