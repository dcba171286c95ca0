"""The exported policy file's format: its version and numpy inference of its arrays.

quadson_mjx.export writes the file, quadson_mjx.deploy_policy loads and checks it on the robot;
both read these names from here. Only numpy is imported: the robot's computer loads this module.
"""

from __future__ import annotations

import json

import numpy as np

# 2 added "squash" (a version-1 file is a tanh_normal policy); 3 the robot's metadata (motors, home
# pose, limits, trained sensor model, model identity, provenance) and format_version in meta_json
FORMAT_VERSION = 3
FORMAT_VERSIONS = (1, 2, 3)  # the versions the loaders (load, deploy_policy) read
SQUASH = {"tanh": np.tanh, "clip": lambda x: np.clip(x, np.float32(-1.0), np.float32(1.0))}
ACTIVATIONS = {
    "swish": lambda x: x * (np.float32(0.5) + np.float32(0.5) * np.tanh(np.float32(0.5) * x)),  # x sigmoid(x)
    "relu": lambda x: np.maximum(x, np.float32(0.0)),
    "tanh": np.tanh,
}


class NumpyPolicy:
    """A loaded export; call it with obs (..., obs_size) -> action (..., action_size) float32."""

    def __init__(self, arrays: dict):
        self.mean = np.asarray(arrays["obs_mean"], np.float32)
        self.std = np.asarray(arrays["obs_std"], np.float32)
        n = int(arrays["n_layers"])
        self.kernels = [np.asarray(arrays[f"kernel_{i}"], np.float32) for i in range(n)]
        self.biases = [np.asarray(arrays[f"bias_{i}"], np.float32) for i in range(n)]
        self.activation = str(arrays["activation"])
        self.action_size = int(arrays["action_size"])
        self.obs_size = int(arrays["obs_size"])
        self.squash = str(arrays.get("squash", "tanh"))
        if self.squash not in SQUASH:
            raise ValueError(f"unknown output squash {self.squash!r}; this file is newer than the loader")
        self.meta = json.loads(str(arrays["meta_json"]))

    def __call__(self, obs) -> np.ndarray:
        x = np.asarray(obs, np.float32)
        if x.shape[-1] != self.obs_size:
            raise ValueError(f"observation has {x.shape[-1]} values, the policy takes {self.obs_size}")
        act = ACTIVATIONS[self.activation]
        x = (x - self.mean) / self.std
        for i, (w, b) in enumerate(zip(self.kernels, self.biases, strict=True)):
            x = x @ w + b
            if i < len(self.kernels) - 1:
                x = act(x)
        return SQUASH[self.squash](x[..., : self.action_size])
