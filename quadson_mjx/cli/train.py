"""Train a foot-offset policy for Quadson or Caramel with brax PPO on MJX.

    quadson-train                                             # the real job (small preset on a CPU)
    quadson-train --ppo.num_timesteps=50000000 --env.reward.forward_target=0.4
    quadson-train --preset test --run-dir runs/smoke
    quadson-train --resume runs/20261121-101500
    quadson-train --init-from results/gaits/bound --run-dir runs/bound_heavy --env.randomization.mass_scale=0.9,1.25
    quadson-train --task QuadsonGaitBound --run-dir results/gaits/bound     # a gait's recipe
    quadson-train --task CaramelCommandRough                  # seed 003's robot
    quadson-train --task QuadsonJoystickRough --finetune.env.sim_dt=0.0025 --finetune.ppo.learning_rate=0.0003
                                                              # then a fine-tune from its end (cli/finetune.py)
    quadson-train --compile-only --init-from RUN --env.sim_dt=0.0025   # a run's programs into the cache
    quadson-train @train/recipes/joystick_10min.args          # a recipe: flags read from a file
    quadson-train --list-tasks                                # the registered tasks and their flags
    quadson-train --coordinator host0:1234 --num-processes 2 --process-id 0   # on host0 (1 on host1)
    srun quadson-train --distributed                          # SLURM / Open MPI: one task per host

(`python train/ppo_mjx.py ...` runs the same command.) A task (quadson_mjx.tasks) names a robot, an
env preset, a terrain and a gait recipe; the flags --robot, --env-preset seed|command|robust (seed
000's formulation; + velocity commands; the joystick recipe with domain randomization and pushes),
--terrain and --gait G (seed 000's gait G with its recipe, env_recipes.GAIT_RECIPES: the gait's speed
as target, the contact-pattern reward, domain randomization) spell the same configs. Any config key
can be overridden with --env.KEY=VALUE or --ppo.KEY=VALUE; an unknown key is an error naming it.

A bad input (an unknown flag or key, a value out of range, a run directory that is in use, not
empty or not writable, a damaged run to resume, too many environments for the memory) and a run
that diverges (a NaN or infinite loss or parameter) end with one line on stderr and exit status 2;
Ctrl-C or SIGTERM stops at the next safe point with status 130 (twice: at once, also 130).
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

import jax

from quadson_mjx import tasks, training
from quadson_mjx.cli import finetune, train_configs
from quadson_mjx.cli.distributed import lost_peer, start_distributed
from quadson_mjx.env_config import ENV_TERRAINS
from quadson_mjx.env_recipes import GAIT_RECIPES
from quadson_mjx.errors import ArgumentParser, UsageError, one_line_errors
from quadson_mjx.robots import ROBOT_NAMES


def parse(argv):
    p = ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="overrides: --env.KEY=V --ppo.KEY=V; @FILE reads flags from FILE (train/recipes/)",
        fromfile_prefix_chars="@",
    )
    p.add_argument(
        "--preset", default=None, help="ppo preset: gpu, cpu or test (default: gpu if a GPU is present)"
    )
    p.add_argument(
        "--task",
        default=None,
        metavar="NAME",
        help="a registered task (--list-tasks); instead of --robot, --env-preset, --terrain, --gait",
    )
    p.add_argument("--list-tasks", action="store_true", help="print the registered tasks and exit")
    # default None: given or not matters next to --task and --resume (TASK_FLAG_DEFAULTS fill in)
    p.add_argument("--env-preset", default=None, choices=sorted(tasks.ENV_PRESETS), help="(default: seed)")
    p.add_argument(
        "--gait-action", action="store_true", help="let the policy also scale step length and cycle time"
    )
    p.add_argument("--terrain", default=None, choices=list(ENV_TERRAINS), help="(default: flat)")
    p.add_argument("--robot", default=None, choices=list(ROBOT_NAMES), help="the robot (default: quadson)")
    p.add_argument(
        "--gait",
        default=None,
        choices=sorted(GAIT_RECIPES),
        help="train this gait with its recipe (default: the preset's trot, no recipe)",
    )
    p.add_argument("--run-dir", default=None, help="default: runs/<date-time>")
    p.add_argument(
        "--resume", metavar="RUN_DIR", default=None, help="continue a run from its newest checkpoint"
    )
    p.add_argument(
        "--init-from",
        metavar="RUN",
        default=None,
        help="fine-tune: a new run with RUN's configs (overrides apply) starting from its newest "
        "checkpoint's parameters (or from RUN=RUN_DIR/checkpoints/step_N.msgpack)",
    )
    p.add_argument(
        "--coordinator", default=None, help="several hosts: HOST:PORT of process 0 (jax.distributed)"
    )
    p.add_argument(
        "--distributed",
        action="store_true",
        help="several hosts: take the coordinator, process count and id from the cluster (SLURM, Open MPI)",
    )
    p.add_argument(
        "--init-timeout",
        type=int,
        default=300,
        metavar="S",
        help="several hosts: seconds to wait for every process to join (default: %(default)s)",
    )
    p.add_argument(
        "--heartbeat-timeout",
        type=int,
        default=100,
        metavar="S",
        help="several hosts: seconds after which a silent process counts as dead (default: %(default)s)",
    )
    p.add_argument(
        "--compile-cache",
        default=os.environ.get("JAX_COMPILATION_CACHE_DIR", "~/.cache/quadson_mjx/xla"),
        metavar="DIR",
        help="persistent XLA compilation cache: a second run loads its programs "
        "(default: $JAX_COMPILATION_CACHE_DIR or %(default)s)",
    )
    p.add_argument("--no-compile-cache", action="store_true", help="compile everything afresh")
    p.add_argument(
        "--compile-only",
        action="store_true",
        help="compile the run's training epoch (and what runs before it) into the compilation cache "
        "and exit without training or writing a run directory; one device",
    )
    p.add_argument(
        "--finetune-run-dir",
        default=None,
        metavar="DIR",
        help="the run directory of the fine-tune that --finetune.env.KEY=V / --finetune.ppo.KEY=V ask "
        "for after this run (default: RUN_DIR_finetune)",
    )
    p.add_argument("--num-processes", type=int, default=1, help="several hosts: number of processes")
    p.add_argument("--process-id", type=int, default=0, help="several hosts: this process's index")
    args, rest = p.parse_known_args(argv)
    bad = [r for r in rest if not r.startswith(("--env.", "--ppo.", finetune.PREFIX))]
    if bad:
        p.error(f"unrecognised arguments: {' '.join(bad)}")
    try:
        rest, args.finetune = finetune.split_overrides(rest)
    except ValueError as e:
        p.error(str(e))
    return args, rest


def _terminate(signum, frame):
    """SIGTERM (a cluster scheduler's preemption, `kill`) ends the script like Ctrl-C. While
    `training.train` runs it defers both to its next safe point (log closed, state saved)."""
    raise KeyboardInterrupt(f"signal {signum}")


def exit_at_once_on_another_signal() -> None:
    """After a stopped run has closed its files, a further Ctrl-C or SIGTERM ends the process at once
    with status 130 and one line. Without it the interpreter's shutdown, which can take seconds
    (jax clears its backends and caches at exit), got the signal as a KeyboardInterrupt and printed
    a traceback from inside that clean-up."""

    def now(signum, frame):
        training.monitor.exit_at_once(signum)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, now)


@one_line_errors
def main(argv=None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # before training started (imports, configs): nothing was written
        print("\ninterrupted before training started: nothing was saved", file=sys.stderr)
        return 130


def _main(argv) -> int:
    args, overrides = parse(sys.argv[1:] if argv is None else argv)
    args.program = argv is None  # this process's own command line: it may own the process's signals
    if args.list_tasks:
        print(train_configs.list_tasks())
        return 0
    if args.task is not None and train_configs.task_flags_given(args):
        given = ", ".join(train_configs.task_flags_given(args))
        raise UsageError(f"--task {args.task} names the robot, env preset, terrain and gait: remove {given}")
    signal.signal(signal.SIGTERM, _terminate)
    if not args.no_compile_cache:
        training.enable_compilation_cache(args.compile_cache)
    if not start_distributed(args):
        return _run(args, overrides, None)
    # jax.distributed.initialize has set a SIGTERM handler of its own (a preemption notifier that
    # records the signal and lets the process run on: a scheduler's SIGTERM went unheard and the run
    # trained to its end). From here both signals are deferred to the training loop's first safe
    # point, where the other processes learn of the stop too.
    stop = training.SignalStop()
    with stop.installed():
        return _run(args, overrides, stop)


def _run(args, overrides, stop) -> int:
    """Builds or loads the run's configs and trains it, then the fine-tune it asks for, if any;
    `stop`: see training.train."""
    primary = jax.process_index() == 0  # the process that writes the run directory
    if args.resume and args.init_from:
        raise UsageError("--resume continues a run, --init-from starts a new one: give one of them")
    if args.compile_only:
        given = [f for f, on in (("--resume", args.resume), ("--run-dir", args.run_dir)) if on]
        given += finetune.spelled(args.finetune)
        if given:
            raise UsageError(
                f"--compile-only builds a new run's programs and writes no run: remove {' '.join(given)}"
            )
    env_cfg, ppo_cfg, run_dir, plan, trained = train_configs.run_configs(args, overrides, primary)
    if args.compile_only:
        return _compile_only(args, env_cfg, ppo_cfg, stop)
    ahead = None
    if plan is not None and not trained:
        reason = finetune.why_not_ahead(ppo_cfg, not args.no_compile_cache)
        when = (
            "compiled by a second process while this run trains"
            if reason is None
            else f"compiled when it starts ({reason})"
        )
        print(f"then a fine-tune in {plan[1]} ({' '.join(plan[0])}): its programs {when}")
        if reason is None and primary:
            start = training.resume_point(run_dir, ppo_cfg)[0] if args.resume else 0
            ahead = finetune.Ahead(run_dir, plan[0], start)
    try:
        if trained:
            print(f"{run_dir} has trained all its steps: on to its fine-tune")
        else:
            record = finetune.record(*plan) if plan is not None and not args.resume else None
            code = _stage(
                args,
                None if args.resume else (env_cfg, ppo_cfg),
                run_dir,
                args.init_from,
                stop,
                ahead,
                record,
            )
            if code or plan is None:
                return code
        try:
            if ahead is not None and (line := ahead.finish()):
                print(line)
        except KeyboardInterrupt:
            print(
                f"\ninterrupted before the fine-tune: continue with python train/ppo_mjx.py --resume {run_dir}"
            )
            return 130
    finally:
        if ahead is not None:
            ahead.stop()
    tune_overrides, tune_dir = plan
    if (tune_dir / "config.json").exists():  # started before: resumed
        return _stage(args, None, tune_dir, None, stop)
    env_cfg, ppo_cfg = training.load_run_config(run_dir)  # as --init-from loads them
    try:
        env_cfg, ppo_cfg, _ = train_configs.new_run_configs(
            env_cfg, ppo_cfg, tune_overrides, tune_dir, primary
        )
    except (ValueError, FileExistsError) as e:
        raise UsageError(f"the fine-tune's {e}") from None
    return _stage(args, (env_cfg, ppo_cfg), tune_dir, run_dir, stop)


def _compile_only(args, env_cfg, ppo_cfg, stop) -> int:
    """--compile-only: trains in a temporary run directory until brax's first training epoch is
    compiled (training.compile_only), then removes it."""
    reason = finetune.why_not_ahead(ppo_cfg, not args.no_compile_cache)
    if reason is not None:
        raise UsageError(f"--compile-only: {reason}")
    run_dir = Path(tempfile.mkdtemp(prefix="quadson-compile-"))
    t0 = time.monotonic()
    try:
        with training.compile_only(), training.XlaCompilations() as built:
            training.train(
                env_cfg, ppo_cfg, run_dir, init_from=args.init_from, stop=stop, progress_stream=sys.stderr
            )
    except training.Compiled:
        print(f"compiled in {time.monotonic() - t0:.0f} s: {built.summary()}")
        return 0
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)
    raise RuntimeError("--compile-only trained instead: brax's training epoch was not found (brax changed?)")


def _stage(args, configs, run_dir: Path, init_from, stop, on_eval=None, record=None) -> int:
    """Trains one run: new with configs=(env_cfg, ppo_cfg), or resumed (configs None) -> exit status."""
    primary = jax.process_index() == 0
    print(f"run directory: {run_dir}  devices: {', '.join(d.device_kind for d in jax.devices())}")
    if jax.process_count() > 1:
        print(
            f"process {jax.process_index()} of {jax.process_count()}, {jax.local_device_count()} local devices"
            + ("" if primary else ": process 0 evaluates and writes the run directory")
        )
    env_cfg, ppo_cfg = configs or (None, None)
    t0 = time.monotonic()
    try:
        _, _, metrics = training.train(
            env_cfg,
            ppo_cfg,
            run_dir,
            resume=configs is None,
            init_from=init_from,
            stop=stop,
            on_eval=on_eval,
            record=record,
        )
    except (ValueError, FileExistsError, FileNotFoundError) as e:
        # a damaged checkpoint or state file met on resume, a directory taken in the meantime
        raise UsageError(str(e)) from None
    except jax.errors.JaxRuntimeError as e:
        if jax.process_count() == 1:
            raise
        raise UsageError(lost_peer(e)) from None
    except KeyboardInterrupt:
        if args.program:
            exit_at_once_on_another_signal()
        print(f"\ninterrupted: the log {run_dir / 'train.mcap'} is closed and readable.")
        if (run_dir / "config.json").exists():
            try:
                where = f"from its checkpoint at step {training.latest_checkpoint(run_dir)[1]:,}"
            except FileNotFoundError:
                where = "from step 0 (no checkpoint yet)"
            print(f"Continue {where} with: python train/ppo_mjx.py --resume {run_dir}")
        else:
            print("Nothing was saved yet: run the same command again.")
        return 130
    print(f"\ndone in {time.monotonic() - t0:.0f} s")
    if not primary:
        return 0
    shown = ("eval/episode_reward", "eval/mean_forward_speed", "eval/avg_episode_length")
    if "eval/episode_reward" not in metrics:  # ppo.run_evals=false: the last epoch's loss
        shown = ("training/total_loss",)
    for key in shown:
        if key in metrics:
            print(f"  {key}: {metrics[key]:.3f}")
    print(
        f"  metrics log: {run_dir / 'train.mcap'}  (open in Foxglove; check: python -m quadson_mjx.mcap_check)"
    )
    print(f"  checkpoints: {run_dir / training.CHECKPOINT_DIR}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
