"""A training run's configs from the command line (cli/train.py): a task or the task flags, a
preset, --env./--ppo. overrides, --init-from's source run, a resumed run's saved configs, and the
fine-tune asked for after the run (cli/finetune.py). Every bad input raises UsageError in one line."""

from __future__ import annotations

import time
from pathlib import Path

import jax

from quadson_mjx import tasks, training
from quadson_mjx.cli import finetune
from quadson_mjx.config import apply_overrides
from quadson_mjx.env_config import check_env_config
from quadson_mjx.errors import UsageError
from quadson_mjx.training.guards import check_backend

# the flags a task stands for, with their defaults
TASK_FLAG_DEFAULTS = {"robot": "quadson", "env_preset": "seed", "terrain": "flat", "gait": None}


def is_main_job(env_cfg) -> bool:
    """Whether an env config (before overrides) is the main job's: no task and no flag, or its task
    QuadsonFlat. The main job has PPO settings of its own on a GPU (training.presets.MAIN_JOB)."""
    return env_cfg.to_dict() == tasks.config_from_flags().to_dict()


def task_flags_given(args) -> list[str]:
    """The flags of a task that the command line set (--robot quadson counts, though the default)."""
    return [
        f"--{key.replace('_', '-')} {getattr(args, key)}"
        for key in TASK_FLAG_DEFAULTS
        if getattr(args, key) is not None
    ]


# the flags that set a new run's configs, in the order a refusal names them
CONFIG_FLAGS = ("task", "gait", "gait_action", "env_preset", "terrain", "robot", "preset")


def config_flags_given(args, defaults_allowed: bool) -> list[str]:
    """The CONFIG_FLAGS the command line set, as "--name"; with defaults_allowed a task flag at its
    default (TASK_FLAG_DEFAULTS: --robot quadson, --env-preset seed, --terrain flat) is not counted."""

    def given(key):
        value = getattr(args, key)
        if key == "gait_action":  # a switch
            return bool(value)
        return value is not None and not (defaults_allowed and value == TASK_FLAG_DEFAULTS.get(key))

    return [f"--{key.replace('_', '-')}" for key in CONFIG_FLAGS if given(key)]


def list_tasks() -> str:
    """One line per task: its name and the flags that spell the same config."""
    width = max(map(len, tasks.task_names()))
    lines = []
    for name, flags in tasks.TASK_FLAGS.items():
        spelled = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in flags.items() if v is not None)
        lines.append(f"{name:{width}s}  {spelled}")
    return "\n".join(lines)


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
    flags = config_flags_given(args, defaults_allowed=False)
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


def run_configs(args, overrides, primary: bool):
    """-> (env_cfg, ppo_cfg, run_dir, plan, trained): the run's configs and directory, the fine-tune
    after it ((overrides, run_dir) or None) and whether a resumed run has trained all its steps
    already (then only its fine-tune is left)."""
    plan, trained = None, False  # the fine-tune after the run: (overrides, run_dir); the run done already
    if args.init_from:
        env_cfg, ppo_cfg, run_dir = init_configs(args, overrides, primary)
    elif args.resume:
        # what would change the configs: the saved ones rule, so each is refused rather than ignored
        options = config_flags_given(args, defaults_allowed=True) + [
            name
            for name, given in (
                ("--run-dir", args.run_dir is not None),
                ("--finetune-run-dir", args.finetune_run_dir is not None),
            )
            if given
        ]
        if overrides or options or args.finetune:
            given = " ".join([*options, *overrides, *finetune.spelled(args.finetune)])
            raise UsageError(f"--resume takes the run's saved configs; remove {given}")
        run_dir = Path(args.resume)
        plan = finetune.recorded(run_dir)
        try:
            # the checks train() makes, answered as a usage error
            env_cfg, ppo_cfg = training.load_run_config(run_dir)
            check_backend(env_cfg)
            holder = training.lock_holder(run_dir) if primary else None
            if holder is not None:
                raise UsageError(f"run directory {run_dir} is in use by process {holder or '(starting)'}")
            trained = plan is not None and finetune.finished(run_dir, ppo_cfg)
            if not trained:
                training.resume_point(run_dir, ppo_cfg)
                training.check_writable_dir(run_dir)
        except (ValueError, OSError) as e:
            raise UsageError(f"cannot resume {run_dir}: {e}") from None
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
    if args.finetune:  # checked now, not after the run's minutes of training
        tune_dir = Path(args.finetune_run_dir or finetune.default_run_dir(run_dir))
        if tune_dir.resolve() == Path(run_dir).resolve():
            raise UsageError(f"the fine-tune needs a run directory of its own, not the run's {run_dir}")
        try:
            new_run_configs(env_cfg, ppo_cfg, args.finetune, tune_dir, primary)
        except (ValueError, FileExistsError) as e:
            raise UsageError(f"the fine-tune's {e}") from None
        plan = (args.finetune, tune_dir)
    elif args.finetune_run_dir and not args.resume:
        raise UsageError(
            "--finetune-run-dir is the run directory of a fine-tune: give its --finetune.env.KEY=V"
        )
    return env_cfg, ppo_cfg, run_dir, plan, trained
