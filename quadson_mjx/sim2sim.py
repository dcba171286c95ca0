"""Sim-to-sim: an exported policy (.onnx / .npz) closed loop through the deploy loop
(quadson_mjx.deploy, the code the robot runs) against MuJoCo C (quadson_mjx.sim2sim_plant: another
timestep, full contacts, another servo model with latency, IMU and encoder noise, bias and drift).

    rows = run_suite(["old.onnx", ("new", "new.onnx")], terrains=("flat", "stones"), which="all",
                     seconds=20.0, seeds=(0, 1, 2), velocity_sources=("true", "zero", "command"))
    print(format_table(summarize(rows)))

Per run (one policy, terrain, command schedule, seed): falls (the env's termination: roll or pitch
beyond max_tilt_rad, the base below min_height_m above the ground under it, the base box's bottom
in the ground), tracking RMS of vx, vy (body frame) and yaw rate against the command and the mean
body vx over every control step after the first second (not smoothed), steps with an invalid IK
leg, and the feet's contact pattern against the gait's phase table over the same steps
(gait_pattern: a foot is down above 1 N of normal force; the table at the loop's phase clock after
the step; exact and within one control step, as the MJX gait evaluation counts it). A fall ends
the run. `summarize` pools runs per condition: the RMS over all their steps, falls as a share of
runs.

Terrains: "flat", "stones", or one tile of a tiles policy's training ground, "tiles:TYPE:LEVEL"
(`tile_terrain`; "tiles:TYPE:LEVEL/N" on the field laid out in N levels): the whole field of its
env config, the run starting at that tile's centre (within
TILE_START_M) with a seeded heading. Every run also reports the distance it covered along its
command (the body-frame velocity along the command, capped at the command's speed, summed over the
whole run as the terrain curriculum sums it) against the distance commanded, and success: no fall
and at least SUCCESS_SHARE of it (terrain_tiles' curriculum and the MJX tiles evaluation count the
same).

Command sets: the 13-command sweep, the step schedule, "tile": TILE_COMMAND held (the MJX tiles
evaluation's trial), or "gait": the policy's own gait command,
forward at its gait's speed (DeployLoop.gait_command). A policy trained without commands (the
five gait policies) walks only at that speed and does not observe a command: it runs the "gait"
set only (suite_jobs refuses the others).
A policy that observes the base velocity (true_state) gets it from `velocity_source`: "true" (the
simulator's), "zero" (no estimator) or "command" (the command as the estimate); a sensor-only
policy gets none. Commands beyond the policy's trained command range are clipped to it, as
the deploy loop clips what it observes, and tracked against the clipped command.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from quadson_mjx import gait_pattern
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.deploy_imu import calibrate_imu
from quadson_mjx.robots import get_robot
from quadson_mjx.sim2sim_loop import VELOCITY_SOURCES, LoopAdapter  # noqa: F401 (the module's API)
from quadson_mjx.sim2sim_table import GROUP_KEYS, format_table, rms, summarize  # noqa: F401 (the module's API)
from quadson_mjx.sim2sim_tiles import (  # noqa: F401 (the module's API)
    SUCCESS_SHARE,
    TILE,
    TILE_COMMAND,
    TILE_PREFIX,
    TILE_START_M,
    start_xy,
    tile_field,
    tile_seed_shift,
    tile_terrain,
)

TERRAINS = P.TERRAINS
WARMUP_S = 1.0  # tracking errors count after this much of a run [s]
# The command sweep (vx [m/s], vy [m/s], yaw rate [rad/s]): standing, forward and back, sideways,
# turning, and combinations, inside the training ranges (vx -0.3..0.5, vy +-0.2, yaw +-0.8)
SWEEP = (
    (0.0, 0.0, 0.0),
    (0.15, 0.0, 0.0),
    (0.3, 0.0, 0.0),
    (0.5, 0.0, 0.0),
    (-0.2, 0.0, 0.0),
    (-0.3, 0.0, 0.0),
    (0.0, 0.15, 0.0),
    (0.0, -0.15, 0.0),
    (0.0, 0.0, 0.5),
    (0.0, 0.0, -0.5),
    (0.3, 0.0, 0.4),
    (0.2, 0.1, -0.3),
    (0.4, -0.1, 0.2),
)
STEP_SCHEDULE = ((0.0, 0.0, 0.0), (0.4, 0.0, 0.0), (0.0, 0.0, 0.0), (-0.2, 0.0, 0.0))  # 5 s each
GAIT = "gait"  # the command set of the policy's own gait command (its schedule: None, see run_one)
COMMAND_SETS = ("sweep", "step", "all", TILE, GAIT)
DEFAULT_RANDOMIZATION = {
    "friction": (0.5, 1.2),
    "mass_scale": (0.85, 1.15),
    "motor_strength": (0.8, 1.2),
    "base_com_shift_m": (-0.02, 0.02),
}
# the plant's randomized model: each a (low, high) range (quadson_mjx.sim2sim_plant.Plant) and the
# widest this check lets through
RANDOMIZED = {
    "friction": (0.05, 3.0),
    "mass_scale": (0.1, 3.0),
    "motor_strength": (0.1, 3.0),
    "base_com_shift_m": (-0.1, 0.1),
}
DEFAULT_PUSH = {"interval_s": (2.0, 4.0), "speed_mps": (0.1, 0.4)}


def check_ranges(ranges: dict) -> dict:
    """{key: (low, high)} of RANDOMIZED keys, finite, low <= high, inside the key's bounds, as
    floats; ValueError naming the key otherwise."""
    out = {}
    for key, pair in ranges.items():
        if key not in RANDOMIZED:
            raise ValueError(f"randomization {key!r}: the plant randomizes {', '.join(RANDOMIZED)}")
        lo_ok, hi_ok = RANDOMIZED[key]
        try:
            lo, hi = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ValueError(f"randomization {key}: a range is two numbers LOW,HIGH, got {pair!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo_ok <= lo <= hi <= hi_ok):
            raise ValueError(
                f"randomization {key}: {lo},{hi} is not a range LOW <= HIGH inside [{lo_ok}, {hi_ok}]"
            )
        out[key] = (lo, hi)
    return out


def step_schedule(segment_s: float = 5.0) -> tuple[str, tuple]:
    return ("step", tuple((i * segment_s, c) for i, c in enumerate(STEP_SCHEDULE)))


def schedules(which: str, seconds: float) -> list[tuple[str, tuple | None, float]]:
    """which: "sweep" | "step" | "all" | "gait" -> [(label, ((start_s, command), ...), duration_s)]:
    each sweep command for `seconds`, the step schedule in four segments of seconds / 4; "gait" one
    run of `seconds` whose schedule is None: the policy's gait command, which run_one takes from
    the policy's deploy loop."""
    if which == GAIT:
        return [(GAIT, None, seconds)]
    if which == TILE:
        return [(TILE, ((0.0, TILE_COMMAND),), seconds)]
    out = []
    if which in ("sweep", "all"):
        out += [(f"cmd{i:02d}", ((0.0, c),), seconds) for i, c in enumerate(SWEEP)]
    if which in ("step", "all"):
        label, sched = step_schedule(seconds / len(STEP_SCHEDULE))
        out.append((label, sched, seconds))
    if not out:
        raise ValueError(f"unknown command set {which!r}: {', '.join(COMMAND_SETS)}")
    return out


