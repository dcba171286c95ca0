"""Seed 000's five gaits: open loop, gait + PID and gait + policy, over many randomized episodes.

    quadson-gaits --runs results/gaits                 # every gait with a run in results/gaits/<gait>
    quadson-gaits --gaits walk,bound --envs 10 --seconds 5 --json runs/gaits.json
(`python eval/gaits.py ...` runs the same command.)

For each gait, the controllers `gait` (open loop), `pid` (gait + seed 003's roll/pitch stabilizer)
and, where RUNS/<gait> (or --run GAIT=DIR) holds a trained run, `policy` each walk --envs episodes
of --seconds (seed 000's 18.75 s by default) at the gait's own forward speed, on flat ground, one
randomized model per episode (friction, masses, servo strength, latency, centre of mass), in the
gait recipe's env config (env_config(gait=G, gait_recipe=True) with the training's feet-only
contact; a run's own config for its policy). Reported per row (quadson_mjx.gait_eval): falls, mean speed against the command,
roll/pitch std, and how often the feet's contact (from contact forces) matches the gait's phase table.
--randomization KEY=VALUE (repeatable) sets one range of the randomized model for every row
(`randomization.KEY`: friction, mass_scale, motor_strength, base_com_shift_m, latency_s; a range
LOW,HIGH, or one corner as VALUE,VALUE), to evaluate a policy on part of its training range.
--physics KEY=VALUE (repeatable; sim_dt, solver_iterations) integrates every row otherwise than
trained: a finer timestep or more solver iterations, nearer MuJoCo's converged physics.
Prints a markdown table; --json writes every number (whole or not at all).
A bad input (an unknown gait or controller, an unknown or out-of-range --randomization, a non-finite or impossible time, an episode longer than
MAX_SECONDS, a --json path that exists or lies in a missing or read-only folder, a run in RUNS/<gait>
that does not load or trained another gait) exits with status 2 and one line on stderr, before any
episode runs.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax

from quadson_mjx import errors, gait_eval
from quadson_mjx import rollout as R
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import SEED_EPISODE_S, check_env_config, env_config, with_added_keys
from quadson_mjx.env_recipes import GAIT_RECIPES
from quadson_mjx.errors import UsageError
from quadson_mjx.tasks import FAST_PHYSICS

FIVE = ("walk", "trot", "pace", "bound", "gallop")
# the training presets' physics, for gaits without a run
TRAINING_PHYSICS = FAST_PHYSICS
MAX_SECONDS = 3600.0  # longest episode [s]


def parse(argv):
    p = errors.ArgumentParser(prog="quadson-gaits", description=__doc__.split("\n\n")[0])
    p.add_argument("--gaits", default=",".join(FIVE), help="comma-separated (default: all five)")
    p.add_argument("--runs", default=None, help="directory with one trained run per gait: RUNS/<gait>")
    p.add_argument(
        "--run",
        action="append",
        default=[],
        metavar="GAIT=DIR",
        help="one gait's run, instead of RUNS/<gait>; repeatable",
    )
    p.add_argument("--envs", type=int, default=100, help="episodes per row")
    p.add_argument("--seconds", type=float, default=SEED_EPISODE_S, help="episode length [s]")
    p.add_argument("--settle-s", type=float, default=1.0, help="start of the measured window [s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="write all results here")
    p.add_argument("--controllers", default="gait,pid,policy", help="comma-separated rows to run")
    p.add_argument(
        "--randomization",
        action="append",
        default=[],
        metavar="KEY=LOW,HIGH",
        help="a range of the randomized model for every row (randomization.KEY), repeatable",
    )
    p.add_argument(
        "--physics",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"integrate every row otherwise than trained, repeatable ({', '.join(PHYSICS_KEYS)})",
    )
    p.add_argument(
        "--footfalls",
        type=float,
        nargs=2,
        metavar=("START_S", "END_S"),
        default=None,
        help="print environment 0's footfall diagram over this window of each row",
    )
    args = p.parse_args(argv)
    gaits = [g for g in args.gaits.split(",") if g]
    bad = [g for g in gaits if g not in GAIT_RECIPES]
    if bad or not gaits:
        p.error(f"--gaits: unknown {bad}; choose from {sorted(GAIT_RECIPES)}")
    errors.check_number("--seconds", args.seconds, 0.0, MAX_SECONDS, above=True)
    errors.check_number("--settle-s", args.settle_s, 0.0)
    if args.envs < 1 or not args.seconds > args.settle_s >= 0:
        p.error("need --envs >= 1 and --seconds > --settle-s >= 0")
    if args.runs and not Path(args.runs).is_dir():
        p.error(f"--runs {args.runs} is not a directory")
    args.run_dirs = {}
    for item in args.run:
        gait, eq, run = item.partition("=")
        if not eq or gait not in GAIT_RECIPES or gait in args.run_dirs:
            p.error(f"--run {item}: GAIT=DIR, once per gait, GAIT one of {sorted(GAIT_RECIPES)}")
        if not Path(run).is_dir():
            p.error(f"--run {item}: {run} is not a directory")
        args.run_dirs[gait] = Path(run)
    controllers = [c for c in args.controllers.split(",") if c]
    if not controllers or any(c not in ("gait", "pid", "policy") for c in controllers):
        p.error(f"--controllers takes gait, pid, policy; got {args.controllers!r}")
    args.controllers = controllers
    if args.footfalls and not 0 <= args.footfalls[0] < args.footfalls[1] <= args.seconds:
        p.error("--footfalls needs 0 <= START_S < END_S <= --seconds")
    if args.json and Path(args.json).exists():
        p.error(f"--json {args.json} exists; give a new path")
    if args.json:
        errors.check_writable(args.json, "--json")
    args.randomization = [f"randomization.{r}" for r in args.randomization]
    bad = [f for f in args.physics if f.partition("=")[0] not in PHYSICS_KEYS]
    if bad:
        raise UsageError(f"--physics {bad[0]}: the physics keys are {', '.join(PHYSICS_KEYS)}")
    for flag, overrides in (("--randomization", args.randomization), ("--physics", args.physics)):
        try:  # every override checked on the recipe's config before any run loads
            check_env_config(
                apply_overrides(env_config(gait=gaits[0], gait_recipe=True), overrides, prefix="env.")
            )
        except ValueError as e:
            raise UsageError(f"{flag}: {errors.one_line(e)}") from None
    for g in gaits:
        check_run(run_of(args, g), g, "--run" if g in args.run_dirs else "--runs")
    return args, gaits


# env keys that --physics may set: how the rows are integrated, not what the robot or the task is
PHYSICS_KEYS = ("sim_dt", "solver_iterations")


def run_of(args, gait: str) -> Path | None:
    """The gait's --run, else RUNS/<gait> if it is a directory, else None (no trained run)."""
    if gait in args.run_dirs:
        return args.run_dirs[gait]
    run = Path(args.runs) / gait if args.runs else None
    return run if run is not None and run.is_dir() else None


