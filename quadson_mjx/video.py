"""Headless videos of rollouts: MuJoCo's OpenGL renderer into an MP4 (H.264) or a GIF, one frame per
control step, from a camera that follows the robot.

    python eval/rollout.py --run results/policy_h200_seed --seconds 5 --video walk.mp4

OpenGL without a display: EGL (Mesa's software rasteriser llvmpipe on a CPU, the NVIDIA driver on a
GPU) or OSMesa, chosen by MUJOCO_GL=egl|osmesa, else EGL when libEGL is installed, else OSMesa. The
context is made here, so MUJOCO_GL need not be set before mujoco is imported. Frames are encoded by
the ffmpeg binary of the imageio-ffmpeg package (pip install "quadson_mjx[video]").

A video is written under a temporary name beside the target (".NAME.partial.mp4") and renamed to
the target when closed, so the target is never a half-written file; `abort()` removes it instead.
A bad path (not .mp4 or .gif, a folder, a missing or read-only folder, an existing file without
overwrite) is refused when the writer is made, before any frame is rendered.
"""

from __future__ import annotations

import copy
import ctypes.util
import os
from pathlib import Path

import mujoco
import numpy as np

from quadson_mjx import errors

BACKENDS = ("egl", "osmesa")
SUFFIXES = (".mp4", ".gif")
# The tracking camera: distance [m] from the robot's centre of mass, azimuth and elevation [deg]
# (MuJoCo's: azimuth 90 looks along +y, elevation < 0 looks down): a view from the front left.
CAMERA_DISTANCE_M = 0.8
CAMERA_AZIMUTH_DEG = 140.0
CAMERA_ELEVATION_DEG = -20.0


def pick_backend() -> str:
    """MUJOCO_GL if it names a headless backend, else "egl" if libEGL is found, else "osmesa"."""
    env = os.environ.get("MUJOCO_GL", "").lower().strip()
    if env in BACKENDS:
        return env
    return "egl" if ctypes.util.find_library("EGL") else "osmesa"


def gl_context(width: int, height: int, backend: str | None = None):
    """A current, headless OpenGL context (mujoco's GLContext) -> (context, backend name)."""
    backend = backend or pick_backend()
    if backend not in BACKENDS:
        raise ValueError(f"unknown OpenGL backend {backend!r}; choose from {BACKENDS}")
    try:
        if backend == "egl":
            from mujoco.egl import GLContext
        else:
            from mujoco.osmesa import GLContext
        ctx = GLContext(width, height)
        ctx.make_current()
    except Exception as e:  # missing library, no device: both surface as different types
        raise RuntimeError(
            f"cannot open a headless OpenGL context with {backend} ({type(e).__name__}: {e}); install "
            "EGL (apt-get install libegl1 libgl1-mesa-dri) or OSMesa (apt-get install libosmesa6) "
            "and set MUJOCO_GL=egl or osmesa"
        ) from e
    return ctx, backend


def _track_body_id(model: mujoco.MjModel, name: str | None) -> int:
    if name is not None:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if body < 0:
            raise KeyError(f"body {name!r} not in the model")
        return body
    free = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    return int(model.jnt_bodyid[free[0]]) if free.size else 0


