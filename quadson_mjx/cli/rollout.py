"""Headless rollouts of a controller to MCAP files that open in Foxglove.

    quadson-rollout --controller gait --seconds 3                    # gait alone, flat ground
    quadson-rollout --controller pid --terrain rough --envs 10 --out runs/pid_rough.mcap
    quadson-rollout --run runs/20261121-101500 --vx 0.2 --yaw-rate 0.25
    quadson-rollout --suite --out-dir runs/compare [--run RUN_DIR]   # the comparison set
(`python eval/rollout.py ...` runs the same command.)

Controllers: `gait` (zero action), `pid` (gait + seed 003's roll/pitch stabilizer), or a trained
policy from a run directory (`--run`, newest checkpoint unless `--checkpoint`). All environments
step together on the accelerator (vmap of env.step under lax.scan); the host writes the MCAP file
(topics: quadson_mjx.foxglove_mcap). Without --vx/--vy/--yaw-rate the gait's seed-speed forward walk
is commanded. An episode that ends (fall) restarts from the first state; every env is one episode
of the trial otherwise. `--suite` writes one file per controller x terrain (flat, rough) x command
(forward at the gait's seed speed; turning in place at 0.25 rad/s; the command sweep: 75 envs, each
with its own command of the grid vx in [-0.3, 0.5], vy in [-0.2, 0.2], yaw rate in [-0.8, 0.8]),
for eval/report.py. With --run, the named controllers get the policy's ground contact and
termination settings, so that falls mean the same. `--randomize` switches domain randomization
(one randomized model per env) and pushes on, for every controller.
Env config keys can be overridden with --env.KEY=VALUE (named controllers only).
`--video out.mp4` (or .gif) also renders the first environment, headless, at the control rate
(quadson_mjx.video). Check a file: python -m quadson_mjx.mcap_check FILE --rollout

A usage error exits with status 2 and one line on stderr naming the argument and the fix, before
anything is compiled or written: an impossible or non-finite number (--vx nan), a trial longer than
MAX_SECONDS (an hour), an unknown gait or --env key or a value the env config refuses, an output
that exists without --overwrite, or that lies in a missing or read-only folder, a missing run
directory. The MCAP file is written as OUT.partial and renamed to OUT when the rollout has finished
(Ctrl-C leaves OUT.partial, readable with quadson_mjx.mcap_check, says so in one line and exits
with status 130); a long rollout prints its progress after every segment.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from quadson_mjx import errors, gait, recording
from quadson_mjx import rollout as R
from quadson_mjx.commands import sweep_commands
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import ENV_TERRAINS, check_env_config, env_config, with_added_keys
from quadson_mjx.errors import UsageError
from quadson_mjx.robots import ROBOT_NAMES, TERRAINS

MAX_SECONDS = 3600.0  # longest trial [s]: an hour of one env is ~180k steps and several GB of MCAP

SUITE_YAW_RATE = 0.25  # rad/s, seed 003's turning test
# the command sweep: the joystick range of the issue, a 5 x 3 x 5 grid (75 envs, one command each)
RANDOMIZE_OVERRIDES = ["randomize=true", "pushes=true"]


def policy_ground_overrides(run_dir) -> list[str]:
    """The policy's ground contact and termination settings, for the named controllers of a suite."""
    if not run_dir:
        return []
    from quadson_mjx import training

    try:
        cfg = with_added_keys(training.load_run_config(Path(run_dir))[0])
    except ValueError as e:
        raise UsageError(f"--run {run_dir}: {errors.one_line(e)}") from None
    return [
        f"base_terrain_contact={cfg.base_terrain_contact}",
        f"joint_limits={cfg.joint_limits}",
        f"termination.base_below_terrain={cfg.termination.base_below_terrain}",
        f"termination.base_clearance_m={cfg.termination.base_clearance_m}",
    ]


