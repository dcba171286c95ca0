"""Sim-to-sim: exported policies closed loop through the deploy loop against MuJoCo C
(quadson_mjx.sim2sim): falls, tracking RMS and invalid-IK steps per command, a table, a JSON summary,
MCAP files for Foxglove and, on request, videos.

    quadson-sim2sim /tmp/old.onnx --velocity-source true,zero,command --seeds 3 --out runs/s2s
    quadson-sim2sim new.onnx old.onnx --terrain stones --randomize --pushes --latency-ms 60

    quadson-sim2sim walk.onnx bound.onnx --commands gait --terrain flat   # gait policies
    quadson-sim2sim tiles.onnx --tiles slope_up,stairs_up --levels 3 6 7 --seeds 16   # tiled ground
(`python eval/sim2sim.py ...` runs the same command.)

Each policy runs every command of --commands (the 13-command sweep, each for --seconds; the step
schedule vx 0 -> 0.4 -> 0 -> -0.2 m/s in four segments of --seconds / 4; "gait": forward at the
policy's gait speed for --seconds, the only set of a policy trained without commands) on each
terrain, with --seeds seeds (heading, sensor biases and noise, randomized model, pushes). Every run
reports falls, tracking RMS and the feet's contact pattern against the gait's phase table. A policy
that observes the base velocity gets it from each --velocity-source; a sensor-only policy runs once.
--randomize draws each run's model from the policy's trained ranges; --randomization KEY=LOW,HIGH
replaces one of them for every policy (to compare policies trained on different ranges). Writes
OUT/summary.json (the command line, the plant's settings, one row per condition, one per run),
OUT/mcap/*.mcap (the first seed's runs; --mcap all|none), OUT/video/*.mp4 with --video.
Check a file: python -m quadson_mjx.mcap_check FILE --rollout. Bad input: one line, exit status 2.

--tiles TYPES --levels L ... (a policy trained on the tiled ground): instead of --terrain, each
tile (type, level) of the policy's own training field, every run starting at the tile's centre
and holding vx 0.3 m/s for --seconds (default 3; at most the walk to the tile's edge), the trial
of the MJX tiles evaluation (quadson-tiles-eval); the table adds the share of runs that succeeded
(no fall, >= 80 % of the commanded distance) and of the distance covered. --tile-levels N lays the
field out in N levels (level L is (L + 1) / N of each type's largest size), as quadson-tiles-eval's
--env.tiles.levels=N.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
import time
from pathlib import Path

from quadson_mjx import sim2sim as S
from quadson_mjx import sim2sim_model, sim2sim_plant
from quadson_mjx.errors import (
    ArgumentParser,
    UsageError,
    check_number,
    check_readable,
    one_line_errors,
    write_text_atomic,
)

MAX_LATENCY_MS = 100.0


def parse(argv):
    p = ArgumentParser(prog="quadson-sim2sim", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "policy", nargs="+", help="exported policy files (*.onnx or *.npz; python -m quadson_mjx.export)"
    )
    p.add_argument("--terrain", default=None, choices=("flat", "stones", "both"), help="default: both")
    p.add_argument(
        "--tiles",
        default=None,
        metavar="TYPES",
        help="tile types of the policy's tiled ground (comma list or all)",
    )
    p.add_argument("--levels", type=int, nargs="+", default=None, help="with --tiles: the tiles' levels")
    p.add_argument(
        "--tile-levels",
        type=int,
        default=None,
        metavar="N",
        help="with --tiles: the policy's field laid out in N levels instead of its own (level L of N "
        "is (L + 1) / N of each type's largest size: --tile-levels 8 --levels 5 is 15 deg and 3 cm)",
    )
    p.add_argument(
        "--commands",
        default=None,
        choices=S.COMMAND_SETS,
        help="the command sweep, the step schedule, both (all, the default), the tile trial (tile, "
        "the default with --tiles), or the policy's gait command (gait)",
    )
    p.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="per sweep command; the step schedule's total [s] (default 20; 3 with --tiles)",
    )
    p.add_argument("--latency-ms", type=float, default=20.0, help="servo latency after the loop's step [ms]")
    p.add_argument(
        "--randomize", action="store_true", help="randomized model (friction, masses, motors, CoM)"
    )
    p.add_argument(
        "--randomization",
        action="append",
        default=[],
        metavar="KEY=LOW,HIGH",
        help="with --randomize: a range replacing the policy's trained one, repeatable "
        f"({', '.join(S.RANDOMIZED)})",
    )
    p.add_argument("--pushes", action="store_true", help="horizontal velocity kicks at random intervals")
    p.add_argument("--seeds", type=int, default=3, help="seeds 0 .. N-1 per command")
    p.add_argument(
        "--velocity-source",
        default="true",
        help="for a policy that observes the base velocity: true, zero, command (comma list) or all",
    )
    p.add_argument("--no-sensor-noise", action="store_true", help="ideal IMU and encoders")
    p.add_argument(
        "--imu-mount-tilt",
        type=float,
        default=sim2sim_plant.SensorParams.mount_tilt,
        metavar="RAD",
        help="the IMU's mounting roll and pitch on the frame, uniform in +-RAD per run (default %(default)s)",
    )
    p.add_argument(
        "--imu-calibration-s",
        type=float,
        default=0.0,
        metavar="S",
        help="stand S seconds at home on level ground first (off flat ground: a level twin of the "
        "plant with its IMU) and calibrate the loop's IMU (mounting tilt, gyro bias) from those "
        "readings (quadson_mjx.deploy_imu); 0: none",
    )
    p.add_argument("--out", default=None, help="output folder (default: runs/sim2sim_<time>)")
    p.add_argument(
        "--mcap", default="first", choices=("first", "all", "none"), help="which runs get an MCAP file"
    )
    p.add_argument("--video", action="store_true", help="also an .mp4 of each MCAP'd run (headless OpenGL)")
    p.add_argument("--workers", type=int, default=1, help="processes running the runs")
    p.add_argument("--per-command", action="store_true", help="also print one line per command and seed")
    a = p.parse_args(argv)
    tiles = a.tiles is not None
    if tiles and (a.terrain is not None or a.commands not in (None, S.TILE)):
        raise UsageError(
            "--tiles runs the tile trial on the tiles it names: leave out --terrain and --commands"
        )
    if (a.levels is not None) != tiles:
        raise UsageError("--tiles TYPES and --levels L ... go together")
    if a.tile_levels is not None and not tiles:
        raise UsageError("--tile-levels N lays out the tiled ground: it needs --tiles TYPES --levels L ...")
    if a.tile_levels is not None and not 1 <= a.tile_levels <= 100:
        raise UsageError(f"--tile-levels {a.tile_levels}: give 1 to 100 levels")
    a.terrain = a.terrain or "both"
    a.commands = a.commands or (S.TILE if tiles else "all")
    a.seconds = a.seconds if a.seconds is not None else (3.0 if tiles else 20.0)
    check_number("--seconds", a.seconds, 1.0, 3600.0)
    check_number("--latency-ms", a.latency_ms, 0.0, MAX_LATENCY_MS)
    check_number("--seeds", a.seeds, 1, 1000)
    check_number("--workers", a.workers, 1, 64)
    check_number("--imu-calibration-s", a.imu_calibration_s, 0.0, 60.0)
    check_number("--imu-mount-tilt", a.imu_mount_tilt, 0.0, 0.2)
    sources = S.VELOCITY_SOURCES if a.velocity_source == "all" else tuple(a.velocity_source.split(","))
    bad = [s for s in sources if s not in S.VELOCITY_SOURCES]
    if bad or not sources:
        raise UsageError(
            f"--velocity-source {a.velocity_source}: choose from {', '.join(S.VELOCITY_SOURCES)} or all"
        )
    a.velocity_sources = sources
    a.ranges = parse_ranges(a.randomization)
    if a.ranges and not a.randomize:
        raise UsageError("--randomization sets ranges of the randomized model: add --randomize")
    for path in a.policy:
        check_readable(path, "policy")
        if Path(path).suffix.lower() not in (".onnx", ".npz"):
            raise UsageError(
                f"policy {path}: a policy file is *.onnx or *.npz (python -m quadson_mjx.export)"
            )
        try:
            adapter = S.LoopAdapter(path)
        except (ValueError, KeyError) as e:
            raise UsageError(f"policy {path}: the deploy loop refuses it: {e}") from e
        if adapter.loop.needs_imu_calibration and not a.imu_calibration_s > 0:
            raise UsageError(f"policy {path}: trained for a calibrated IMU; add --imu-calibration-s S")
        try:
            S.check_command_set(adapter, a.commands, path)
        except ValueError as e:
            raise UsageError(str(e)) from None
        if tiles:
            a.terrains = tile_terrains(a, adapter.env_config, path)
    if not tiles:
        a.terrains = S.TERRAINS if a.terrain == "both" else (a.terrain,)
    return a


def tile_terrains(a, env_config: dict, path) -> tuple[str, ...]:
    """--tiles TYPES --levels L ... -> ("tiles:TYPE:LEVEL", ...) on the policy's own field (with
    --tile-levels N: "tiles:TYPE:LEVEL/N", the field laid out in N levels), its --seconds of the
    tile trial inside the tile; UsageError otherwise."""
    try:
        spec = S.tile_field(env_config, a.tile_levels)
    except ValueError as e:
        raise UsageError(f"--tiles: policy {path}: {e}") from None
    types = spec.types if a.tiles == "all" else tuple(t.strip() for t in a.tiles.split(","))
    of = "" if a.tile_levels is None else f"/{a.tile_levels}"
    terrains = tuple(f"{S.TILE_PREFIX}{t}:{lv}{of}" for t in types for lv in a.levels)
    for t in terrains:
        try:
            S.tile_terrain(t, env_config)
        except ValueError as e:
            raise UsageError(f"--tiles {a.tiles} --levels {' '.join(map(str, a.levels))}: {e}") from None
    walk = S.TILE_COMMAND[0] * a.seconds
    if walk > spec.tile_m / 2 - S.TILE_START_M:
        raise UsageError(
            f"--seconds {a.seconds}: at {S.TILE_COMMAND[0]} m/s the robot walks {walk:.2f} m from the "
            f"centre of a {spec.tile_m} m tile and leaves it: at most {(spec.tile_m / 2 - S.TILE_START_M) / S.TILE_COMMAND[0]:.2f} s"
        )
    return terrains


@one_line_errors
def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    a = parse(argv)
    out = Path(a.out or f"runs/sim2sim_{time.strftime('%Y%m%d-%H%M%S')}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create the folder ({e.strerror})") from e
    names = [Path(p).stem for p in a.policy]
    policies = [
        (f"{n}{i}" if names.count(n) > 1 else n, p)
        for i, (n, p) in enumerate(zip(names, a.policy, strict=True))
    ]
    sensors = sim2sim_plant.SensorParams(enabled=not a.no_sensor_noise, mount_tilt=a.imu_mount_tilt)
    kw = dict(
        terrains=a.terrains,
        which=a.commands,
        seconds=a.seconds,
        seeds=tuple(range(a.seeds)),
        latency_s=a.latency_ms / 1000.0,
        randomize=a.randomize,
        pushes=a.pushes,
        velocity_sources=a.velocity_sources,
        out_dir=out if a.mcap != "none" else None,
        mcap=a.mcap,
        video=a.video,
        sensors=sensors,
        ranges=a.ranges,
        imu_calibration_s=a.imu_calibration_s,
    )
    t0 = time.perf_counter()

    def progress(done, total, row):
        if a.per_command:
            print(f"[{done}/{total}] {run_line(row)}", flush=True)

    rows = S.run_suite(policies, workers=a.workers, progress=progress, **kw)
    wall = time.perf_counter() - t0
    summary = S.summarize(rows)
    print(S.format_table(summary))
    sim_s = sum(r["sim_s"] for r in rows)
    print(f"{len(rows)} runs, {sim_s:.0f} s simulated in {wall:.1f} s wall ({a.workers} worker(s))")
    result = {
        "command": "python eval/sim2sim.py " + shlex.join(argv),
        "settings": {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in kw.items()
            if k not in ("out_dir", "sensors")
        },
        "plant": {
            "timestep_s": sim2sim_model.TIMESTEP_S,
            "servo": dataclasses.asdict(sim2sim_plant.ServoParams(latency_s=kw["latency_s"])),
            "sensors": dataclasses.asdict(sensors),
            "settle_s": sim2sim_plant.SETTLE_S,
        },
        "policies": {n: str(p) for n, p in policies},
        "wall_s": wall,
        "summary": summary,
        "runs": rows,
    }
    write_text_atomic(out / "summary.json", json.dumps(result, indent=1, default=_jsonable) + "\n")
    print(f"wrote {out / 'summary.json'}")
    return 0


def parse_ranges(items: list[str]) -> dict:
    """["KEY=LOW,HIGH", ...] -> {KEY: (LOW, HIGH)} (sim2sim.check_ranges); UsageError otherwise."""
    ranges = {}
    for item in items:
        key, eq, pair = item.partition("=")
        if not eq or key in ranges:
            what = "is given twice" if eq else "is not KEY=LOW,HIGH"
            raise UsageError(f"--randomization {item}: {what}")
        try:
            ranges.update(S.check_ranges({key: tuple(pair.split(","))}))
        except ValueError as e:
            raise UsageError(f"--randomization {item}: {e}") from None
    return ranges


def run_line(row: dict) -> str:
    """One run in one line (a run that fell within the first second has no tracked step: '-')."""
    f = lambda x, spec=".3f": "-" if x is None else format(x, spec)  # noqa: E731
    status = f"FELL at {row['fall_time_s']:.2f} s" if row["fell"] else "ok"
    pattern = "-" if row["pattern_1step"] is None else f"{100 * row['pattern_1step']:.1f}%"
    return (
        f"{row['policy_name']} {row['velocity_source']} {row['terrain']} {row['label']} seed {row['seed']}: "
        f"{status}, rms vx {f(row['vx_rms'])} vy {f(row['vy_rms'])} yaw {f(row['yaw_rate_rms'])}, "
        f"vx mean {f(row['vx_mean'])}, pattern {pattern}, ik invalid {row['invalid_ik_steps']}, "
        f"{row['wall_s']:.1f} s"
    )


def _jsonable(x):
    if hasattr(x, "tolist"):
        return x.tolist()
    return str(x)


if __name__ == "__main__":
    raise SystemExit(main())