def check_command_set(adapter, which: str, name: str) -> None:
    """ValueError when the policy cannot run the command set `which`: one trained without commands
    walks its gait at the gait's own speed only (the "gait" set)."""
    if which != GAIT and not adapter.tracks_commands:
        raise ValueError(
            f"policy {name} was trained without commands (it walks its gait at the gait's own "
            f"speed and observes no command): run it with --commands gait, not {which!r}"
        )


def clip_schedule(schedule, env_config: dict):
    """The schedule with each command clipped to the policy's trained command range (as the deploy
    loop clips what it observes): the reference the tracking errors are measured against."""
    r = env_config.get("command_range")
    if not r or not env_config.get("command_tracking", False):
        return schedule
    lo = np.array([r["vx"][0], r["vy"][0], r["yaw_rate"][0]], np.float64)
    hi = np.array([r["vx"][1], r["vy"][1], r["yaw_rate"][1]], np.float64)
    return tuple((t, tuple(float(x) for x in np.clip(c, lo, hi))) for t, c in schedule)


def command_at(schedule, t: float) -> np.ndarray:
    cmd = schedule[0][1]
    for start, c in schedule:
        if t + 1e-9 >= start:
            cmd = c
    return np.asarray(cmd, np.float64)


# --- one run --------------------------------------------------------------------------------------------


