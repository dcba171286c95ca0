"""Loading an exported policy on the robot: an .onnx (ONNX Runtime) or an .npz (numpy alone), its
metadata checked before anything runs.

    policy = load_policy("policy.onnx")   # policy(obs (obs_size,)) -> action (action_size,) float32
    policy.meta                           # the export's metadata (quadson_mjx.export: meta_json)

A file is refused (ValueError, one line) when it is not a policy file (another suffix, damaged or
truncated, no metadata), when its format version is one this loader does not know
(policy_file.FORMAT_VERSIONS), or when its observation cannot be built on a robot (`check_buildable`:
an entry from the simulator, or one the loop has no sensor for). Numpy (and onnxruntime for an
.onnx) only.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quadson_mjx import obs_spec
from quadson_mjx.policy_file import FORMAT_VERSIONS, NumpyPolicy

# observation entries the deploy loop builds (quadson_mjx.deploy), and lagged copies "name@-k" of
# obs_spec.HISTORY_ENTRIES
BUILDABLE = (
    "base_rpy", "base_lin_vel", "base_ang_vel", "motor_pos", "phase_sin", "phase_cos", "command",
    "gravity", "gyro", "motor_vel", "last_action", "yaw_error", "servo_latency",
)  # fmt: skip


def check_buildable(spec: obs_spec.Spec, where: str = "policy") -> None:
    """ValueError when an entry of `spec` cannot be built from the robot's sensors: one from the
    simulator (a critic's privileged entry), or a name the loop does not know."""
    for e in spec.entries:
        if e.sensor == "simulator":
            raise ValueError(
                f"{where}: observation entry {e.name!r} comes from the simulator; a robot cannot build it"
            )
        base, _, lag = e.name.partition("@-")
        if base not in BUILDABLE or (lag and (base not in obs_spec.HISTORY_ENTRIES or not lag.isdigit())):
            raise ValueError(f"{where}: observation entry {e.name!r} is not one the deploy loop builds")


def check_meta(meta: dict, where: str) -> dict:
    """meta, or ValueError for an unknown format version or an observation the robot cannot build."""
    if not isinstance(meta, dict) or "env_config" not in meta:
        raise ValueError(f"{where}: not a quadson_mjx export (its metadata has no env_config)")
    version = meta.get("format_version", 2)  # files before version 3 kept it only in the .npz arrays
    if version not in FORMAT_VERSIONS:
        raise ValueError(
            f"{where}: export format {version!r} is not one this loader knows ({', '.join(map(str, FORMAT_VERSIONS))}); "
            "update quadson_mjx on the robot or export again"
        )
    if "obs_spec" in meta:
        check_buildable(obs_spec.Spec.from_json(meta["obs_spec"]), where)
    return meta


class OnnxPolicy:
    """An .onnx export run by ONNX Runtime on one CPU thread: obs (obs_size,) -> action (action_size,)."""

    def __init__(self, path: str | Path, threads: int = 1):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads  # an MLP of 4 x 128: threads would cost more than they save
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own types for a damaged or foreign file
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ValueError(f"{path}: not a readable ONNX model (damaged or truncated?): {first}") from None
        props = self.session.get_modelmeta().custom_metadata_map
        if "meta_json" not in props:
            raise ValueError(f"{path}: not a quadson_mjx export (no meta_json in its metadata)")
        self.meta = check_meta(json.loads(props["meta_json"]), str(path))
        (inp,), (out,) = self.session.get_inputs(), self.session.get_outputs()
        self.obs_size, self.action_size = int(inp.shape[1]), int(out.shape[1])
        self._names = ([out.name], inp.name)

    def __call__(self, obs) -> np.ndarray:
        x = np.asarray(obs, np.float32).reshape(1, self.obs_size)
        return self.session.run(self._names[0], {self._names[1]: x})[0][0]


def load_npz(path: str | Path) -> NumpyPolicy:
    """An exported .npz (numpy only); ValueError for a damaged file or an unknown format."""
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        version = int(arrays.get("format_version", -1))
        policy = NumpyPolicy(arrays) if version in FORMAT_VERSIONS else None
    except Exception as e:  # zipfile, numpy and NumpyPolicy raise several types for a damaged file
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ValueError(
            f"{path}: not a readable policy .npz (damaged or truncated?): {type(e).__name__} {first}"
        ) from None
    if policy is None:
        raise ValueError(
            f"{path}: export format {version} is not one this loader knows ({', '.join(map(str, FORMAT_VERSIONS))})"
        )
    policy.meta.setdefault("format_version", version)
    check_meta(policy.meta, str(path))
    return policy


def load_policy(path: str | Path):
    """An exported policy: .onnx (ONNX Runtime) or .npz (numpy). ValueError (one line) for a file
    that is missing, of another kind, damaged, of an unknown format version or not buildable."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such policy file")
    if path.suffix.lower() == ".onnx":
        return OnnxPolicy(path)
    if path.suffix.lower() == ".npz":
        return load_npz(path)
    raise ValueError(f"{path}: a policy file is *.onnx or *.npz (python -m quadson_mjx.export)")
