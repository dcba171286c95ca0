"""Knocked down while walking (quadson_mjx.knockdown, quadson-knockdown): bad input gives one line and
exit status 2; one short knock-down of the committed walking and get-up policies runs end to end on
sim2sim's plant: the kick fells the robot, the supervisor leaves walking, and every target sent is
finite and inside the motor limits.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from quadson_mjx import knockdown as K
from quadson_mjx.cli import knockdown as cli
from quadson_mjx.deploy_supervisor import Mode

ROOT = Path(__file__).resolve().parents[1]
WALK, GETUP = ROOT / "results/policy_h100_sensors", ROOT / "results/getup_h100"


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    "extra, says",
    [
        (["--walk", "no/such/walk.onnx"], "--walk no/such/walk.onnx"),
        (["--getup", str(ROOT / "README.md")], "*.onnx or *.npz"),
        (["--getup", str(ROOT / "results")], "not a training run directory"),
        (["--trials", "0"], "--trials 0"),
        (["--trials", "many"], "--trials"),
        (["--terrain", "mud"], "--terrain mud"),
        (["--seconds", "nan"], "--seconds nan"),
        (["--json", "no/such/folder/out.json"], "does not exist"),
    ],
)
def test_bad_input_gives_one_line_and_status_2(capsys, tmp_path, extra, says):
    argv = ["--walk", str(WALK), "--getup", str(GETUP), *extra]
    assert cli.main(argv) == 2
    assert says in _one_line_error(capsys)


def test_a_walking_run_as_the_getup_policy_is_refused(capsys):
    assert cli.main(["--walk", str(WALK), "--getup", str(WALK), "--trials", "1"]) == 2
    assert "not getup" in _one_line_error(capsys)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from quadson_mjx import export

    out = tmp_path_factory.mktemp("knockdown")
    return export.export_run(WALK, out / "walk.onnx"), export.export_run(GETUP, out / "getup.onnx")


def test_one_knockdown_end_to_end_targets_in_limits_fall_detected(exported):
    sup, plant, _ = K.build(*exported, "flat")
    sent, modes = [], []
    send, step = plant.send, sup.step
    plant.send = lambda m: (sent.append(np.array(m)), send(m))
    sup.step = lambda *a, **k: (out := step(*a, **k), modes.append(out.mode))[0]
    plant.rng = np.random.default_rng(0)
    row = K.run_trial(sup, plant, np.random.default_rng(1), walk_s=1.0, seconds_per_trial=1.5, hold_s=0.5)
    sent = np.array(sent)
    r = sup.walking.config.robot
    assert sent.shape == (len(modes), 12) and len(modes) == round(row["sim_s"] / 0.02)
    assert np.all(np.isfinite(sent))
    assert np.all(sent >= r.motor_limits[:, 0]) and np.all(sent <= r.motor_limits[:, 1])
    assert row["bad_target_ticks"] == 0
    assert modes[:50] == [Mode.WALKING] * 50 and not row["fell_before_kick"]  # walked until the kick
    assert row["detected"] and Mode.FALLEN in modes and 0.0 < row["t_detect_s"] < 1.0
    assert 1 <= len(row["kicks"]) <= K.MAX_KICKS and row["max_tilt_deg"] > 50.0
    assert row["attempts"] >= 1 and math.isfinite(row["final_tilt_deg"])
    assert row["success"] is False  # 1.5 s after a fall is too short to stand and walk 0.5 s


def test_cli_writes_json_and_an_mcap_of_the_first_trial(exported, tmp_path, capsys):
    from quadson_mjx import mcap_check

    walk, getup = exported
    out, mcap = tmp_path / "kd.json", tmp_path / "kd.mcap"
    argv = ["--walk", str(walk), "--getup", str(getup), "--trials", "2", "--seed", "3", "--seconds", "1"]
    assert cli.main([*argv, "--json", str(out), "--mcap", str(mcap)]) == 0
    res = json.loads(out.read_text())
    assert [t["trial"] for t in res["trials"]] == [0, 1] and res["summary"]["trials"] == 2
    assert res["summary"]["detected"] == sum(t["detected"] for t in res["trials"])
    assert res["summary"]["bad_target_ticks"] == 0 and res["settings"]["seconds_per_trial"] == 1.0
    assert "success 0/2" in capsys.readouterr().out  # 1 s after the last kick cannot include 2 s walking
    steps = round(res["trials"][0]["sim_s"] / 0.02)
    report = mcap_check.check(str(mcap))
    assert report.complete and report.counts["/rollout/step"] == steps