def make_plant(
    robot,
    env_config: dict,
    terrain: str,
    latency_s: float,
    seed: int,
    randomize: bool,
    pushes: bool,
    sensors: P.SensorParams | None = None,
    servo: P.ServoParams | None = None,
    ranges: dict | None = None,
):
    """A Plant for the policy's robot; randomization and push ranges from its env config, the
    randomization's keys in `ranges` (RANDOMIZED: (low, high) each) replacing the config's."""
    servo = servo or P.ServoParams(latency_s=latency_s)
    rand = None
    if randomize:
        rand = {**DEFAULT_RANDOMIZATION, **env_config.get("randomization", {}), **(ranges or {})}
    push = {**DEFAULT_PUSH, **env_config.get("push", {})} if pushes else None
    tile = tile_terrain(terrain, env_config)
    model = P.plant_model(robot, terrain) if tile is None else P.plant_model(robot, "tiles", tiles=tile[0])
    return P.Plant(robot, model, servo, sensors or P.SensorParams(), seed, rand, push)


def standing_readings(plant: P.Plant, seconds: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The plant's IMU read every dt for `seconds` while the robot stands at home -> (quats (N, 4),
    gyros (N, 3)), N >= 1; the plant's physics advances."""
    quats, gyros = [], []
    for _ in range(max(1, int(round(seconds / dt)))):
        readings = plant.read()
        quats.append(readings.imu_quat_wxyz)
        gyros.append(readings.gyro)
        plant.advance(dt)
    return np.array(quats), np.array(gyros)


def level_twin(plant: P.Plant, seed: int) -> P.Plant:
    """A twin of `plant` standing at home on the flat scene (the nominal model, no pushes) with the
    plant's IMU: its mounting and gyro bias as the plant drew them for this run, its noise. The
    level floor a robot is calibrated on before it walks onto other ground."""
    twin = P.Plant(
        plant.robot, P.plant_model(plant.robot, "flat"), plant.servo, plant.sensors, seed + 1_000_003
    )
    twin.reset()
    twin.mount, twin.gyro_bias = plant.mount.copy(), plant.gyro_bias.copy()
    return twin


