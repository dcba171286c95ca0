"""warp_build against the step it prepares: in a fresh process with an empty Warp kernel cache,
the modules it builds are the ones the env's first Warp step (jitted and vmapped, as training runs
it) needs, so that step compiles none of MuJoCo Warp's modules itself."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# MJX's own foreign-call module, built by the first call, outside MuJoCo Warp's step (0.5 s on one
# H100, benchmarks/results/time_to_policy_h100_warp_main_warp_first.log): not listed by warp_build.
MJX_FFI_MODULE = "mujoco.mjx.warp.ffi"

CHILD = r"""
import json, os, sys
os.environ["WARP_CACHE_PATH"] = sys.argv[1]
import jax
import jax.numpy as jnp
from warp._src import context
from quadson_mjx import warp_build
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config

env = LocomotionEnv(apply_overrides(env_config(terrain="flat"), ["impl=warp", "warp_max_worlds=2"]))
build = warp_build.start(env.mj_model, env.warp_buffers, workers=2)
build.wait()
compiled = []
original = context.Module._compile

def counted(self, *args, **kwargs):
    built = original(self, *args, **kwargs)
    if built:
        compiled.append(self.name)
    return built

context.Module._compile = counted
s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 2))
s = jax.jit(jax.vmap(env.step))(s, jnp.zeros((2, env.action_size)))
jax.block_until_ready(s.obs)
print("RESULT " + json.dumps({"modules": build.modules, "errors": build.errors, "compiled_after": compiled}))
"""


@pytest.mark.slow
def test_prebuilt_modules_are_the_ones_the_first_step_needs(tmp_path):
    res = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path / "warp_cache")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    line = [x for x in res.stdout.splitlines() if x.startswith("RESULT ")][-1]
    out = json.loads(line[len("RESULT ") :])
    # The flat model's step on the CPU launches about 33 modules (smooth, passive, forward, the
    # solver's and the collision's generated kernels).
    assert out["modules"] >= 20
    assert out["errors"] == []
    assert set(out["compiled_after"]) <= {MJX_FFI_MODULE}, out["compiled_after"]
