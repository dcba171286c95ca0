"""Policy export: the numpy inference of the .npz equals brax's JAX policy to float32 precision."""

import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from quadson_mjx import export, training
from quadson_mjx.config import to_json
from quadson_mjx.env_config import env_config

OBS, ACT = 29, 12


@pytest.fixture(scope="module", params=["tanh_normal", "gait_normal"])
def run_dir(tmp_path_factory, request):
    """A run directory with a perturbed-init checkpoint (two hidden layers) and a non-trivial
    normaliser, for each policy distribution."""
    run = tmp_path_factory.mktemp("run")
    env_cfg = env_config()
    ppo_cfg = training.ppo_config("test")
    ppo_cfg.policy_hidden = (16, 8)
    ppo_cfg.policy_distribution = request.param
    (run / "config.json").write_text(
        json.dumps({"env": json.loads(to_json(env_cfg)), "ppo": json.loads(to_json(ppo_cfg)), "versions": {}})
    )
    normalizer, policy, value = training.params_template(OBS, ACT, ppo_cfg)
    k_mean, k_std, k_pol = jax.random.split(jax.random.PRNGKey(7), 3)
    normalizer = normalizer.replace(
        mean=jax.random.normal(k_mean, (OBS,)), std=0.5 + jax.random.uniform(k_std, (OBS,))
    )
    # brax's init with random biases and kernels, so no layer is trivially zero (gait_normal's mean
    # layer starts at zero) and gait_normal's means leave [-1, 1], where the export must clip
    policy = jax.tree.map(
        lambda p, k: p + (0.5 if p.ndim == 1 else 0.3) * jax.random.normal(k, p.shape),
        policy,
        _keys(policy, k_pol),
    )
    training.save_checkpoint(run, 1000, (normalizer, policy, value))
    return run


def _keys(tree, key):
    leaves, treedef = jax.tree.flatten(tree)
    return jax.tree.unflatten(treedef, list(jax.random.split(key, len(leaves))))


def test_numpy_inference_matches_the_jax_policy(run_dir, tmp_path):
    out = export.export_run(run_dir, tmp_path / "policy.npz")
    numpy_policy = export.load(out)
    policy, _, ppo_cfg, _ = training.load_policy(run_dir)
    obs = np.asarray(jax.random.normal(jax.random.PRNGKey(3), (64, OBS)) * 2.0, np.float32)
    want = np.asarray(jax.jit(policy)(obs, jax.random.PRNGKey(0))[0])
    if ppo_cfg.policy_distribution == "gait_normal":  # brax returns the raw mean; the env clips it
        assert np.abs(want).max() > 1.0
        want = np.clip(want, -1.0, 1.0)
    got = numpy_policy(obs)
    assert got.shape == (64, ACT) and got.dtype == np.float32
    assert np.std(want) > 0.1  # the actions spread over (-1, 1): a real comparison
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)  # float32 rounding, summation order
    one = numpy_policy(obs[0])  # an unbatched observation, as on the robot
    np.testing.assert_allclose(one, want[0], rtol=1e-5, atol=1e-5)
    assert numpy_policy.meta["checkpoint"] == "step_000000001000.msgpack"
    assert numpy_policy.meta["action_scale_m"] == 0.05
    with pytest.raises(ValueError, match="29"):
        numpy_policy(np.zeros(30, np.float32))


def test_inference_module_imports_only_numpy(tmp_path):
    # Load export.py by path in a fresh interpreter (as on the robot) and list the heavy modules present.
    path = Path(export.__file__)
    code = (
        "import importlib.util, sys;"
        f"spec = importlib.util.spec_from_file_location('export', {str(path)!r});"
        "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m);"
        "print(sorted(n for n in ('jax', 'brax', 'flax', 'mujoco', 'quadson_mjx') if n in sys.modules))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"