def run_episode(
    adapter: LoopAdapter,
    plant: P.Plant,
    schedule,
    duration_s: float,
    seed: int = 0,
    recorder=None,
    terrain: str = "flat",
    imu_calibration_s: float = 0.0,
) -> dict:
    """One closed-loop run: reset the plant at the terrain's start (start_xy) with a seeded heading,
    start the loop on its sensor readings, then every ctrl_dt: read, step the loop, send, advance
    the physics. -> the run's metrics (see the module docstring). imu_calibration_s > 0: first the
    robot stands that long at home on level ground while the IMU is read each tick, and the loop
    takes its deploy_imu calibration from those readings, as a robot does on a level floor before
    its walk: on flat ground in the plant itself, elsewhere in a level twin of it
    (level_twin). A policy that observes the servos' latency is given the plant's (ValueError when
    it is outside the range the policy was trained for)."""
    term = {
        "max_tilt_rad": math.pi / 4,
        "min_height_m": 0.1,
        "base_below_terrain": True,
        "base_clearance_m": 0.0,
    }
    term.update(adapter.env_config.get("termination", {}))
    dt = adapter.ctrl_dt
    rng = np.random.default_rng(seed)
    yaw = float(rng.uniform(-math.pi, math.pi))
    plant.reset(start_xy(terrain, adapter.env_config, rng), yaw)
    if imu_calibration_s > 0:
        floor = plant if terrain == "flat" else level_twin(plant, seed)
        adapter.loop.imu_calibration = calibrate_imu(*standing_readings(floor, imu_calibration_s, dt))
    if adapter.loop.needs_servo_latency:  # the plant's own latency, as a perfect calibration measures it
        adapter.loop.servo_latency_s = plant.delay * float(plant.m.opt.timestep)
    adapter.reset(plant.read())
    n = int(round(duration_s / dt))
    err, vx, forces, stance = [], [], [], []
    invalid, faults, fell, fall_t, off = 0, 0, False, None, False
    progress, commanded = 0.0, 0.0
    truth = plant.truth()
    for k in range(n):
        command = command_at(schedule, k * dt)
        readings = plant.read()
        out = adapter.step(readings, command, truth["lin_vel"])
        plant.send(out.motor_targets)
        plant.advance(dt)
        truth = plant.truth()
        t = (k + 1) * dt
        speed = math.hypot(command[0], command[1])
        if speed > 0:  # along the command, capped at its speed
            along = (truth["lin_vel"][0] * command[0] + truth["lin_vel"][1] * command[1]) / speed
            progress += min(max(along, 0.0), speed) * dt
            commanded += speed * dt
        if t > WARMUP_S + 1e-9:
            err.append([truth["lin_vel"][0], truth["lin_vel"][1], truth["ang_vel"][2]] - command)
            vx.append(truth["lin_vel"][0])
            forces.append(plant.foot_forces())
            stance.append(adapter.scheduled_stance())
        invalid += int(not np.all(out.valid))
        faults += int(adapter.faulty(out))
        r, p, _ = truth["rpy"]
        fell = (
            abs(r) > term["max_tilt_rad"]
            or abs(p) > term["max_tilt_rad"]
            or truth["height"] < term["min_height_m"]
            or (term["base_below_terrain"] and truth["clearance"] < term["base_clearance_m"])
        )
        off = not truth["on_field"]
        if recorder is not None:
            recorder.step(k, plant, readings, out, command, truth, fell or off)
        if fell or off:
            fall_t = t if fell else None
            break
    e = np.asarray(err, np.float64).reshape(-1, 3)
    sq = np.sum(e * e, axis=0)
    pattern = gait_pattern.pattern_counts(np.reshape(forces, (-1, 4)), np.reshape(stance, (-1, 4)))
    return {
        "fell": bool(fell),
        "fall_time_s": fall_t,
        "off_field": bool(off and not fell),
        "steps": k + 1,
        "sim_s": (k + 1) * dt,
        "tracked_steps": int(len(e)),
        "sq_err_sum": sq.tolist(),  # for pooling runs
        "vx_rms": rms(sq[0], len(e)),
        "vy_rms": rms(sq[1], len(e)),
        "yaw_rate_rms": rms(sq[2], len(e)),
        "vx_sum": float(np.sum(vx)),  # for pooling runs
        "vx_mean": float(np.mean(vx)) if vx else None,
        **pattern,
        "pattern": pattern["pattern_hits"] / len(e) if len(e) else None,
        "pattern_1step": pattern["pattern_1step_hits"] / len(e) if len(e) else None,
        "invalid_ik_steps": invalid,
        "fault_steps": faults,
        "push_count": plant.pushes,
        "progress_m": progress,
        "commanded_m": commanded,
        "success": bool(not fell and not off and progress >= SUCCESS_SHARE * commanded),
    }


def plant_seed_of(seed: int, schedule_index: int = 0, terrain: str = "flat") -> int:
    """The plant's seed (model draw, sensor biases and noise, pushes) of a run: one stream per seed,
    command schedule and terrain."""
    shift = {"flat": 0, "stones": 17}.get(terrain)
    shift = tile_seed_shift(terrain) if shift is None else shift
    return 1_000_003 * seed + 7919 * schedule_index + shift


