"""Knocked down while walking (quadson_mjx.knockdown, quadson-knockdown): bad input gives one line and
exit status 2; one short knock-down of the committed walking and get-up policies runs end to end on
sim2sim's plant: the kick fells the robot, the supervisor leaves walking, and every target sent is
finite and inside the motor limits.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from quadson_mjx import knockdown as K
from quadson_mjx.cli import knockdown as cli
from quadson_mjx.deploy_supervisor import Mode
from quadson_mjx.stats import success_interval

ROOT = Path(__file__).resolve().parents[1]
WALK, GETUP = ROOT / "results/policy_h100_sensors", ROOT / "results/getup_topple_h100"


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
        (["--knock", "slap"], "--knock slap"),
        (["--first", "-1"], "--first -1"),
        (["--video", "out.avi"], "*.mp4 or *.gif"),
        (["--supervisor", "fall_tilt=0.5"], "--supervisor fall_tilt=0.5"),
        (["--supervisor", "settle_s=soon"], "not a number"),
        (["--supervisor", "fall_tilt_rad=0.1"], "upright_tilt_rad <"),
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


def test_knock_names_agree():
    assert cli.KNOCKS == K.KNOCKS


def test_shove_wrench_by_hand(exported):
    """A shove is SHOVE_FORCES_N[n] along a horizontal world direction, applied at the centre of the
    base box's top face: xfrc_applied (at the base's centre of mass) is that force and the moment
    (point - centre of mass) x force; it acts SHOVE_S (8 ticks of 20 ms) and is then cleared, and a
    second shove keeps the first's direction."""
    _, plant, _ = K.build(*exported, "flat")
    plant.rng = np.random.default_rng(0)
    plant.reset((0.0, 0.0), 0.7)
    shove = K.Shove(plant, np.random.default_rng(4))
    info = shove.start(0, 0.02)
    assert info["force_n"] == K.SHOVE_FORCES_N[0] and info["duration_s"] == K.SHOVE_S
    d, b, m = plant.d, plant.root, plant.m
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
    ticks = 0
    while True:
        shove.tick()
        f, tau = d.xfrc_applied[b, :3].copy(), d.xfrc_applied[b, 3:].copy()
        if not np.any(f):
            assert not np.any(tau)
            break
        ticks += 1
        top = d.xpos[b] + d.xmat[b].reshape(3, 3) @ (m.geom_pos[g] + [0.0, 0.0, m.geom_size[g][2]])
        assert f[2] == 0.0 and np.linalg.norm(f) == pytest.approx(K.SHOVE_FORCES_N[0])
        np.testing.assert_allclose(tau, np.cross(top - d.xipos[b], f), atol=1e-12)
        plant.advance(0.02)
    assert ticks == round(K.SHOVE_S / 0.02) == 8
    first = shove.direction.copy()
    shove.start(1, 0.02)
    shove.tick()
    f_dir = d.xfrc_applied[b, :3] / np.linalg.norm(d.xfrc_applied[b, :3])
    np.testing.assert_allclose(f_dir, first, atol=1e-12)
    assert np.linalg.norm(d.xfrc_applied[b, :3]) == pytest.approx(K.SHOVE_FORCES_N[1])


@pytest.mark.parametrize("knock", ["kick", "shove"])
def test_one_knockdown_end_to_end_targets_in_limits_fall_detected(exported, knock, monkeypatch):
    if knock == "shove":  # one shove hard enough to fell it within this short trial
        monkeypatch.setattr(K, "SHOVE_FORCES_N", (60.0,))
        monkeypatch.setattr(K.Shove, "max_knocks", 1)
    sup, plant, _ = K.build(*exported, "flat")
    sent, modes = [], []
    send, step = plant.send, sup.step
    plant.send = lambda m: (sent.append(np.array(m)), send(m))
    sup.step = lambda *a, **k: (out := step(*a, **k), modes.append(out.mode))[0]
    plant.rng = np.random.default_rng(0)
    row = K.run_trial(
        sup, plant, np.random.default_rng(1), walk_s=1.0, seconds_per_trial=1.5, hold_s=0.5, knock=knock
    )
    sent = np.array(sent)
    r = sup.walking.config.robot
    assert sent.shape == (len(modes), 12) and len(modes) == round(row["sim_s"] / 0.02)
    assert np.all(np.isfinite(sent))
    assert np.all(sent >= r.motor_limits[:, 0]) and np.all(sent <= r.motor_limits[:, 1])
    assert row["bad_target_ticks"] == 0
    assert modes[:50] == [Mode.WALKING] * 50 and not row["fell_before_kick"]  # walked until the kick
    assert row["detected"] and 0.0 < row["t_detect_s"] < 1.0
    assert Mode.GETTING_UP in modes  # (fallen lasts no tick with the default settle_s 0)
    limit = K.MAX_KICKS if knock == "kick" else len(K.SHOVE_FORCES_N)
    assert 1 <= len(row["kicks"]) <= limit and row["max_tilt_deg"] > 50.0
    assert ("force_n" in row["kicks"][0]) is (knock == "shove")
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
    wins = sum(t["success"] for t in res["trials"])
    assert res["summary"]["success_rate_95"] == success_interval(wins, 2)
    assert res["settings"]["supervisor"]["fall_tilt_rad"] == pytest.approx(math.radians(25.0))
    printed = capsys.readouterr().out
    assert "success 0/2" in printed  # 1 s after the last kick cannot include 2 s walking
    # --mirror-to trained (the default) recorded as the side it resolved to: this policy trained on both
    assert res["settings"]["getup_mirror_to"] is None and "get-up mirrored to neither side" in printed
    steps = round(res["trials"][0]["sim_s"] / 0.02)
    report = mcap_check.check(str(mcap))
    assert report.complete and report.counts["/rollout/step"] == steps


def test_no_knock_walks_without_a_false_alarm(exported):
    """--knock none under the walking run's pushes: 1.5 s of walking on the stone field, no knock, no
    fall detected, the supervisor in walking throughout, the trial a success."""
    sup, plant, _ = K.build(*exported, "stones", pushes=True)
    assert plant.push is not None
    plant.rng = np.random.default_rng(2)
    row = K.run_trial(sup, plant, np.random.default_rng(3), walk_s=0.5, seconds_per_trial=1.0, knock="none")
    assert row["kicks"] == [] and not row["detected"] and row["final_mode"] == str(Mode.WALKING)
    assert row["sim_s"] == pytest.approx(1.5) and row["success"] and row["max_tilt_deg"] < 25.0
