"""Headless rendering (quadson_mjx.video) on the CPU: the tracking camera keeps the robot in the
middle of the frame wherever it walks, the MP4 and GIF decode to the frames rendered, and
eval/rollout.py --video renders the rollout's first environment."""

import types
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from quadson_mjx import video
from quadson_mjx.robots.quadson import model as qmodel

W, H = 96, 72  # small frames: software rendering on 2 cores


@pytest.fixture(scope="module")
def model():
    return qmodel.load_model("flat")


@pytest.fixture(scope="module")
def renderer(model):
    with video.Renderer(model, W, H, shadows=False) as r:
        yield r


def _robot_pixels(renderer, qpos) -> np.ndarray:
    """(H, W) bool: pixels that change when the robot's geoms (groups 2, 3) are hidden."""
    with_robot = renderer.render(qpos).astype(int)
    renderer.option.geomgroup[2] = 0
    try:
        without = renderer.render(qpos).astype(int)
    finally:
        renderer.option.geomgroup[2] = 1
    return np.abs(with_robot - without).max(axis=-1) > 40


def test_tracking_camera_keeps_the_robot_in_the_middle(model, renderer):
    home = qmodel.home_qpos(model)
    assert renderer.backend in video.BACKENDS
    frame = renderer.render(home)
    assert frame.shape == (H, W, 3) and frame.dtype == np.uint8 and frame.std() > 10
    rows, cols = np.mgrid[0:H, 0:W]
    for dx, dy in [(0.0, 0.0), (3.0, -1.0)]:  # the robot walked 3 m forward and 1 m right
        q = home.copy()
        q[0] += dx
        q[1] += dy
        mask = _robot_pixels(renderer, q)
        # the camera looks at the robot's centre of mass from 0.8 m: the robot fills a good part
        # of the frame and its pixels are centred
        assert 0.05 < mask.mean() < 0.8
        assert abs(rows[mask].mean() / H - 0.5) < 0.15 and abs(cols[mask].mean() / W - 0.5) < 0.15
    # an independent check that the mask finds the robot: a fixed camera loses it after 3 m
    fixed = video.mujoco.MjvCamera()
    video.mujoco.mjv_defaultFreeCamera(renderer.model, fixed)
    fixed.lookat[:], fixed.distance, fixed.elevation = (0.0, 0.0, 0.2), 0.8, -20.0
    tracking, renderer.camera = renderer.camera, fixed
    try:
        assert _robot_pixels(renderer, home).mean() > 0.05
        far = home.copy()
        far[0] += 3.0
        assert _robot_pixels(renderer, far).mean() < 0.01
    finally:
        renderer.camera = tracking


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_video_file_decodes_to_the_rendered_frames(model, renderer, tmp_path, suffix):
    home = qmodel.home_qpos(model)
    frames = []
    for k in range(4):
        q = home.copy()
        q[2] += 0.03 * k  # the robot rises 3 cm a frame: different frames
        frames.append(renderer.render(q))
    path = tmp_path / f"clip{suffix}"
    w = video.VideoWriter(path, W, H, fps=50.0)
    for f in frames:
        w.write(f)
    w.close()
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert tuple(meta["size"]) == (W, H)
    if suffix == ".mp4":
        assert meta["fps"] == pytest.approx(50.0)
    decoded = [np.frombuffer(b, np.uint8).reshape(H, W, 3) for b in reader]
    assert len(decoded) == 4
    for got, want in zip(decoded, frames, strict=True):
        assert np.abs(got.astype(int) - want).mean() < 8  # lossy H.264 / a 256-colour palette
    assert np.abs(decoded[0].astype(int) - decoded[3]).mean() > 2  # and the frames differ
    with pytest.raises(FileExistsError, match="overwrite"):
        video.VideoWriter(path, W, H, fps=50.0)