def run_one(job: dict) -> dict:
    """One job of run_suite (a plain dict, so that worker processes can take it) -> its row."""
    t0 = time.perf_counter()
    adapter = LoopAdapter(job["policy"], job["velocity_source"])
    robot = get_robot(adapter.env_config.get("robot", "quadson"))
    schedule = job["schedule"] or ((0.0, adapter.gait_command),)
    schedule = clip_schedule(schedule, adapter.env_config)
    seed = job["seed"]
    plant_seed = plant_seed_of(seed, job["schedule_index"], job["terrain"])
    plant = make_plant(
        robot,
        adapter.env_config,
        job["terrain"],
        job["latency_s"],
        plant_seed,
        job["randomize"],
        job["pushes"],
        sensors=job.get("sensors"),
        ranges=job.get("ranges"),
    )
    recorder = None
    if job.get("mcap") or job.get("video"):
        from quadson_mjx.sim2sim_record import Recorder

        recorder = Recorder(job.get("mcap"), job.get("video"), plant, adapter, job)
    try:
        row = run_episode(
            adapter,
            plant,
            schedule,
            job["duration_s"],
            seed,
            recorder,
            job["terrain"],
            job.get("imu_calibration_s", 0.0),
        )
    finally:
        if recorder is not None:
            recorder.close()
    keys = ("policy_name", "terrain", "label", "seed", "latency_s", "randomize", "pushes", "ranges")
    return {
        **{k: job[k] for k in keys},
        "velocity_source": adapter.velocity_source,
        "imu_calibration_s": job.get("imu_calibration_s", 0.0),
        "robot": robot.name,
        "commands": [list(c) for _, c in schedule],
        "duration_s": job["duration_s"],
        **row,
        "wall_s": time.perf_counter() - t0,
    }


def suite_jobs(
    policies,
    terrains=TERRAINS,
    which="all",
    seconds=20.0,
    seeds=(0,),
    latency_s=0.02,
    randomize=False,
    pushes=False,
    velocity_sources=("true",),
    out_dir=None,
    mcap="first",
    video=False,
    sensors: P.SensorParams | None = None,
    ranges: dict | None = None,
    imu_calibration_s: float = 0.0,
) -> list[dict]:
    """Every (policy, velocity source, terrain, schedule, seed) as a job for run_one. policies:
    paths, or (name, path) pairs. A sensor-only policy runs once, whatever velocity_sources says.
    mcap: "none" | "first" (the first seed's runs) | "all", written under out_dir/mcap/. ranges:
    randomization ranges replacing each policy's trained ones (check_ranges), for every policy."""
    ranges = check_ranges(ranges or {})
    jobs = []
    for pol in policies:
        name, path = pol if isinstance(pol, tuple) else (Path(pol).stem, pol)
        adapter = LoopAdapter(path)
        check_command_set(adapter, which, name)
        observes = adapter.observes_velocity
        for vs in velocity_sources if observes else ("true",):
            for terrain in terrains:
                for si, (label, sched, dur) in enumerate(schedules(which, seconds)):
                    for j, seed in enumerate(seeds):
                        tag = (
                            f"{name}_{vs if observes else 'none'}_{terrain.replace(':', '-')}_{label}_s{seed}"
                        )
                        want = out_dir is not None and (mcap == "all" or (mcap == "first" and j == 0))
                        jobs.append(
                            {
                                "policy": str(path),
                                "policy_name": name,
                                "velocity_source": vs,
                                "terrain": terrain,
                                "label": label,
                                "schedule": sched,
                                "schedule_index": si,
                                "duration_s": dur,
                                "seed": seed,
                                "latency_s": latency_s,
                                "randomize": randomize,
                                "pushes": pushes,
                                "mcap": str(Path(out_dir) / "mcap" / f"{tag}.mcap") if want else None,
                                "video": str(Path(out_dir) / "video" / f"{tag}.mp4")
                                if want and video
                                else None,
                                "sensors": sensors,
                                "ranges": ranges,
                                "imu_calibration_s": imu_calibration_s,
                            }
                        )
    return jobs


def run_suite(policies, workers: int = 1, progress=None, **kw) -> list[dict]:
    """Runs every job of suite_jobs(policies, **kw) -> one row per run (run_one). workers > 1 runs
    them in that many processes. progress(done, total, row) after each."""
    jobs = suite_jobs(policies, **kw)
    for j in jobs:
        for f in ("mcap", "video"):
            if j[f]:
                Path(j[f]).parent.mkdir(parents=True, exist_ok=True)
    rows = []
    if workers <= 1:
        for j in jobs:
            rows.append(run_one(j))
            if progress:
                progress(len(rows), len(jobs), rows[-1])
        return rows
    import concurrent.futures as cf
    import multiprocessing as mp

    with cf.ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as ex:
        for row in ex.map(run_one, jobs):
            rows.append(row)
            if progress:
                progress(len(rows), len(jobs), row)
    return rows
