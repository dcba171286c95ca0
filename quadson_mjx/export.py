"""A trained policy for the robot's computer: one .npz file and a numpy-only inference function.

    python -m quadson_mjx.export RUN_DIR OUT.npz [--checkpoint PATH]

The file holds the observation normaliser (mean, std) and the policy MLP's layers of a brax PPO
checkpoint (quadson_mjx.training), plus the env and PPO configs as JSON so the robot side can check
the observation layout (29 values, seed 000: rpy, body linear and angular velocity, 12 motor
positions, sin/cos of the 4 leg phases; + command (vx, vy, yaw rate) when command tracking).

Inference is brax's deterministic PPO policy: obs -> (obs - mean) / std -> Dense + swish for every
hidden layer -> Dense -> the Gaussian's mean, in float32; then, by the run's policy_distribution,
"tanh_normal": tanh of the first action_size outputs (the last layer also carries the scales),
"gait_normal": the mean clipped to [-1, 1] (what the env does to every action). The result is the
env's normalised action in [-1, 1]: foot offsets times env.action_scale_m [m].

Only numpy is imported at module level: copy this file and the .npz onto the robot.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FORMAT_VERSION = 2  # 2 added "squash"; a version-1 file is a tanh_normal policy
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


def load(path: str | Path) -> NumpyPolicy:
    """Loads an exported .npz (numpy only)."""
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    if int(arrays.get("format_version", -1)) not in (1, FORMAT_VERSION):
        raise ValueError(f"{path}: export format {arrays.get('format_version')} is not 1 or {FORMAT_VERSION}")
    return NumpyPolicy(arrays)


def _policy_layers(policy: dict, distribution: str) -> list[dict]:
    """The policy's Dense layers in order, as brax builds them for `distribution`."""
    params = policy["params"]

    def hidden(group):
        names = sorted((k for k in group if k.startswith("hidden_")), key=lambda k: int(k.split("_")[1]))
        if len(names) != len(group):
            raise ValueError(f"unexpected policy layers {sorted(group)}: not a brax MLP")
        return [group[n] for n in names]

    if distribution == "tanh_normal":  # one MLP whose last layer outputs (mean, scale)
        return hidden(params)
    if distribution == "gait_normal":  # MLP (activated final layer) -> Dense mean; std separate
        if set(params) != {"MLP_0", "Dense_0", "std_logparam"}:
            raise ValueError(f"unexpected policy layers {sorted(params)} for a gait_normal policy")
        return hidden(params["MLP_0"]) + [params["Dense_0"]]
    raise ValueError(f"cannot export a {distribution!r} policy")


def export_arrays(
    params, obs_size: int, action_size: int, normalize: bool, meta: dict, distribution: str = "tanh_normal"
) -> dict:
    """(normaliser, policy, value) params of a brax PPO checkpoint -> the .npz's arrays."""
    normalizer, policy = params[0], params[1]
    layers = _policy_layers(policy, distribution)
    if normalize:
        mean = np.asarray(normalizer.mean, np.float32)
        std = np.asarray(normalizer.std, np.float32)
    else:
        mean, std = np.zeros(obs_size, np.float32), np.ones(obs_size, np.float32)
    out = {
        "format_version": np.int64(FORMAT_VERSION),
        "obs_mean": mean,
        "obs_std": std,
        "n_layers": np.int64(len(layers)),
        "squash": np.str_("tanh" if distribution == "tanh_normal" else "clip"),
        "activation": np.str_("swish"),  # brax make_ppo_networks' default, used by training.make_networks
        "obs_size": np.int64(obs_size),
        "action_size": np.int64(action_size),
        "meta_json": np.str_(json.dumps(meta)),
    }
    for i, layer in enumerate(layers):
        out[f"kernel_{i}"] = np.asarray(layer["kernel"], np.float32)
        out[f"bias_{i}"] = np.asarray(layer["bias"], np.float32)
    want = 2 * action_size if distribution == "tanh_normal" else action_size
    if out[f"kernel_{len(layers) - 1}"].shape[1] != want:
        raise ValueError(
            f"the policy's last layer has {out[f'kernel_{len(layers) - 1}'].shape[1]} outputs, "
            f"a {distribution} policy of {action_size} actions has {want}"
        )
    return out


def export_run(run_dir: str | Path, out_path: str | Path, checkpoint: str | Path | None = None) -> Path:
    """Exports the newest (or the given) checkpoint of a training run directory to out_path (.npz)."""
    from quadson_mjx import training
    from quadson_mjx.config import to_json
    from quadson_mjx.env import QuadsonEnv

    env_cfg, ppo_cfg = training.load_run_config(run_dir)
    env = QuadsonEnv(env_cfg)
    path = Path(checkpoint) if checkpoint else training.latest_checkpoint(run_dir)[0]
    params = training.load_checkpoint(path, env.observation_size, env.action_size, ppo_cfg)
    meta = {
        "checkpoint": str(path.name),
        "env_config": json.loads(to_json(env_cfg)),
        "ppo_config": json.loads(to_json(ppo_cfg)),
        "ctrl_dt_s": env.ctrl_dt,
        "action_scale_m": float(env_cfg.action_scale_m),
        "versions": training.versions(),
    }
    arrays = export_arrays(
        params,
        env.observation_size,
        env.action_size,
        bool(ppo_cfg.normalize_observations),
        meta,
        distribution=ppo_cfg.policy_distribution,
    )
    out_path = Path(out_path)
    np.savez(out_path, **arrays)
    return out_path


if __name__ == "__main__":
    import argparse

    p = argparse.ArgumentParser(description="Export a trained policy to .npz for numpy inference.")
    p.add_argument("run_dir")
    p.add_argument("out")
    p.add_argument("--checkpoint", default=None)
    a = p.parse_args()
    print(export_run(a.run_dir, a.out, a.checkpoint))
