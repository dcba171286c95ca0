"""The fine-tune that follows a run in the same command: `quadson-train ... --finetune.env.KEY=V
--finetune.ppo.KEY=V [--finetune-run-dir DIR]` trains the run, then a new run in DIR (default
RUN_DIR_finetune) from its final checkpoint with the run's configs and these overrides, as
`quadson-train --init-from RUN_DIR --run-dir DIR --env.KEY=V --ppo.KEY=V` would, in the same
process. The fine-tune's programs are compiled by a process of their own while the run trains
(training/precompile.py), so it starts without the compilation's wait.

The run's config.json records the fine-tune ("finetune": its overrides and run directory), so
`--resume RUN_DIR` finishes the run and then starts the fine-tune, or resumes it where it stopped.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax

from quadson_mjx import training

PREFIX = "--finetune."


def split_overrides(overrides: list[str]) -> tuple[list[str], list[str]]:
    """-> (the run's --env./--ppo. overrides, the fine-tune's as --env./--ppo. overrides) from the
    command line's, where the fine-tune's are spelled --finetune.env.KEY=V / --finetune.ppo.KEY=V."""
    own = [o for o in overrides if not o.startswith(PREFIX)]
    tune = ["--" + o[len(PREFIX) :] for o in overrides if o.startswith(PREFIX)]
    bad = [o for o in tune if not (o.startswith("--env.") or o.startswith("--ppo."))]
    if bad:
        raise ValueError(f"{PREFIX}KEY=V takes env. and ppo. keys: {', '.join(spelled(bad))}")
    return own, tune


def spelled(overrides: list[str]) -> list[str]:
    """The fine-tune's --env./--ppo. overrides as the command line spells them (--finetune.env.KEY=V)."""
    return [PREFIX + o[2:] for o in overrides]


def default_run_dir(run_dir: Path) -> Path:
    return Path(f"{run_dir}_finetune")


def record(overrides: list[str], run_dir: Path) -> dict:
    """config.json's entry for the fine-tune that follows a run."""
    return {"finetune": {"overrides": list(overrides), "run_dir": str(run_dir)}}


def recorded(run_dir: Path) -> tuple[list[str], Path] | None:
    """-> (overrides, run directory) of the fine-tune a run's config.json records, or None."""
    try:
        entry = json.loads((Path(run_dir) / "config.json").read_text()).get("finetune")
    except (OSError, ValueError, AttributeError):
        return None
    if not entry:
        return None
    return list(entry["overrides"]), Path(entry["run_dir"])


def finished(run_dir: Path, ppo_cfg) -> bool:
    """Whether a run has its final checkpoint (its last epoch's step)."""
    per_epoch, epochs = training.epoch_steps(ppo_cfg)
    try:
        return training.latest_checkpoint(Path(run_dir))[1] >= per_epoch * epochs
    except FileNotFoundError:
        return False


def why_not_ahead(ppo_cfg, compile_cache: bool) -> str | None:
    """Why the fine-tune's programs cannot be compiled ahead in this run, or None."""
    if not compile_cache:
        return "no compilation cache (--no-compile-cache)"
    if jax.process_count() > 1 or training.local_devices_to_use(ppo_cfg) > 1:
        return "compiling ahead takes one device of one process"
    return None


class Ahead:
    """The run's on_eval hook: after its first training epoch (its first checkpoint exists, its own
    compilation is over) starts the process that compiles the fine-tune's programs."""

    def __init__(self, run_dir: Path, overrides: list[str], start_step: int):
        self.run_dir, self.overrides, self.start_step = Path(run_dir), overrides, start_step
        self.job: training.Precompile | None = None
        self.failed: str | None = None

    def __call__(self, step: int, _record: dict) -> None:
        if self.job is None and self.failed is None and step > self.start_step:
            cache = jax.config.jax_compilation_cache_dir
            log = self.run_dir / "finetune_compile.log"
            try:
                self.job = training.Precompile(self.run_dir, self.overrides, cache, log)
            except OSError as e:  # the run trains on; the fine-tune compiles when it starts
                self.failed = f"compiling ahead could not start ({e}): the fine-tune compiles when it starts"

    def finish(self) -> str | None:
        """Waits for the compiling process -> its line, or None if it never started."""
        return self.failed if self.job is None else self.job.finish(timeout_s=600)

    def stop(self) -> None:
        if self.job is not None:
            self.job.stop()