def parse(argv):
    p = errors.ArgumentParser(
        prog="quadson-rollout", description=__doc__.split("\n\n")[0], epilog="overrides: --env.KEY=V"
    )
    p.add_argument("--controller", default=None, choices=R.CONTROLLERS, help="default: gait (not with --run)")
    p.add_argument("--run", default=None, help="run directory of a trained policy (instead of --controller)")
    p.add_argument("--checkpoint", default=None, help="checkpoint file of --run (default: newest)")
    p.add_argument("--terrain", default=None, choices=list(ENV_TERRAINS), help="default: flat, or the run's")
    p.add_argument("--gait", default=None, help="a gait of the robot (default: the robot's, Quadson's trot)")
    p.add_argument(
        "--robot",
        default="quadson",
        choices=list(ROBOT_NAMES),
        help="robot of --controller (a --run brings its own)",
    )
    p.add_argument("--vx", type=float, default=None, help="m/s")
    p.add_argument("--vy", type=float, default=0.0, help="m/s")
    p.add_argument("--yaw-rate", type=float, default=0.0, help="rad/s")
    p.add_argument("--envs", type=int, default=1, help="environments (episodes) in parallel")
    p.add_argument("--viz-envs", type=int, default=16, help="envs drawn in 3D (all are in /rollout/step)")
    p.add_argument("--seconds", type=float, default=10.0, help="trial length [s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--segment-steps", type=int, default=250, help="steps per compiled segment (flush)")
    p.add_argument("--out", default=None, help="MCAP file (default: runs/rollout_<controller>_<time>.mcap)")
    p.add_argument("--out-dir", default="runs/compare", help="directory of --suite files")
    p.add_argument(
        "--suite", action="store_true", help="controllers x terrains x commands for eval/report.py"
    )
    p.add_argument(
        "--randomize", action="store_true", help="domain randomization (a model per env) and pushes on"
    )
    p.add_argument("--no-sweep", action="store_true", help="--suite without the command sweep")
    p.add_argument("--video", default=None, help="also render env 0 to this .mp4 or .gif (headless)")
    p.add_argument("--video-size", default="640x480", help="video frame size WIDTHxHEIGHT [pixels]")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    args, rest = p.parse_known_args(argv)
    bad = [r for r in rest if not r.startswith("--env.")]
    if bad:
        p.error(f"unrecognised arguments: {' '.join(bad)}")
    return args, [r[len("--env.") :] for r in rest]


def check_args(args, overrides=()) -> None:
    """Raises UsageError for values the rollout cannot run with, before anything is compiled or
    written: numbers, the env configs the named controllers will run (gait, --env.KEY=V), the run
    directory, and every output path (missing or read-only folder, a folder, exists)."""
    if args.controller is not None and args.run is not None:
        raise UsageError(
            f"--controller {args.controller} and --run {args.run}: give one (--run rolls out its policy; "
            "--suite --run runs every controller and the policy)"
        )
    if args.controller is not None and args.suite:
        raise UsageError(f"--controller {args.controller}: --suite runs every controller; leave it out")
    args.controller = args.controller or "gait"
    if args.envs < 1:
        raise UsageError(f"--envs {args.envs}: need at least 1 environment (e.g. --envs 1)")
    if not args.seconds > 0:
        raise UsageError(f"--seconds {args.seconds}: the trial length must be a positive number of seconds")
    errors.check_number("--seconds", args.seconds, 0.0, MAX_SECONDS, above=True)
    for flag, value in (("--vx", args.vx), ("--vy", args.vy), ("--yaw-rate", args.yaw_rate)):
        if value is not None:
            errors.check_number(flag, value)
    if args.viz_envs < 0:
        raise UsageError(f"--viz-envs {args.viz_envs}: must be >= 0 (0 draws no environment)")
    if args.segment_steps < 1:
        raise UsageError(f"--segment-steps {args.segment_steps}: must be >= 1")
    if args.run is not None and not (Path(args.run) / "config.json").is_file():
        raise UsageError(f"--run {args.run}: not a training run directory (no config.json in it)")
    if args.checkpoint is not None and args.run is None:
        raise UsageError(f"--checkpoint {args.checkpoint}: needs --run (the run directory it belongs to)")
    if args.checkpoint is not None and not Path(args.checkpoint).is_file():
        raise UsageError(f"--checkpoint {args.checkpoint}: no such file")
    if args.run is not None and overrides:
        raise UsageError(
            f"--env.{overrides[0]}: --env overrides are not allowed with --run (the policy's env config is used)"
        )
    if args.video is not None:
        if Path(args.video).suffix.lower() not in (".mp4", ".gif"):
            raise UsageError(f"--video {args.video}: the file name must end in .mp4 or .gif")
        if args.suite:
            raise UsageError("--video renders one rollout: leave it out of --suite")
        video_size(args.video_size)
    if args.suite:
        named = [*policy_ground_overrides(args.run), *overrides]
        for terrain in TERRAINS:
            named_env_config(args, named, terrain)
    elif args.run is None:
        named_env_config(args, overrides, args.terrain)
    check_outputs(args)


