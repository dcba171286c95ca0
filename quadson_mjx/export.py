"""A trained policy for the robot's computer: one .npz or .onnx file, and numpy-only inference.

    python -m quadson_mjx.export RUN_DIR OUT.npz  [--checkpoint PATH] [--overwrite]
    python -m quadson_mjx.export RUN_DIR OUT.onnx [--checkpoint PATH] [--overwrite]

The output's suffix picks the format; an existing file is kept unless --overwrite is given. The .npz
holds the observation normaliser (mean, std) and the policy MLP's layers of a brax PPO
checkpoint (quadson_mjx.training; with an asymmetric critic the actor's "state" normaliser only),
plus the metadata of quadson_mjx.export_meta as JSON: env and PPO configs, the observation and
action specification (quadson_mjx.obs_spec), the robot's motors, home pose and limits, the trained
sensor ranges, the model's identity and the run's provenance, so the robot side checks the layout it
builds against the one the policy was trained on. A checkpoint with non-finite weights is refused;
the file is written atomically (quadson_mjx.errors.atomic_write). Bad inputs on the command line:
one line on stderr, exit status 2.

Inference is brax's deterministic PPO policy: obs -> (obs - mean) / std -> Dense + swish for every
hidden layer -> Dense -> the Gaussian's mean, in float32; then, by the run's policy_distribution,
"tanh_normal": tanh of the first action_size outputs (the last layer also carries the scales),
"gait_normal": the mean clipped to [-1, 1] (what the env does to every action). The result is the
env's normalised action in [-1, 1]: foot offsets times env.action_scale_m [m].

The .onnx is the same computation as one ONNX graph (opset ONNX_OPSET, written with the `onnx`
package): input "obs" float32 [batch, obs_size], output "action" float32 [batch, action_size]; the
normaliser's mean and std are constants of the graph, and the run's metadata (the .npz's meta_json)
the observation and action specifications ("obs_spec", "action_spec", JSON) and a one-line
description ("obs_layout") are in the model's metadata_props. ONNX Runtime runs it
(quadson_mjx.deploy does, on the robot).

Only numpy is imported at module level. The .npz's inference is quadson_mjx.policy_file (numpy only):
copy that file and the .npz onto the robot, or run the .onnx with quadson_mjx.deploy.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from quadson_mjx.policy_file import (  # noqa: F401  (FORMAT_VERSIONS, SQUASH, ACTIVATIONS: this module's names too)
    ACTIVATIONS,
    FORMAT_VERSION,
    FORMAT_VERSIONS,
    SQUASH,
    NumpyPolicy,
)

SUFFIXES = (".npz", ".onnx")
ONNX_OPSET = 17  # every op used is older; ONNX Runtime >= 1.13 runs opset 17
ONNX_IR_VERSION = 8  # the IR of opset 17: a newer one would shut out older runtimes


def load(path: str | Path) -> NumpyPolicy:
    """Loads an exported .npz (numpy only; quadson_mjx.deploy_policy.load_npz, which checks it)."""
    from quadson_mjx.deploy_policy import load_npz

    return load_npz(path)


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


def _actor_stats(normalizer, key: str = "state"):
    """(mean, std) of the actor's observation normaliser: with an asymmetric critic brax keeps one
    per observation key ({"state": ..., "privileged_state": ...}) and the policy reads "state"."""
    mean, std = normalizer.mean, normalizer.std
    if isinstance(mean, dict):
        mean, std = mean[key], std[key]
    return np.asarray(mean, np.float32), np.asarray(std, np.float32)


def export_arrays(
    params, obs_size: int, action_size: int, normalize: bool, meta: dict, distribution: str = "tanh_normal"
) -> dict:
    """(normaliser, policy, value) params of a brax PPO checkpoint -> the .npz's arrays. obs_size:
    the actor's observation size. Raises ValueError for non-finite weights or normaliser values."""
    normalizer, policy = params[0], params[1]
    layers = _policy_layers(policy, distribution)
    if normalize:
        mean, std = _actor_stats(normalizer)
    else:
        mean, std = np.zeros(obs_size, np.float32), np.ones(obs_size, np.float32)
    if mean.shape != (obs_size,):
        raise ValueError(f"the normaliser has {mean.shape} values, the actor observes {obs_size}")
    out = {
        "format_version": np.int64(FORMAT_VERSION),
        "obs_mean": mean,
        "obs_std": std,
        "n_layers": np.int64(len(layers)),
        "squash": np.str_("tanh" if distribution == "tanh_normal" else "clip"),
        "activation": np.str_("swish"),  # brax make_ppo_networks' default, used by training.make_networks
        "obs_size": np.int64(obs_size),
        "action_size": np.int64(action_size),
        "meta_json": np.str_(json.dumps({**meta, "format_version": FORMAT_VERSION})),
    }
    for i, layer in enumerate(layers):
        out[f"kernel_{i}"] = np.asarray(layer["kernel"], np.float32)
        out[f"bias_{i}"] = np.asarray(layer["bias"], np.float32)
    bad = [k for k, v in out.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v))]
    if bad or not np.all(std > 0):
        raise ValueError(
            f"the checkpoint's policy is not finite ({', '.join(bad) or 'obs_std <= 0'}): "
            "a diverged run; export an earlier checkpoint with --checkpoint"
        )
    want = 2 * action_size if distribution == "tanh_normal" else action_size
    if out[f"kernel_{len(layers) - 1}"].shape[1] != want:
        raise ValueError(
            f"the policy's last layer has {out[f'kernel_{len(layers) - 1}'].shape[1]} outputs, "
            f"a {distribution} policy of {action_size} actions has {want}"
        )
    return out


