"""Train a foot-offset policy for Quadson or Caramel with brax PPO on MJX.

    quadson-train                                             # the real job (small preset on a CPU)
    quadson-train --ppo.num_timesteps=50000000 --env.reward.forward_target=0.4
    quadson-train --preset test --run-dir runs/smoke
    quadson-train --resume runs/20261121-101500
    quadson-train --init-from results/gaits/bound --run-dir runs/bound_heavy --env.randomization.mass_scale=0.9,1.25
    quadson-train --task QuadsonGaitBound --run-dir results/gaits/bound     # a gait's recipe
    quadson-train --task CaramelCommandRough                  # seed 003's robot
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
import signal
import sys
import time
from pathlib import Path

import jax

from quadson_mjx import tasks, training
from quadson_mjx.cli.distributed import lost_peer, start_distributed
from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import ENV_TERRAINS, check_env_config
from quadson_mjx.env_recipes import GAIT_RECIPES
from quadson_mjx.errors import ArgumentParser, UsageError, one_line_errors
from quadson_mjx.robots import ROBOT_NAMES
from quadson_mjx.training.guards import check_backend

# the flags a task stands for, with their defaults
TASK_FLAG_DEFAULTS = {"robot": "quadson", "env_preset": "seed", "terrain": "flat", "gait": None}


def is_main_job(env_cfg) -> bool:
    """Whether an env config (before overrides) is the main job's: no task and no flag, or its task
    QuadsonFlat. The main job has PPO settings of its own on a GPU (training.presets.MAIN_JOB)."""
    return env_cfg.to_dict() == tasks.config_from_flags().to_dict()


def parse(argv):
    p = ArgumentParser(description=__doc__.split("\n\n")[0], epilog="overrides: --env.KEY=V --ppo.KEY=V")
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
    p.add_argument("--num-processes", type=int, default=1, help="several hosts: number of processes")
    p.add_argument("--process-id", type=int, default=0, help="several hosts: this process's index")
    args, rest = p.parse_known_args(argv)
    bad = [r for r in rest if not (r.startswith("--env.") or r.startswith("--ppo."))]
    if bad:
        p.error(f"unrecognised arguments: {' '.join(bad)}")
    return args, rest


def task_flags_given(args) -> list[str]:
    """The flags of a task that the command line set (--robot quadson counts, though the default)."""
    return [
        f"--{key.replace('_', '-')} {getattr(args, key)}"
        for key in TASK_FLAG_DEFAULTS
        if getattr(args, key) is not None
    ]


def list_tasks() -> str:
    """One line per task: its name and the flags that spell the same config."""
    width = max(map(len, tasks.task_names()))
    lines = []
    for name, flags in tasks.TASK_FLAGS.items():
        spelled = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in flags.items() if v is not None)
        lines.append(f"{name:{width}s}  {spelled}")
    return "\n".join(lines)


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


def new_run_configs(env_cfg, ppo_cfg, overrides, run_dir, primary: bool):
    """A new run's configs: the --env./--ppo. overrides applied and checked, and its run directory
    (default runs/<date-time>; on the primary process checked to be new) -> (env_cfg, ppo_cfg,
    run_dir). Raises ValueError (or OSError) naming what is wrong."""
    env_over = [o[len("--env.") :] for o in overrides if o.startswith("--env.")]
    ppo_over = [o[len("--ppo.") :] for o in overrides if o.startswith("--ppo.")]
    env_cfg = apply_overrides(env_cfg, env_over, prefix="env.")
    ppo_cfg = apply_overrides(ppo_cfg, ppo_over, prefix="ppo.")
    check_env_config(env_cfg)
    training.check_ppo_config(ppo_cfg)
    check_backend(env_cfg)
    run_dir = Path(run_dir or f"runs/{time.strftime('%Y%m%d-%H%M%S')}")
    if primary:
        training.check_new_run_dir(run_dir)
    return env_cfg, ppo_cfg, run_dir


def init_configs(args, overrides, primary: bool):
    """--init-from: the source run's configs with the overrides -> (env_cfg, ppo_cfg, run_dir)."""
    flags = [
        name
        for name, given in (
            ("--task", args.task is not None),
            ("--gait", args.gait is not None),
            ("--gait-action", args.gait_action),
            ("--env-preset", args.env_preset is not None),
            ("--terrain", args.terrain is not None),
            ("--robot", args.robot is not None),
            ("--preset", args.preset is not None),
        )
        if given
    ]
    if flags:
        given = " ".join(flags)
        raise UsageError(
            f"--init-from takes the source run's configs (change them with --env.KEY=V): remove {given}"
        )
    try:
        source, _, _ = training.init_point(Path(args.init_from))
        env_cfg, ppo_cfg = training.load_run_config(source)
        env_cfg, ppo_cfg, run_dir = new_run_configs(env_cfg, ppo_cfg, overrides, args.run_dir, primary)
    except (ValueError, OSError) as e:
        raise UsageError(f"--init-from: {e}") from None
    return env_cfg, ppo_cfg, run_dir


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
        print(list_tasks())
        return 0
    if args.task is not None and task_flags_given(args):
        given = ", ".join(task_flags_given(args))
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
    """Builds or loads the run's configs and trains; `stop`: see training.train."""
    primary = jax.process_index() == 0  # the process that writes the run directory
    if args.resume and args.init_from:
        raise UsageError("--resume continues a run, --init-from starts a new one: give one of them")
    if args.init_from:
        env_cfg, ppo_cfg, run_dir = init_configs(args, overrides, primary)
    elif args.resume:
        # what would change the configs: the saved ones rule, so each is refused rather than ignored
        options = [
            name
            for name, given in (
                ("--task", args.task is not None),
                ("--gait", args.gait is not None),
                ("--gait-action", args.gait_action),
                ("--env-preset", args.env_preset not in (None, "seed")),
                ("--terrain", args.terrain not in (None, "flat")),
                ("--robot", args.robot not in (None, "quadson")),
                ("--preset", args.preset is not None),
                ("--run-dir", args.run_dir is not None),
            )
            if given
        ]
        if overrides or options:
            given = " ".join([*options, *overrides])
            raise UsageError(f"--resume takes the run's saved configs; remove {given}")
        run_dir = Path(args.resume)
        try:
            # the checks train() makes, answered as a usage error
            env_cfg, ppo_cfg = training.load_run_config(run_dir)
            check_backend(env_cfg)
            holder = training.lock_holder(run_dir) if primary else None
            if holder is not None:
                raise UsageError(f"run directory {run_dir} is in use by process {holder or '(starting)'}")
            training.resume_point(run_dir, ppo_cfg)
            training.check_writable_dir(run_dir)
        except (ValueError, OSError) as e:
            raise UsageError(f"cannot resume {run_dir}: {e}") from None
        env_cfg = ppo_cfg = None
    else:
        on_gpu = jax.default_backend() == "gpu"
        preset = args.preset or ("gpu" if on_gpu else "cpu")
        if not on_gpu and args.preset is None:
            print("No GPU found: running the small 'cpu' preset (minutes). Use a GPU for the real job.")
        try:
            if args.task is not None:
                env_cfg = tasks.make_task_config(args.task)
                env_cfg.gait_action = args.gait_action
            else:
                flags = {k: getattr(args, k) for k in TASK_FLAG_DEFAULTS}
                flags = {k: d if flags[k] is None else flags[k] for k, d in TASK_FLAG_DEFAULTS.items()}
                env_cfg = tasks.config_from_flags(**flags, gait_action=args.gait_action)
            main = is_main_job(env_cfg)
            if main and preset == "gpu" and not any(o.startswith("--env.impl=") for o in overrides):
                env_cfg, line = training.main_job_env(env_cfg, jax.device_count())
                print(line)
            env_cfg, ppo_cfg, run_dir = new_run_configs(
                env_cfg, training.ppo_config(preset, main), overrides, args.run_dir, primary
            )
        except (ValueError, FileExistsError) as e:
            raise UsageError(str(e)) from None
    print(f"run directory: {run_dir}  devices: {', '.join(d.device_kind for d in jax.devices())}")
    if jax.process_count() > 1:
        print(
            f"process {jax.process_index()} of {jax.process_count()}, {jax.local_device_count()} local devices"
            + ("" if primary else ": process 0 evaluates and writes the run directory")
        )
    t0 = time.monotonic()
    try:
        _, _, metrics = training.train(
            env_cfg, ppo_cfg, run_dir, resume=bool(args.resume), init_from=args.init_from, stop=stop
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