def default_out(args) -> Path:
    name = "policy" if args.run else args.controller
    return Path(f"runs/rollout_{name}_{time.strftime('%Y%m%d-%H%M%S')}.mcap")


def check_outputs(args) -> None:
    """Every file the command will write: its folder exists (--out-dir and the default runs/ are
    created) and is writable, it is not a folder, and it does not exist unless --overwrite."""
    if args.suite:
        folder, what = Path(args.out_dir), "--out-dir"
    elif args.out is None:
        args.out = str(default_out(args))
        folder, what = Path(args.out).parent, "the default output folder"
    else:
        folder, what = None, None
    if folder is not None:
        errors.make_folder(folder, what)
    outputs = [("--out", p) for p in suite_outputs(args)] if args.suite else [("--out", Path(args.out))]
    outputs += [("--video", Path(args.video))] if args.video else []
    for flag, out in outputs:
        errors.check_writable(out, flag)
        if out.exists() and not args.overwrite:
            raise UsageError(f"{out} exists: pass --overwrite to replace it, or choose another name")


def named_env_config(args, overrides, terrain):
    """The env config of a named controller (gait, pid): the robot's, --gait, the terrain, then the
    overrides; UsageError naming the key for an unknown gait, key or a value out of range."""
    extra = RANDOMIZE_OVERRIDES if args.randomize else []
    try:
        cfg = env_config(terrain=terrain or "flat", gait=args.gait, robot=args.robot)
    except ValueError as e:
        raise UsageError(f"--gait {args.gait}: {errors.one_line(e)}") from None
    try:
        cfg = apply_overrides(cfg, [*overrides, *extra], prefix="env.")
        check_env_config(cfg)
    except ValueError as e:
        raise UsageError(errors.one_line(e)) from None
    return cfg


def video_size(text: str) -> tuple[int, int]:
    """ "640x480" -> (640, 480); UsageError unless two even numbers of pixels in [16, 4096]."""
    parts = text.lower().split("x")
    if len(parts) == 2 and all(p.isdigit() and 16 <= int(p) <= 4096 and int(p) % 2 == 0 for p in parts):
        return int(parts[0]), int(parts[1])
    raise UsageError(f"--video-size {text}: give WIDTHxHEIGHT in even numbers of pixels, e.g. 640x480")


def suite_tasks(args) -> dict:
    """task name -> command of the suite: None (the gait's forward walk), (3,), or (75, 3) the sweep."""
    return {
        "forward": None,
        "turn": (0.0, 0.0, SUITE_YAW_RATE),
        **({} if args.no_sweep else {"sweep": sweep_commands()}),
    }


def suite_path(args, name: str, terrain: str, task: str) -> Path:
    tag = "_randomized" if args.randomize else ""
    return Path(args.out_dir) / f"{name}_{terrain}{tag}_{task}.mcap"


def suite_outputs(args) -> list[Path]:
    names = [*R.CONTROLLERS, *(["policy"] if args.run else [])]
    return [suite_path(args, n, ter, task) for n in names for ter in TERRAINS for task in suite_tasks(args)]


def build(args, overrides, controller_name: str, terrain: str | None):
    """-> (env, controller, metadata) for a named controller or a run directory's policy."""
    if controller_name == "policy":
        from quadson_mjx import training

        try:
            policy, env_cfg, _, _ = training.load_policy(Path(args.run), args.checkpoint)
        except ValueError as e:
            raise UsageError(f"--run {args.run}: {errors.one_line(e)}") from None
        if overrides:
            raise UsageError("--env overrides are not allowed with --run: the policy's env config is used")
        env_cfg = with_added_keys(env_cfg)
        if terrain and terrain != env_cfg.terrain:
            env_cfg = apply_overrides(env_cfg, [f"terrain={terrain}"])
        if args.randomize:
            env_cfg = apply_overrides(env_cfg, RANDOMIZE_OVERRIDES)
        env = LocomotionEnv(env_cfg)
        ckpt = args.checkpoint or str(training.latest_checkpoint(Path(args.run))[0])
        return env, R.policy_controller(policy), {"run_dir": str(args.run), "checkpoint": ckpt}
    env = LocomotionEnv(named_env_config(args, overrides, terrain))
    return env, R.named_controller(env, controller_name), {"run_dir": "", "checkpoint": ""}