class Renderer:
    """Offscreen frames of a model at given qpos, from a camera tracking the base body.
    render(qpos (nq,)) -> (height, width, 3) uint8 RGB. close() frees the OpenGL context.
    `camera` (MjvCamera) and `option` (MjvOption, e.g. geomgroup) may be changed between frames."""

    def __init__(
        self,
        model: mujoco.MjModel,
        width: int = 640,
        height: int = 480,
        backend: str | None = None,
        shadows: bool = True,
        track_body: str | None = None,
    ):
        """track_body: the body the camera follows (default: the free-floating base, the body of the
        model's first free joint)."""
        self.model = copy.deepcopy(model)  # the offscreen buffer size is a model setting
        self.model.vis.global_.offwidth = max(width, self.model.vis.global_.offwidth)
        self.model.vis.global_.offheight = max(height, self.model.vis.global_.offheight)
        self.width, self.height = width, height
        self.data = mujoco.MjData(self.model)
        self._ctx, self.backend = gl_context(width, height, backend)
        self._con = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scene = mujoco.MjvScene(self.model, maxgeom=1000)
        # Shadows and the floor's reflection cost most of a software-rendered frame (llvmpipe)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = shadows
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = shadows
        self.option = mujoco.MjvOption()
        self._perturb = mujoco.MjvPerturb()
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        self.camera.trackbodyid = _track_body_id(self.model, track_body)
        self.camera.distance = CAMERA_DISTANCE_M
        self.camera.azimuth = CAMERA_AZIMUTH_DEG
        self.camera.elevation = CAMERA_ELEVATION_DEG
        self._viewport = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)

    def render(self, qpos) -> np.ndarray:
        self.data.qpos[:] = qpos
        mujoco.mj_forward(self.model, self.data)  # body poses, subtree CoM (tracked), lights
        self._ctx.make_current()
        mujoco.mjv_updateScene(
            self.model,
            self.data,
            self.option,
            self._perturb,
            self.camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self._scene,
        )
        mujoco.mjr_render(self._viewport, self._scene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self._viewport, self._con)
        return np.flipud(self._rgb).copy()  # OpenGL's rows run bottom-up

    def close(self) -> None:
        if self._ctx is not None:
            self._con.free()
            self._ctx.free()
            self._ctx = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def check_video_path(path, overwrite: bool = False, what: str = "video") -> Path:
    """Raise before anything is rendered: ValueError unless the name ends in .mp4 or .gif,
    FileExistsError if it exists without overwrite, errors.UsageError for a folder or a missing or
    read-only folder. -> Path(path)."""
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise ValueError(f"{what} {path}: a video file name ends in .mp4 or .gif")
    errors.check_writable(path, what)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists: pass overwrite=True (--overwrite) to replace it")
    return path


class VideoWriter:
    """Frames (height, width, 3) uint8 -> an .mp4 (H.264, yuv420p) or a .gif (one palette) at fps.
    close() finishes the file and renames it into place; abort() discards it."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float, overwrite: bool = False):
        import imageio_ffmpeg

        self.path = check_video_path(path, overwrite)
        suffix = self.path.suffix.lower()
        # ffmpeg picks the container from the suffix: keep it last in the temporary name
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{suffix}")
        if suffix == ".mp4" and (width % 2 or height % 2):
            raise ValueError(f"H.264 needs an even width and height, got {width} x {height}")
        if suffix == ".gif":
            kw = {
                "codec": "gif",
                "pix_fmt_out": "pal8",
                "quality": None,
                "output_params": ["-vf", "split[a][b];[a]palettegen[p];[b][p]paletteuse"],
            }
        else:
            kw = {"codec": "libx264", "pix_fmt_out": "yuv420p", "quality": 7, "output_params": []}
        self.frames = 0
        self._gen = imageio_ffmpeg.write_frames(
            str(self._tmp), (width, height), fps=fps, macro_block_size=1, ffmpeg_log_level="error", **kw
        )
        self._gen.send(None)  # starts ffmpeg

    def write(self, frame: np.ndarray) -> None:
        self._gen.send(np.ascontiguousarray(frame, np.uint8))
        self.frames += 1

    def close(self) -> None:
        """Finish the file and rename it to `path`."""
        if self._gen is not None:
            self._gen.close()
            self._gen = None
            os.replace(self._tmp, self.path)

    def abort(self) -> None:
        """Stop ffmpeg and remove the temporary file; `path` is left as it was."""
        if self._gen is not None:
            try:
                self._gen.close()
            finally:
                self._gen = None
                self._tmp.unlink(missing_ok=True)


class RolloutVideo:
    """Renders environment `env_index` of each rollout segment (recording.record's on_segment) into
    a video at the control rate."""

    def __init__(
        self,
        path: str | Path,
        model: mujoco.MjModel,
        ctrl_dt: float,
        overwrite: bool = False,
        size: tuple[int, int] = (640, 480),
        env_index: int = 0,
    ):
        self.env_index = env_index
        width, height = size
        self._writer = VideoWriter(path, width, height, 1.0 / ctrl_dt, overwrite)
        try:
            self._renderer = Renderer(model, width, height)
        except Exception:
            self._writer.abort()
            raise

    def add_segment(self, start: int, traj) -> None:
        """start: first step index; traj: host Trajectory [t, B] (quadson_mjx.rollout)."""
        for qpos in np.asarray(traj.qpos[:, self.env_index], np.float64):
            self._writer.write(self._renderer.render(qpos))

    @property
    def frames(self) -> int:
        return self._writer.frames

    def close(self) -> None:
        """Finish the video (renamed into place)."""
        self._renderer.close()
        self._writer.close()

    def abort(self) -> None:
        """Discard the video (the rollout failed or was interrupted)."""
        self._renderer.close()
        self._writer.abort()