def test_rollout_cli_video_renders_the_first_environment(monkeypatch, tmp_path, model):
    from quadson_mjx.cli import rollout as cli

    home = qmodel.home_qpos(model)
    env0 = np.stack([home + np.eye(model.nq)[2] * 0.02 * k for k in range(3)])  # (3, nq), rising
    env1 = np.stack([home + np.eye(model.nq)[0] * 5.0] * 3)  # 5 m away: not drawn
    calls = {}

    def fake_record(path, env, controller, rng, n_envs, n_steps, on_segment=None, **kw):
        calls.update(n_envs=n_envs, n_steps=n_steps)
        Path(path).write_bytes(b"")
        on_segment(0, types.SimpleNamespace(qpos=np.stack([env0, env1], axis=1)))  # [t, B, nq]
        return {"steps": n_steps, "falls": 0, "off_field": 0, "nan_resets": 0}

    monkeypatch.setattr(cli.recording, "record", fake_record)
    out, clip = tmp_path / "r.mcap", tmp_path / "r.mp4"
    argv = [
        "--envs",
        "2",
        "--seconds",
        "0.06",
        "--out",
        str(out),
        "--video",
        str(clip),
        "--video-size",
        "96x72",
    ]
    assert cli.main(argv) == 0
    assert calls == {"n_envs": 2, "n_steps": 3}
    reader = imageio_ffmpeg.read_frames(str(clip))
    meta = next(reader)
    assert tuple(meta["size"]) == (W, H) and meta["fps"] == pytest.approx(50.0)  # the control rate
    decoded = [np.frombuffer(b, np.uint8).reshape(H, W, 3) for b in reader]
    assert len(decoded) == 3
    with video.Renderer(model, W, H) as r:  # the CLI renders with shadows
        want = r.render(env0[2])
    assert np.abs(decoded[2].astype(int) - want).mean() < 8


def test_regression_video_bad_paths_refused_before_ffmpeg_starts(tmp_path, monkeypatch):
    # Bad video paths are refused when the writer is made, before ffmpeg or a GL context starts
    # (the rollout CLI checks the same paths before the rollout runs): a suffix other than .mp4 or
    # .gif, a folder, a missing folder, a path below a regular file, an existing file.
    from quadson_mjx.errors import UsageError

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", lambda *a, **k: pytest.fail("ffmpeg started"))
    a_file = tmp_path / "file.mp4"
    a_file.write_bytes(b"keep")
    cases = [
        (tmp_path / "clip.avi", ValueError, ".mp4 or .gif"),
        (tmp_path / "dir.mp4", UsageError, "is a folder"),
        (tmp_path / "no" / "clip.mp4", UsageError, "does not exist"),
        (a_file / "clip.gif", UsageError, "is a file, not a folder"),
        (a_file, FileExistsError, "overwrite"),
    ]
    (tmp_path / "dir.mp4").mkdir()
    for path, exc, words in cases:
        with pytest.raises(exc, match=words.replace(".", r"\.")):
            video.VideoWriter(path, W, H, fps=50.0)
    assert a_file.read_bytes() == b"keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.mp4", "file.mp4"]


def test_regression_video_is_renamed_into_place_only_when_closed(tmp_path):
    # Nothing half-written: while frames are written the target does not exist (a temporary
    # ".clip.partial.mp4" beside it does); close() renames it, abort() removes it and leaves an
    # existing target as it was.
    frame = np.zeros((H, W, 3), np.uint8)
    path = tmp_path / "clip.mp4"
    w = video.VideoWriter(path, W, H, fps=50.0)
    w.write(frame)
    # ffmpeg may not have opened its output yet: the temporary file or nothing
    assert not path.exists() and {p.name for p in tmp_path.iterdir()} <= {".clip.partial.mp4"}
    w.close()
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]
    before = path.read_bytes()
    w = video.VideoWriter(path, W, H, fps=50.0, overwrite=True)
    w.write(frame + 255)
    w.abort()
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"] and path.read_bytes() == before