def check_run(run_dir: Path | None, gait: str, flag: str = "--runs") -> None:
    """UsageError (naming `flag`) unless run_dir (if any) is a training run of `gait` whose config
    loads."""
    if run_dir is None:
        return
    from quadson_mjx import training

    if not (run_dir / "config.json").is_file():
        raise UsageError(f"{flag}: {run_dir} is not a training run directory (no config.json in it)")
    try:
        cfg = with_added_keys(training.load_run_config(run_dir)[0])
    except ValueError as e:
        raise UsageError(f"{flag}: {run_dir}: {errors.one_line(e)}") from None
    if cfg.gait != gait:
        raise UsageError(f"{flag}: {run_dir} trained the gait {cfg.gait!r}, not {gait!r}")


def rows_for_gait(gait: str, run_dir: Path | None, args) -> list[dict]:
    """The gait's rows: gait, pid and (with a run) policy, in the run's env config if there is one."""
    from quadson_mjx import training

    policy = None
    if run_dir is not None:
        try:
            policy, env_cfg, _, _ = training.load_policy(run_dir)
        except ValueError as e:
            raise UsageError(f"--runs: {run_dir}: {errors.one_line(e)}") from None
        env_cfg = with_added_keys(env_cfg)
        if env_cfg.gait != gait:
            raise ValueError(f"{run_dir} trained the gait {env_cfg.gait!r}, not {gait!r}")
        if env_cfg.command_tracking or not env_cfg.randomize:
            env_cfg = apply_overrides(env_cfg, ["command_tracking=false", "randomize=true"])
    else:
        env_cfg = env_config(gait=gait, gait_recipe=True, **TRAINING_PHYSICS)
    if args.randomization or args.physics:
        env_cfg = apply_overrides(env_cfg, args.randomization + args.physics, prefix="env.")
    env = LocomotionEnv(env_cfg)
    controllers = [c for c in (R.gait_only(env), R.pid_stabilizer(env)) if c.name in args.controllers]
    if policy is not None and "policy" in args.controllers:
        controllers.append(R.policy_controller(policy))
    rows = []
    for controller in controllers:
        i = ("gait", "pid", "policy").index(controller.name)  # the same draws whichever rows run
        t0 = time.time()
        rng = jax.random.fold_in(jax.random.PRNGKey(args.seed), i)
        stats = gait_eval.evaluate(
            env, controller, rng, args.envs, args.seconds, args.settle_s, footfall_s=args.footfalls
        )
        rows.append({"gait": gait, "controller": controller.name, "run_dir": str(run_dir or ""), **stats})
        for line in stats.get("footfalls", []):
            print(f"  {line}")
        print(
            f"{gait} {controller.name}: {stats['falls']}/{stats['episodes']} falls, {time.time() - t0:.0f} s",
            flush=True,
        )
    return rows


