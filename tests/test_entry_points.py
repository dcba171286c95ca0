"""The evaluation programs' answers to bad input: one line on stderr ("error: ..."), exit status 2,
nothing written, before anything is simulated or compiled (quadson_mjx.errors). In-process through
`main(argv)`; a few runs through the console scripts check the exit status a shell sees.
rollout's cases are in test_rollout_cli.py, mcap_check's in test_mcap_log.py, gaits' in
test_gaits.py, video paths in test_video.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.writer import Writer

from quadson_mjx.mcap_log import McapLog

ROOT = Path(__file__).resolve().parents[1]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return err


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _rollout_file(path: Path, n_envs: int = 2, n_steps: int = 100, vx: float = 0.1) -> None:
    """A minimal rollout MCAP (the fields quadson_mjx.report reads): every env walks forward at
    `vx` m/s, level, for n_steps of 0.02 s, and never falls."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        w.add_metadata("rollout", {"controller": "gait", "terrain": "flat", "ctrl_dt_s": "0.02"})
        sid = w.register_schema("step", "jsonschema", b"{}")
        ch = w.register_channel("/rollout/step", "json", sid)
        for k in range(n_steps):
            for e in range(n_envs):
                base = dict.fromkeys(("y", "z", "roll", "pitch", "yaw", "vy", "vz", "wx", "wy", "wz"), 0.0)
                base.update(x=vx * 0.02 * (k + 1), vx=vx)
                m = {"env": e, "base": base, "done": False, "command": {"vx": vx, "vy": 0.0, "yaw_rate": 0.0}}
                t = 20_000_000 * (k + 1)
                w.add_message(ch, t, json.dumps(m).encode(), t)
        w.finish()


# --- report -----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def report_cli():
    from quadson_mjx.cli import report

    return report


@pytest.fixture(scope="module")
def rollout_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rollout") / "gait_flat_forward.mcap"
    _rollout_file(path)
    return path


def test_regression_report_bad_inputs_are_one_line(report_cli, capsys, tmp_path, rollout_file):
    # Regression: a missing file, a non-rollout MCAP and --window-s nan gave tracebacks;
    # --window-s -1 wrote tables of NaN. Each is one line, exit status 2, nothing written.
    log = tmp_path / "train.mcap"  # an MCAP, but a training log
    with McapLog(log) as m:
        m.log("/train/metrics", {"steps": 1.0}, 1)
    text = tmp_path / "notes.txt"
    text.write_text("not an MCAP")
    out = tmp_path / "out"
    good = str(rollout_file)
    cases = [
        ([str(tmp_path / "missing.mcap")], "no such file"),
        ([str(tmp_path)], "is a folder"),
        ([str(log)], "not a rollout MCAP file (it has no /rollout/step messages)"),
        ([str(text)], "not a rollout MCAP file (offset 0: not an MCAP file"),
        ([good, "--window-s", "nan"], "--window-s nan: must be a finite number > 0"),
        ([good, "--window-s", "-1"], "--window-s -1.0: must be a finite number > 0"),
        ([good, "--window-s", "0"], "--window-s 0.0"),
        ([good, "--settle-s", "-1"], "--settle-s -1.0: must be a finite number >= 0"),
        ([good, "--avg-s", "inf"], "--avg-s inf"),
        ([good, "--window-s", "x"], "invalid float value"),
        ([], "required: files"),
        ([good, "--out-dir", str(text / "sub")], "--out-dir"),
    ]
    before = _files(tmp_path)
    for argv, words in cases:
        assert report_cli.main([*argv, "--out-dir", str(out)] if "--out-dir" not in argv else argv) == 2, argv
        assert words in _one_line_error(capsys), argv
    assert _files(tmp_path) == before  # no report folder, no half table


def test_report_writes_whole_tables_of_a_rollout(report_cli, capsys, tmp_path, rollout_file):
    # The tables of the minimal rollout: vx 0.1 m/s at every step (hand: mean 0.1, std 0), speed
    # from the x travel 0.1 * 0.02 * 99 m over 99 steps = 0.1 m/s; written atomically (no temporary
    # files left beside them).
    out = tmp_path / "out"
    assert report_cli.main([str(rollout_file), "--out-dir", str(out)]) == 0
    assert {"report.json", "report.md"} <= set(_files(out)) and not any(
        n.startswith(".") for n in _files(out)
    )
    rows = json.loads((out / "report.json").read_text())
    assert rows[0]["seed000"]["vx"] == pytest.approx([0.1, 0.0], abs=1e-12)
    assert rows[0]["seed003"]["speed"][0] == pytest.approx(0.1, rel=1e-9)
    assert "| gait | flat | forward |" in (out / "report.md").read_text()
    capsys.readouterr()