def check_output(out_path: str | Path, overwrite: bool = False) -> Path:
    """The output path if it can be written: ValueError for an unknown suffix, FileExistsError for
    an existing file without overwrite, errors.UsageError for a missing or read-only folder."""
    import tempfile

    from quadson_mjx.errors import UsageError, check_writable

    out_path = Path(out_path)
    if out_path.suffix.lower() not in SUFFIXES:
        raise ValueError(
            f"{out_path}: unknown output format {out_path.suffix or '(no suffix)'!r}; "
            f"name the file *.npz (numpy) or *.onnx (ONNX)"
        )
    if out_path.exists() and not overwrite:
        raise FileExistsError(f"{out_path} exists: pass --overwrite to replace it, or choose another name")
    out_path = check_writable(out_path, "output")
    try:  # as root os.access says yes to a read-only file system: try it
        with tempfile.TemporaryFile(dir=out_path.parent if str(out_path.parent) else "."):
            pass
    except OSError as e:
        raise UsageError(
            f"output {out_path}: its folder is not writable ({e.strerror}); choose a writable path"
        ) from None
    return out_path


def export_run(
    run_dir: str | Path, out_path: str | Path, checkpoint: str | Path | None = None, overwrite: bool = False
) -> Path:
    """Exports the newest (or the given) checkpoint of a training run directory to out_path, a .npz
    or an .onnx by its suffix, written atomically under exactly that name. Raises (before loading
    anything) ValueError for another suffix, FileExistsError if out_path exists and not overwrite,
    errors.UsageError for a folder that is missing or not writable; then ValueError for a checkpoint
    of another run or robot, a damaged or non-finite one (training.load_checkpoint)."""
    out_path = check_output(out_path, overwrite)
    from quadson_mjx import training
    from quadson_mjx.envs import make_env
    from quadson_mjx.errors import atomic_write
    from quadson_mjx.export_meta import run_meta

    env_cfg, ppo_cfg = training.load_run_config(run_dir, for_evaluation=True)  # a Warp run: its JAX model
    env = make_env(env_cfg)
    path = Path(checkpoint) if checkpoint else training.latest_checkpoint(run_dir)[0]
    params = training.load_checkpoint(path, env.observation_size, env.action_size, ppo_cfg)
    meta = run_meta(env, ppo_cfg, Path(run_dir), path)
    arrays = export_arrays(
        params,
        env.obs_spec.size,
        env.action_size,
        bool(ppo_cfg.normalize_observations),
        meta,
        distribution=ppo_cfg.policy_distribution,
    )
    data = onnx_model(arrays).SerializeToString() if out_path.suffix.lower() == ".onnx" else None
    if out_path.exists() and not overwrite:  # appeared meanwhile
        raise FileExistsError(f"{out_path} exists: pass --overwrite to replace it, or choose another name")
    with atomic_write(out_path, "wb") as f:
        if data is not None:
            f.write(data)
        else:
            np.savez(f, **arrays)  # to a file object: numpy appends no ".npz"
    return out_path


def _layout(meta: dict, key: str) -> str:
    """One line describing the spec `key` of an export's metadata (quadson_mjx.obs_spec)."""
    from quadson_mjx.obs_spec import Spec

    return Spec.from_json(meta[key]).describe() if key in meta else "(not recorded in this export)"