def one(args, overrides, controller_name, terrain, command, out: Path) -> None:
    env, controller, meta = build(args, overrides, controller_name, terrain)
    if command is None:
        seed_speed = float(gait.seed_speed(env.gait_params))
        vx = seed_speed if args.vx is None else args.vx
        command = (vx, args.vy, args.yaw_rate)
    n_steps = round(args.seconds / env.ctrl_dt)
    if n_steps < 1:
        raise UsageError(f"--seconds {args.seconds}: shorter than one control step ({env.ctrl_dt} s)")
    n_envs = len(command) if np.ndim(command) == 2 else args.envs
    t0 = time.monotonic()
    video = None
    if args.video:
        from quadson_mjx import video as V

        size = video_size(args.video_size)
        video = V.RolloutVideo(args.video, env.mj_model, env.ctrl_dt, overwrite=args.overwrite, size=size)
    # written under a temporary name, renamed when complete: OUT is never a half-written file
    partial = out.with_name(out.name + ".partial")
    progress = Progress(partial, n_steps, env.ctrl_dt, args.segment_steps, video)
    try:
        summary = recording.record(
            partial,
            env,
            controller,
            jax.random.PRNGKey(args.seed),
            n_envs,
            n_steps,
            command=command,
            segment_steps=args.segment_steps,
            metadata={**meta, "seed": args.seed, "trial_s": n_steps * env.ctrl_dt},
            overwrite=True,  # the partial file of an earlier, interrupted run
            viz_envs=args.viz_envs,
            randomize=args.randomize,
            on_segment=progress,
        )
    except KeyboardInterrupt:
        if video is not None:
            video.abort()
        where = (
            f": the steps written so far are in {partial} "
            f"(python -m quadson_mjx.mcap_check {partial} --recover {out})"
            if partial.exists()
            else ""
        )
        print(f"interrupted{where}", file=sys.stderr)
        raise
    except BaseException:
        if video is not None:
            video.abort()
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, out)
    if video is not None:
        video.close()
    shown = "sweep" if np.ndim(command) == 2 else tuple(round(c, 3) for c in command)
    print(
        f"{out}: {controller.name}, {env.config.terrain}, command {shown}, "
        f"{n_envs} env(s) x {n_steps} steps, {summary['falls']} fall(s), {summary['off_field']} at the edge, "
        f"{summary['nan_resets']} non-finite reset(s), {time.monotonic() - t0:.0f} s"
    )


class Progress:
    """on_segment of recording.record: renders the video's frames and, when the trial has more
    than one segment, prints how far it is (simulated seconds, MCAP size, wall time) after each."""

    def __init__(self, path: Path, n_steps: int, ctrl_dt: float, segment_steps: int, video=None):
        self.path, self.n_steps, self.ctrl_dt, self.video = path, n_steps, ctrl_dt, video
        self.show = n_steps > segment_steps
        self.t0 = time.monotonic()

    def __call__(self, start: int, traj) -> None:
        if self.video is not None:
            self.video.add_segment(start, traj)
        if self.show:
            done = start + traj.done.shape[0]
            size = self.path.stat().st_size / 1e6 if self.path.exists() else 0.0
            print(
                f"  {done * self.ctrl_dt:.1f} / {self.n_steps * self.ctrl_dt:.1f} s simulated, "
                f"{size:.1f} MB written, {time.monotonic() - self.t0:.0f} s",
                flush=True,
            )


EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a Ctrl-C


@errors.one_line_errors
def main(argv=None) -> int:
    args, overrides = parse(sys.argv[1:] if argv is None else argv)
    check_args(args, overrides)
    try:
        return _main(args, overrides)
    except KeyboardInterrupt:  # one() has said where the steps written so far are
        return EXIT_INTERRUPTED


def _main(args, overrides) -> int:
    default_name = "policy" if args.run else args.controller
    if not args.suite:
        command = None if args.vx is None else (args.vx, args.vy, args.yaw_rate)
        if command is None and (args.vy or args.yaw_rate):
            command = (0.0, args.vy, args.yaw_rate)
        one(args, overrides, default_name, args.terrain, command, Path(args.out))
        return 0
    names = [*R.CONTROLLERS, *(["policy"] if args.run else [])]
    out_dir = Path(args.out_dir)
    tasks = suite_tasks(args)
    named_overrides = [*policy_ground_overrides(args.run), *overrides]
    for name in names:
        for terrain in TERRAINS:
            for task, command in tasks.items():
                over = overrides if name == "policy" else named_overrides  # a policy keeps its own config
                one(args, over, name, terrain, command, suite_path(args, name, terrain, task))
    print(f"compare: python eval/report.py {out_dir}/*.mcap --out-dir {out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
