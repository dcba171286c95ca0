"""eval/rollout.py's command line: usage errors exit 2 with one line naming the argument and the fix,
before anything is simulated or written (issue 13: --envs 0 raised IndexError and left an MCAP that
checked complete, --seconds -1 ran one step, an existing output said only "File exists (os error 17)").
"""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "eval" / "rollout.py"


@pytest.fixture(scope="module")
def cli():
    from quadson_mjx.cli import rollout

    return rollout


def _usage_error(cli, capsys, argv) -> str:
    rc = cli.main(argv)
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("error: "), err
    return err


@pytest.mark.parametrize(
    "args, words",
    [
        (["--envs", "0"], ["--envs 0", "at least 1"]),
        (["--envs", "-3"], ["--envs -3", "at least 1"]),
        (["--seconds", "-1"], ["--seconds -1.0", "positive"]),
        (["--seconds", "0"], ["--seconds 0.0", "positive"]),
        (["--seconds", "nan"], ["--seconds nan", "positive"]),
        (["--viz-envs", "-1"], ["--viz-envs -1", ">= 0"]),
        (["--segment-steps", "0"], ["--segment-steps 0", ">= 1"]),
        (["--run", "no/such/run"], ["--run no/such/run", "config.json"]),
        (["--video", "clip.avi"], ["--video clip.avi", ".mp4 or .gif"]),
    ],
)
def test_impossible_arguments_are_usage_errors(cli, capsys, tmp_path, args, words):
    out = tmp_path / "out.mcap"
    err = _usage_error(cli, capsys, [*args, "--out", str(out)])
    assert all(w in err for w in words), err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_existing_output_is_named_with_the_overwrite_flag(cli, capsys, tmp_path):
    out = tmp_path / "old.mcap"
    out.write_bytes(b"keep me")
    err = _usage_error(cli, capsys, ["--out", str(out)])
    assert str(out) in err and "--overwrite" in err
    assert out.read_bytes() == b"keep me"
    video = tmp_path / "old.mp4"
    video.write_bytes(b"keep me too")
    err = _usage_error(cli, capsys, ["--out", str(tmp_path / "new.mcap"), "--video", str(video)])
    assert str(video) in err and "--overwrite" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.mcap", "old.mp4"]


def test_suite_checks_every_output_before_running_any(cli, capsys, tmp_path):
    (tmp_path / "pid_rough_turn.mcap").write_bytes(b"")  # the suite's last file
    err = _usage_error(cli, capsys, ["--suite", "--out-dir", str(tmp_path)])
    assert "pid_rough_turn.mcap exists" in err
    assert [p.name for p in tmp_path.iterdir()] == ["pid_rough_turn.mcap"]


def test_usage_error_from_the_shell_has_no_traceback(tmp_path):
    out = tmp_path / "x.mcap"
    res = subprocess.run(
        [sys.executable, str(SCRIPT), "--envs", "0", "--out", str(out)], capture_output=True, text=True
    )
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [res.stderr.strip()]
    assert res.stderr.startswith("error: --envs 0")
    assert "Traceback" not in res.stderr and not out.exists()


# --- hardening: every bad input is one line, exit status 2, before anything is built or written ------


@pytest.fixture
def nothing_runs(cli, monkeypatch):
    """Fails the test if an environment is built or a rollout recorded: validation must come first
    (and no JAX function is compiled)."""

    def refuse(*a, **k):
        raise AssertionError("the rollout started although the input was bad")

    monkeypatch.setattr(cli, "LocomotionEnv", refuse)
    monkeypatch.setattr(cli.recording, "record", refuse)


@pytest.mark.parametrize(
    "args, words",
    [
        (["--env.no_such_key=1"], ["unknown config key 'env.no_such_key'"]),
        (["--env.ctrl_dt=abc"], ["env.ctrl_dt", "abc"]),
        (["--env.ctrl_dt=0.021"], ["env.ctrl_dt", "multiple"]),
        (["--env.terrain=moon"], ["env.terrain", "moon"]),
        (["--env.command_zero_prob=nan"], ["env.command_zero_prob", "finite"]),
        (["--env.randomize"], ["randomize", "key.sub=value"]),
        (["--gait", "foo"], ["--gait foo", "unknown gait 'foo'"]),
        (["--robot", "caramel", "--gait", "walk"], ["--gait walk", "caramel"]),
        (["--suite", "--env.no_such_key=1"], ["env.no_such_key"]),
    ],
)
def test_regression_bad_env_override_or_gait_is_one_line(cli, capsys, tmp_path, nothing_runs, args, words):
    # Regression: any bad --env.* override and --gait foo gave tracebacks (after building the env).
    argv = [
        *args,
        "--out-dir" if "--suite" in args else "--out",
        str(tmp_path / ("s" if "--suite" in args else "o.mcap")),
    ]
    err = _usage_error(cli, capsys, argv)
    assert all(w in err for w in words), err
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