def onnx_model(arrays: dict):
    """The .npz's arrays -> an onnx.ModelProto computing NumpyPolicy's action, checked by
    onnx.checker. Needs the `onnx` package (pip install "quadson_mjx[deploy]")."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    policy = NumpyPolicy(arrays)
    if policy.activation != "swish":
        raise ValueError(f"ONNX export supports the swish activation, not {policy.activation!r}")
    n = len(policy.kernels)
    inits = [numpy_helper.from_array(policy.mean, "obs_mean"), numpy_helper.from_array(policy.std, "obs_std")]
    nodes = [
        helper.make_node("Sub", ["obs", "obs_mean"], ["centred"]),
        helper.make_node("Div", ["centred", "obs_std"], ["x0"]),
    ]
    for i, (w, b) in enumerate(zip(policy.kernels, policy.biases, strict=True)):
        last = i == n - 1
        if last:  # only the Gaussian's mean: the first action_size outputs
            w, b = w[:, : policy.action_size], b[: policy.action_size]
        inits += [numpy_helper.from_array(w, f"kernel_{i}"), numpy_helper.from_array(b, f"bias_{i}")]
        nodes += [
            helper.make_node("MatMul", [f"x{i}", f"kernel_{i}"], [f"mm{i}"]),
            helper.make_node("Add", [f"mm{i}", f"bias_{i}"], ["mean" if last else f"pre{i}"]),
        ]
        if not last:  # swish(x) = x sigmoid(x)
            nodes += [
                helper.make_node("Sigmoid", [f"pre{i}"], [f"sig{i}"]),
                helper.make_node("Mul", [f"pre{i}", f"sig{i}"], [f"x{i + 1}"]),
            ]
    if policy.squash == "tanh":
        nodes.append(helper.make_node("Tanh", ["mean"], ["action"]))
    else:
        inits += [
            numpy_helper.from_array(np.float32(-1.0), "lo"),
            numpy_helper.from_array(np.float32(1.0), "hi"),
        ]
        nodes.append(helper.make_node("Clip", ["mean", "lo", "hi"], ["action"]))
    graph = helper.make_graph(
        nodes,
        "quadson_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", policy.obs_size])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", policy.action_size])],
        initializer=inits,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", ONNX_OPSET)],
        producer_name="quadson_mjx",
        doc_string=(
            f"obs [batch, {policy.obs_size}] float32: {_layout(policy.meta, 'obs_spec')}. "
            f"action [batch, {policy.action_size}] float32 in [-1, 1]: {_layout(policy.meta, 'action_spec')}"
        ),
    )
    model.ir_version = ONNX_IR_VERSION
    props = {
        "meta_json": json.dumps(policy.meta),
        "obs_layout": _layout(policy.meta, "obs_spec"),
        "format_version": str(policy.meta.get("format_version", FORMAT_VERSION)),
    }
    for key in ("obs_spec", "action_spec"):
        if key in policy.meta:
            props[key] = policy.meta[key]
    helper.set_model_props(model, props)
    onnx.checker.check_model(model, full_check=True)
    return model


def main(argv=None) -> int:
    """The command line: every bad input (a bad argument, a run directory or checkpoint that cannot
    be exported, an output that cannot be written) prints one line and returns 2."""
    from quadson_mjx.errors import UsageError, one_line_errors

    @one_line_errors
    def run(argv):
        from quadson_mjx.errors import ArgumentParser

        p = ArgumentParser(
            prog="python -m quadson_mjx.export",
            description="Export a trained policy to .npz (numpy inference) or .onnx (ONNX Runtime).",
        )
        p.add_argument("run_dir", help="training run directory (config.json, checkpoints/)")
        p.add_argument("out", help="output file: *.npz or *.onnx")
        p.add_argument("--checkpoint", default=None, help="checkpoint file (default: the run's newest)")
        p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
        a = p.parse_args(argv)
        try:
            check_output(a.out, a.overwrite)
            if not (Path(a.run_dir) / "config.json").is_file():
                raise ValueError(f"{a.run_dir}: not a training run directory (no config.json in it)")
            if a.checkpoint is not None and not Path(a.checkpoint).is_file():
                raise ValueError(f"--checkpoint {a.checkpoint}: no such file")
            out = export_run(a.run_dir, a.out, a.checkpoint, overwrite=a.overwrite)
        except (ValueError, FileExistsError, FileNotFoundError) as e:
            raise UsageError(str(e)) from None
        print(out)
        return 0

    return run(argv)


if __name__ == "__main__":
    raise SystemExit(main())
