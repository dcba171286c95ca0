"""A fine-tune's programs compiled ahead, in a process of their own, while the run before it trains.

A two-stage recipe (a first stage, then a fine-tune from its final checkpoint under changed configs,
e.g. a finer physics step) compiles the fine-tune's training epoch only when the first stage has
ended: about 41 s of XLA compilation on one H200 for the joystick recipe's 2.5 ms fine-tune, with
the GPU idle. The compilation needs the program's shapes, not the first stage's parameters, so a
second process can build it while the first stage trains and leave it in the persistent
compilation cache; the fine-tune, started in the first stage's process after it, then loads it.

* `compile_only()`: while active, brax PPO's training epoch is lowered and compiled (into the
  persistent cache) when `ppo.train` first calls it, and `Compiled` is raised instead of running
  it. What `ppo.train` runs before (the environments' reset, the networks' initialisation, a step-0
  evaluation) runs and is cached too. One device of one process only (jax's own pmap, which brax
  uses there).
* `Precompile`: that process, started with `quadson-train --compile-only ...` (cli/train.py) and
  waited for when the fine-tune is about to start.

The cache key is the lowered program, so the fine-tune must lower it as the compiling process did:
`training.train` drops the process's traces first (jax.clear_caches) for that reason.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path

import jax

# brax PPO's jitted training epoch: ppo/train.py wraps `def training_epoch(...)` in jax.pmap
EPOCH_FUNCTION = "training_epoch"
# the compiling process's share of GPU memory: the training process beside it holds jax's default
# 75 % (XLA_PYTHON_CLIENT_MEM_FRACTION); the sensor-only joystick task's environment states are 26 kB
# each (guards.state_bytes on the CPU), 0.85 GB for 16,384 robots held twice
CHILD_MEMORY_FRACTION = "0.15"


class Compiled(Exception):  # noqa: N818 (not an error: the signal that compile_only's work is done)
    """Raised by compile_only() in place of brax's first training epoch, once compiled."""

    def __init__(self, seconds: float):
        super().__init__(f"training epoch compiled in {seconds:.1f} s")
        self.seconds = seconds


@contextlib.contextmanager
def compile_only():
    """While active, `jax.pmap(training_epoch)` as brax PPO builds it compiles on its first call
    and raises Compiled instead of running; every other pmap is jax's own."""
    original = jax.pmap

    def pmap(fun, *args, **kwargs):
        mapped = original(fun, *args, **kwargs)
        if getattr(fun, "__name__", "") != EPOCH_FUNCTION:
            return mapped

        def compile_and_stop(*call_args):
            t0 = time.monotonic()
            mapped.lower(*call_args).compile()
            raise Compiled(time.monotonic() - t0)

        return compile_and_stop

    jax.pmap = pmap
    try:
        yield
    finally:
        jax.pmap = original


class Precompile:
    """`quadson-train --compile-only --init-from SOURCE OVERRIDES` in a process of its own, its
    output in `log_path`. `finish()` waits for it and returns one line saying what it did."""

    def __init__(self, source: Path, overrides: list[str], cache_dir: str, log_path: Path):
        self.log_path = Path(log_path)
        argv = [sys.executable, "-m", "quadson_mjx.cli.train", "--compile-only", "--init-from", str(source)]
        argv += ["--compile-cache", cache_dir, *overrides]
        env = {
            **os.environ,
            "XLA_PYTHON_CLIENT_PREALLOCATE": "false",
            "XLA_PYTHON_CLIENT_MEM_FRACTION": CHILD_MEMORY_FRACTION,
        }
        with open(self.log_path, "w") as out:
            self.process = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, env=env
            )

    def finish(self, timeout_s: float | None = None) -> str:
        """Waits (up to timeout_s, then stops it) and -> one line: its last line, or why it failed."""
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.stop()
            return f"compiling ahead: still running after {timeout_s:.0f} s, stopped ({self.log_path})"
        lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        last = lines[-1] if lines else "(no output)"
        if code != 0:
            return f"compiling ahead failed (exit {code}): {last} ({self.log_path})"
        return f"compiling ahead: {last}"

    def stop(self) -> None:
        """Ends the process (on the training's own stop or failure)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