@pytest.mark.parametrize(
    "args",
    [
        ["--vx", "nan"],
        ["--vx", "inf"],
        ["--vy", "nan"],
        ["--yaw-rate=-inf"],
        ["--vx", "0.2", "--yaw-rate", "nan"],
    ],
)
def test_regression_non_finite_command_is_refused(cli, capsys, tmp_path, nothing_runs, args):
    # Regression: --vx nan was accepted (a rollout of NaN commands).
    err = _usage_error(cli, capsys, [*args, "--out", str(tmp_path / "o.mcap")])
    flag = [a.split("=")[0] for a in args if a.startswith("--")][-1]
    assert "must be a finite number" in err and flag in err, err


def test_regression_trial_length_is_bounded(cli, capsys, tmp_path, nothing_runs):
    # Regression: --seconds 1e12 ran (about 77 MB of MCAP a minute, for ever) with no progress shown.
    # The bound: MAX_SECONDS, an hour.
    assert cli.MAX_SECONDS == 3600.0
    for seconds in ("1e12", "3600.5", "inf"):
        err = _usage_error(cli, capsys, ["--seconds", seconds, "--out", str(tmp_path / "o.mcap")])
        assert "--seconds" in err and "<= 3600" in err, err


def test_regression_unwritable_outputs_refused_before_the_rollout(
    cli, capsys, tmp_path, nothing_runs, monkeypatch
):
    # Regression: a read-only --video path failed only after the whole rollout had run. Each output
    # is checked first: a missing folder, a folder as the file, a path below a regular file, and a
    # read-only folder (as root every folder is writable, so os.access is monkeypatched to answer as
    # for a read-only one: what errors.check_writable asks).
    import os

    a_file = tmp_path / "file"
    a_file.write_text("x")
    ok = str(tmp_path / "ok.mcap")
    cases = [
        (["--out", ok, "--video", str(tmp_path / "no" / "v.mp4")], "does not exist"),
        (["--out", str(tmp_path / "no" / "o.mcap")], "does not exist"),
        (["--out", str(tmp_path)], "is a folder"),
        (["--out", ok, "--video", str(a_file / "v.gif")], "is a file, not a folder"),
        (["--suite", "--out-dir", str(a_file / "suite")], "cannot create it"),
    ]
    for argv, words in cases:
        assert words in _usage_error(cli, capsys, argv), argv
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(ro) else real(p, mode))
    for argv in (["--out", ok, "--video", str(ro / "v.mp4")], ["--out", str(ro / "o.mcap")]):
        assert "not writable" in _usage_error(cli, capsys, argv), argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "ro"] and list(ro.iterdir()) == []


def test_regression_checkpoint_without_run_and_overrides_with_run(cli, capsys, tmp_path, nothing_runs):
    err = _usage_error(cli, capsys, ["--checkpoint", str(tmp_path / "c.msgpack")])
    assert "needs --run" in err
    run = Path(__file__).parent / "data" / "legacy_run"
    err = _usage_error(
        cli, capsys, ["--run", str(run), "--env.terrain=rough", "--out", str(tmp_path / "o.mcap")]
    )
    assert "not allowed with --run" in err
    # Regression: --controller gait --run R rolled out R's policy, not the gait, and said nothing
    for argv in (["--controller", "gait", "--run", str(run)], ["--controller", "pid", "--suite"]):
        err = _usage_error(cli, capsys, [*argv, "--out", str(tmp_path / "o.mcap")])
        assert "--controller" in err and ("give one" in err or "leave it out" in err), argv


def _fake_record(calls, fail=None):
    def record(path, env, controller, rng, n_envs, n_steps, on_segment=None, **kw):
        path = Path(path)
        calls["path"] = path
        calls["final_exists_during"] = path.with_name(path.name[: -len(".partial")]).exists()
        path.write_bytes(b"half")
        if fail is not None:
            raise fail
        return {"steps": n_steps, "falls": 0, "off_field": 0, "nan_resets": 0}

    return record


def test_regression_mcap_output_is_written_under_a_temporary_name(cli, capsys, tmp_path, monkeypatch):
    # Nothing half-written: the rollout writes OUT.partial and renames it to OUT when it finished;
    # a failed rollout leaves neither, an interrupted one leaves OUT.partial (readable with
    # mcap_check --recover) and says so. The environment is built (no compile) but not stepped.
    out = tmp_path / "o.mcap"
    calls = {}
    monkeypatch.setattr(cli.recording, "record", _fake_record(calls))
    assert cli.main(["--seconds", "0.04", "--out", str(out)]) == 0
    assert calls["path"] == tmp_path / "o.mcap.partial" and not calls["final_exists_during"]
    assert out.read_bytes() == b"half" and sorted(p.name for p in tmp_path.iterdir()) == ["o.mcap"]

    out2 = tmp_path / "o2.mcap"
    monkeypatch.setattr(cli.recording, "record", _fake_record(calls, RuntimeError("boom")))
    with pytest.raises(RuntimeError):
        cli.main(["--seconds", "0.04", "--out", str(out2)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.mcap"]

    monkeypatch.setattr(cli.recording, "record", _fake_record(calls, KeyboardInterrupt()))
    capsys.readouterr()
    assert cli.main(["--seconds", "0.04", "--out", str(out2)]) == cli.EXIT_INTERRUPTED == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.mcap", "o2.mcap.partial"]
    err = capsys.readouterr().err
    assert err.startswith("interrupted: ") and "--recover" in err and len(err.strip().splitlines()) == 1
