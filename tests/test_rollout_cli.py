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