# --- caramel seed 003, gait ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, words",
    [
        (["--samples-1", "0"], "--samples-1 0: need at least 1 sample"),  # regression: NaN tables
        (["--samples-23", "0"], "--samples-23 0: need at least 1 sample"),
        (["--max-time-s", "-1"], "--max-time-s -1.0: must be a finite number > 0"),  # regression
        (["--max-time-s", "nan"], "--max-time-s nan"),
        (["--max-time-s", "1e9"], "<= 3600"),
        (["--json", "{tmp}/no/r.json"], "does not exist"),
        (["--json", "{tmp}"], "is a folder"),
        (["--run", "{tmp}/missing"], "not a run directory"),
        (["--samples-1", "two"], "invalid int value"),
    ],
)
def test_regression_seed003_bad_inputs_are_one_line(capsys, tmp_path, args, words):
    from quadson_mjx.cli import seed003

    argv = [a.format(tmp=tmp_path) for a in args]
    assert seed003.main(argv) == 2
    assert words in _one_line_error(capsys)
    assert _files(tmp_path) == []


@pytest.mark.parametrize(
    "args, words",
    [
        (["--vx", "nan"], "--vx nan: must be a finite number"),
        (["--yaw-rate", "inf"], "--yaw-rate inf"),
        (["--duration-s", "inf"], "--duration-s inf"),
        (["--duration-s", "0.5"], "must outlast the ramp"),  # it indexed an empty window
        (["--ctrl-dt", "0.021"], "not a whole multiple of the physics timestep"),
        (["--ctrl-dt", "-1"], "--ctrl-dt -1.0"),
        (["--gait", "foo"], "invalid choice: 'foo'"),
        (["--json", "{tmp}/no/g.json"], "does not exist"),
        (["--robot", "caramel", "--gait", "walk"], "caramel runs"),
    ],
)
def test_regression_gait_bad_inputs_are_one_line(capsys, tmp_path, args, words):
    from quadson_mjx.cli import gait

    argv = [a.format(tmp=tmp_path) for a in args]
    assert gait.main(argv) == 2
    assert words in _one_line_error(capsys)
    assert _files(tmp_path) == []


# --- through the console scripts: the status a shell sees ----------------------------------------------


def test_console_scripts_exit_2_with_one_line(tmp_path):
    # One bad input per program, run as the user runs it (pip install -e . puts the scripts on
    # PATH); the programs start together, each pays one Python + JAX import.
    runs = {
        "quadson-rollout": ["--vx", "nan", "--out", str(tmp_path / "r.mcap")],
        "quadson-report": [str(tmp_path / "missing.mcap"), "--out-dir", str(tmp_path / "rep")],
        "quadson-gaits": ["--seconds", "nan"],
        "quadson-gait": ["--duration-s", "-1"],
        "quadson-seed003": ["--samples-1", "0"],
        "quadson-mcap-check": [str(tmp_path)],
    }
    missing = [name for name in runs if shutil.which(name) is None]
    if missing:
        pytest.skip(f"console scripts not installed (pip install -e .): {missing}")
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    procs = {
        name: subprocess.Popen(
            [name, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path
        )
        for name, args in runs.items()
    }
    for name, p in procs.items():
        out, err = p.communicate(timeout=120)
        lines = [line for line in err.splitlines() if line.strip()]
        assert p.returncode == 2, (name, err)
        assert len(lines) == 1 and lines[0].startswith("error: "), (name, err)
    assert _files(tmp_path) == []


def test_eval_script_shim_exits_2_with_one_line(tmp_path):
    # The old script path (eval/report.py) calls the same wrapped main.
    res = subprocess.run(
        [sys.executable, str(ROOT / "eval" / "report.py"), str(tmp_path / "missing.mcap")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert res.returncode == 2 and res.stderr.strip().startswith("error: ")
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