def _f(v: float, fmt: str) -> str:
    """A number, or a dash where nothing was measured (every episode fell before the window)."""
    return "-" if v != v else format(v, fmt)


def markdown(rows: list[dict]) -> str:
    head = (
        "| Gait | Controller | Falls | Speed / command [m/s] | Roll std [deg] | Pitch std [deg] "
        "| Pattern match (exact / +-1 step) | Feet agree | Duty measured (table) |\n"
        "|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        duty = " ".join(f"{d:.2f}" for d in r["duty_measured"])
        lines.append(
            f"| {r['gait']} | {r['controller']} | {r['falls']}/{r['episodes']} "
            f"| {_f(r['speed_mean'], '.3f')} +- {_f(r['speed_std'], '.3f')} / {r['command_vx']:.3f} "
            f"({_f(r['speed_ratio'], '.2f')}) | {_f(r['roll_std_deg'], '.2f')} | {_f(r['pitch_std_deg'], '.2f')} "
            f"| {_f(100 * r['pattern_match'], '.1f')} % / {_f(100 * r['pattern_match_1step'], '.1f')} % "
            f"| {_f(100 * r['foot_agreement'], '.1f')} % | {duty or '-'} ({r['duty_table']:.2f}) |"
        )
    return "\n".join(lines)


@errors.one_line_errors
def main(argv=None) -> int:
    args, gaits = parse(argv)
    rows = []
    for g in gaits:
        rows.extend(rows_for_gait(g, run_of(args, g), args))
    print(markdown(rows))
    if args.json:
        meta = {"envs": args.envs, "seconds": args.seconds, "settle_s": args.settle_s, "seed": args.seed}
        meta["randomization"] = [r[len("randomization.") :] for r in args.randomization]
        meta["physics"] = list(args.physics)
        errors.write_text_atomic(args.json, json.dumps({"settings": meta, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
