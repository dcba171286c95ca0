"""Where the train command's start-up goes before the trainer's clock: runs `python
train/ppo_mjx.py ARGS` in this process with a timestamp printed at each stage (jax imported, its
backend started, the train command imported, the run's configs built, each environment built, the
memory check, the trainer's progress clock created), seconds since this script started.

    JAX_LOG_COMPILES=1 timeout 75 python benchmarks/startup_stages.py --run-dir /tmp/s --compile-cache /tmp/c

With JAX_LOG_COMPILES=1, jax logs every compilation, so the ones before the clock can be counted.
Stop it after the first progress line (timeout): what follows is the training itself.
"""

import sys
import time

T0 = time.monotonic()


def mark(what: str) -> None:
    print(f"[stage] {time.monotonic() - T0:6.2f} s {what}", flush=True)


def timed(owner, name: str, label: str) -> None:
    """Replaces owner.name by a wrapper that marks its end and its duration."""
    inner = getattr(owner, name)

    def wrapper(*a, **k):
        t = time.monotonic()
        out = inner(*a, **k)
        mark(f"{label} ({time.monotonic() - t:.2f} s)")
        return out

    setattr(owner, name, wrapper)


def main(argv: list[str]) -> int:
    import jax

    mark("jax imported")
    jax.devices()
    mark("jax backend started")
    from quadson_mjx.cli import train, train_configs

    mark("train command imported")
    import quadson_mjx.envs as envs
    import quadson_mjx.training.loop as loop
    import quadson_mjx.training.monitor as monitor

    mark("environments, brax and the training loop imported")
    timed(train_configs, "new_run_configs", "configs built")
    timed(envs, "make_env", "environment built")
    timed(loop.guards, "check_memory", "memory checked")
    progress_init = monitor.Progress.__init__

    def progress(self, *a, **k):
        mark("the trainer's clock starts")
        progress_init(self, *a, **k)

    monitor.Progress.__init__ = progress
    loop.Progress = monitor.Progress
    return train.main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
