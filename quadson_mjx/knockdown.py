"""Knocked down while walking: the on-robot supervisor (quadson_mjx.deploy_supervisor) over an exported
walking policy and an exported get-up policy, closed loop against sim2sim's MuJoCo C plant
(quadson_mjx.sim2sim_plant: full contacts, servo model with torque-speed limit and 20 ms latency, IMU
and encoder noise, randomized model as sim2sim's --randomize).

    summary, rows = run_knockdowns("walk.onnx", "getup.onnx", n=50, seed=0, terrain="flat")

One trial: the plant reset on the home stance (random heading, a fresh randomized model and sensor
biases), the supervisor walks it at FORWARD_COMMAND for walk_s, then a knock (`knock`):
* "kick" (`kick`): one velocity kick of the base, a random horizontal direction, the base pushed that
  way at 0.2-0.6 m/s and tipped toward it at 25-35 rad/s; while the supervisor still walks REKICK_S
  later and the robot is upright, another kick, MAX_KICKS in all. Violent: most roll the robot over;
* "shove" (`Shove`): a horizontal force at the top of the base held SHOVE_S, in one random direction
  per trial, 15 N first; while the supervisor still walks RESHOVE_S later and the robot is upright,
  the next force of SHOVE_FORCES_N (up to 96 N): the smallest of them that fells the robot;
* "none": no knock; the supervisor walks for walk_s + seconds_per_trial (times from the start), and
  success is walking throughout with no fall detected and the true tilt below UPRIGHT_TILT_RAD: the
  fall detector's false alarms (with `pushes`, under the walking run's random pushes).
Then the supervisor runs for up to seconds_per_trial from the last knock: fall detection, get-up
attempts, standing_hold, walking. When walking resumes the trial runs hold_s more. Success: walking
resumed within seconds_per_trial of the last knock and, for the hold_s after, the mode stayed
walking and the true tilt (the simulator's base, not the IMU) below UPRIGHT_TILT_RAD. Times in a row
are from the last knock (its list "kicks" holds every knock).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import mujoco
import numpy as np

from quadson_mjx import deploy
from quadson_mjx import sim2sim as S
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.deploy_supervisor import Mode, Supervisor, tilt
from quadson_mjx.quat import quat_rotate
from quadson_mjx.robots import get_robot
from quadson_mjx.robots.quadson.mirror import TRAINED
from quadson_mjx.stats import success_interval

FORWARD_COMMAND = (0.25, 0.0, 0.0)  # vx [m/s], vy [m/s], yaw rate [rad/s] while walking
KICK_SPEED_MPS = (0.2, 0.6)  # horizontal base speed added by the kick, uniform [m/s]
KICK_RATE_RPS = (25.0, 35.0)  # angular rate added about the horizontal axis across it, uniform [rad/s]
MAX_KICKS, REKICK_S = 3, 1.0  # while the supervisor still walks, kick again this long after [s]
# A shove: a horizontal force at the top of the base, in one random direction per trial, held
# SHOVE_S; while the supervisor still walks RESHOVE_S later and the robot is upright, a harder one.
SHOVE_FORCES_N = (15.0, 20.0, 26.0, 34.0, 44.0, 57.0, 74.0, 96.0)
SHOVE_S, RESHOVE_S = 0.16, 1.5  # 8 control ticks of 20 ms
KNOCKS = ("kick", "shove", "none")
UPRIGHT_TILT_RAD = math.radians(30.0)  # the success's bound on the true tilt
LATENCY_S = 0.02  # servo latency of the plant [s], sim2sim's default


class _Tap:
    """The walking DeployLoop, remembering its last StepResult (for the recording)."""

    def __init__(self, loop):
        self.loop, self.last = loop, None

    def step(self, *args, **kwargs):
        self.last = self.loop.step(*args, **kwargs)
        return self.last

    def __getattr__(self, name):
        return getattr(self.loop, name)


def kick(plant, rng) -> dict:
    """Adds a knock-down to the plant's base velocity: a horizontal direction u at angle phi in the body
    frame (uniform), the base's linear velocity += speed u (world frame), its angular velocity +=
    rate (z x u) (body frame: the top tips toward u). -> {"dir_deg", "speed_mps", "rate_rps"}."""
    phi = float(rng.uniform(-math.pi, math.pi))
    speed, rate = float(rng.uniform(*KICK_SPEED_MPS)), float(rng.uniform(*KICK_RATE_RPS))
    u = np.array([math.cos(phi), math.sin(phi), 0.0])
    world = quat_rotate(plant.d.qpos[3:7], u)
    world[2] = 0.0
    plant.d.qvel[0:3] += speed * world / max(float(np.linalg.norm(world)), 1e-9)
    plant.d.qvel[3:6] += rate * np.array([-u[1], u[0], 0.0])  # free joint: angular velocity in body frame
    return {"dir_deg": math.degrees(phi), "speed_mps": speed, "rate_rps": rate}


class NoKnock:
    """No knock: the supervisor walks the whole trial; a fall detected then is a false alarm (or a
    true fall the walking policy caused), which is what the trial measures."""

    name, max_knocks, every_s = "none", 0, math.inf

    def __init__(self, plant, rng):
        pass

    def tick(self) -> None:
        pass


class Kick:
    """Velocity kicks (`kick`), a fresh direction and size each, MAX_KICKS at most."""

    name, max_knocks, every_s = "kick", MAX_KICKS, REKICK_S

    def __init__(self, plant, rng):
        self.plant, self.rng = plant, rng

    def start(self, n: int, dt: float) -> dict:
        return kick(self.plant, self.rng)

    def tick(self) -> None:
        pass


class Shove:
    """Shoves of rising force (SHOVE_FORCES_N) in one direction drawn per trial (uniform in the body
    frame at the first shove), each a horizontal world-frame force held SHOVE_S at the centre of the
    base box's top face, as a hand pushes the robot's back; the torque about the centre of mass
    follows from that point. MuJoCo's xfrc_applied, cleared when the shove ends."""

    name, max_knocks, every_s = "shove", len(SHOVE_FORCES_N), RESHOVE_S

    def __init__(self, plant, rng):
        self.plant, self.rng = plant, rng
        m = plant.m
        g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
        self.top = m.geom_pos[g] + np.array([0.0, 0.0, m.geom_size[g][2]])  # in the base's frame
        self.phi, self.direction, self.force, self.ticks = (
            float(rng.uniform(-math.pi, math.pi)),
            None,
            None,
            0,
        )

    def start(self, n: int, dt: float) -> dict:
        if self.direction is None:  # the first shove fixes the direction, horizontal in the world
            world = quat_rotate(
                self.plant.d.qpos[3:7], np.array([math.cos(self.phi), math.sin(self.phi), 0.0])
            )
            world[2] = 0.0
            self.direction = world / max(float(np.linalg.norm(world)), 1e-9)
        self.force = SHOVE_FORCES_N[n] * self.direction
        self.ticks = int(round(SHOVE_S / dt))
        return {"dir_deg": math.degrees(self.phi), "force_n": SHOVE_FORCES_N[n], "duration_s": SHOVE_S}

    def tick(self) -> None:
        """Before each control period: the force for its physics steps, or none once SHOVE_S passed."""
        d, b = self.plant.d, self.plant.root
        if self.ticks <= 0:
            d.xfrc_applied[b] = 0.0
            return
        point = d.xpos[b] + d.xmat[b].reshape(3, 3) @ self.top
        d.xfrc_applied[b, :3] = self.force
        d.xfrc_applied[b, 3:] = np.cross(point - d.xipos[b], self.force)
        self.ticks -= 1


def build(
    walk_file,
    getup_file,
    terrain: str = "flat",
    randomize: bool = True,
    sensors: bool = True,
    pushes: bool = False,
    supervisor=None,
    mirror_to: str | None = TRAINED,
):
    """Loads the two policies -> (Supervisor over a DeployLoop of walk_file, Plant of sim2sim on
    `terrain` with the walking policy's randomization ranges (and its pushes, when asked), the
    walking policy's env config). supervisor: a SupervisorConfig (default its defaults); mirror_to:
    the get-up policy's (deploy_supervisor.GetupPolicy)."""
    if terrain not in P.TERRAINS:
        raise ValueError(f"unknown terrain {terrain!r}: {', '.join(P.TERRAINS)}")
    walk = deploy.load_policy(walk_file)
    sup = Supervisor(
        _Tap(deploy.DeployLoop(walk)), deploy.load_policy(getup_file), supervisor, getup_mirror_to=mirror_to
    )
    env_cfg = walk.meta["env_config"]
    robot = get_robot(env_cfg.get("robot", "quadson"))
    plant = S.make_plant(
        robot, env_cfg, terrain, LATENCY_S, 0, randomize, pushes, sensors=P.SensorParams(enabled=sensors)
    )
    return sup, plant, env_cfg


def run_trial(
    sup, plant, rng, walk_s=2.0, seconds_per_trial=10.0, hold_s=2.0, recorder=None, knock="kick"
) -> dict:
    """One knock-down (the module's docstring) with the plant's rng already seeded; rng draws the heading
    and the knocks (knock: "kick" or "shove"). -> the trial's row: times [s] from the last knock, tilts
    [deg], counts."""
    if knock not in KNOCKS:
        raise ValueError(f"knock {knock!r}: choose from {', '.join(KNOCKS)}")
    dt = sup.dt
    r = sup.walking.config.robot
    lo, hi = r.motor_limits[:, 0], r.motor_limits[:, 1]
    plant.reset((0.0, 0.0), float(rng.uniform(-math.pi, math.pi)))
    knocker = {"kick": Kick, "shove": Shove, "none": NoKnock}[knock](plant, rng)
    rd = plant.read()
    sup.reset(rd.motor_pos)
    sup.walking.reset_heading(rd.imu_quat_wxyz)
    needs_vel = sup.walking.needs_lin_vel
    k_kick = k_next = int(round(walk_s / dt))
    k_end = k_kick + int(round(seconds_per_trial / dt))
    if knock == "none":  # walking throughout; times and the largest tilt from the start
        k_kick, k_next = 0, -1
    kicks = []
    row = {"detected": False, "fell_before_kick": False, "t_detect_s": None, "t_standing_hold_s": None}
    row |= {"t_walking_s": None, "attempts": 0, "timeouts": 0, "tilt_at_getup_deg": None}
    bad, max_tilt, held, prev, k = 0, 0.0, True, Mode.WALKING, 0
    faults0 = sup.fault_counts
    while k < k_end:
        if k == k_next and not row["detected"] and tilt(plant.d.qpos[3:7]) >= UPRIGHT_TILT_RAD:
            k_next += 1  # walking on, but not upright: wait for it
        elif k == k_next and not row["detected"]:  # the first kick, or another: the last did not fell it
            kicks.append(knocker.start(len(kicks), dt))
            k_kick, k_end = k, k + int(round(seconds_per_trial / dt))
            k_next = k + int(round(knocker.every_s / dt)) if len(kicks) < knocker.max_knocks else -1
        knocker.tick()
        rd = plant.read()
        vel = plant.truth()["lin_vel"] if needs_vel else None
        out = sup.step(rd.imu_quat_wxyz, rd.gyro, rd.motor_pos, command=FORWARD_COMMAND, base_lin_vel=vel)
        m = out.motor_targets
        bad += int(not (np.all(np.isfinite(m)) and np.all(m >= lo - 1e-9) and np.all(m <= hi + 1e-9)))
        plant.send(m)
        plant.advance(dt)
        true_tilt = tilt(plant.d.qpos[3:7])
        t = (k - k_kick + 1) * dt  # the end of this tick, from the kick
        if out.mode is not prev:
            if k < k_kick:
                row["fell_before_kick"] = True
            if prev is Mode.WALKING and k >= k_kick and not row["detected"]:  # walking left
                row["detected"], row["t_detect_s"] = True, t - dt
            if out.mode is Mode.GETTING_UP and prev is not Mode.STANDING_HOLD:  # a new attempt
                row["attempts"] += 1
                if row["tilt_at_getup_deg"] is None:
                    row["tilt_at_getup_deg"] = math.degrees(true_tilt)
            row["timeouts"] += int(out.mode is Mode.RESTING)
            if out.mode is Mode.STANDING_HOLD and row["t_standing_hold_s"] is None:
                row["t_standing_hold_s"] = t - dt
            if out.mode is Mode.WALKING and row["detected"] and row["t_walking_s"] is None:
                row["t_walking_s"] = t - dt
                k_end = k + int(round(hold_s / dt))  # the hold: hold_s of ticks from this one on
        if row["t_walking_s"] is not None:
            held = held and out.mode is Mode.WALKING and true_tilt < UPRIGHT_TILT_RAD
        if k >= k_kick:
            max_tilt = max(max_tilt, true_tilt)
        if recorder is not None:
            _record(recorder, k, plant, rd, out, sup, k == 0 or out.mode is not prev)
        prev, k = out.mode, k + 1
    return row | {
        "kicks": kicks,  # the last one felled the robot, if one did
        # "none": walked throughout, no fall detected, the true tilt below UPRIGHT_TILT_RAD
        "success": bool(row["t_walking_s"] is not None and held)
        if knock != "none"
        else bool(not row["detected"] and max_tilt < UPRIGHT_TILT_RAD),
        "max_tilt_deg": math.degrees(max_tilt),
        "final_tilt_deg": math.degrees(true_tilt),
        "final_mode": str(out.mode),
        "sim_s": k * dt,
        "bad_target_ticks": bad,
        "fault_ticks": {
            n: c - faults0.get(n, 0) for n, c in sup.fault_counts.items() if c > faults0.get(n, 0)
        },
    }


def _record(recorder, k, plant, readings, out, sup, switched: bool) -> None:
    """One tick into sim2sim_record's Recorder; the supervisor's mode switches as log lines."""
    w = sup.walking.last if out.mode is Mode.WALKING else None
    nan = np.full((4, 3), np.nan)
    step = SimpleNamespace(
        obs=np.zeros(0) if w is None else w.obs,
        action=(w.action if w is not None else out.action if out.action is not None else np.zeros(12)),
        foot_targets=nan if w is None else w.foot_targets,
        valid=np.ones(4, bool) if w is None else w.valid,
        motor_targets=out.motor_targets,
    )
    recorder.step(k, plant, readings, step, np.asarray(FORWARD_COMMAND), plant.truth(), False)
    if recorder.writer is not None and switched:
        recorder.writer.log(recorder.t_ns, "info", f"supervisor: {out.mode} (tilt {out.tilt_rad:.2f} rad)")


def settings(
    seconds_per_trial: float = 10.0,
    walk_s: float = 2.0,
    hold_s: float = 2.0,
    knock: str = "kick",
    pushes: bool = False,
) -> dict:
    """The trial's constants, for a results file."""
    if knock == "kick":
        knocks = {"kick_speed_mps": list(KICK_SPEED_MPS), "kick_rate_rps": list(KICK_RATE_RPS)}
        knocks |= {"max_kicks": MAX_KICKS, "rekick_s": REKICK_S}
    elif knock == "none":
        knocks = {}
    else:
        knocks = {"shove_forces_n": list(SHOVE_FORCES_N), "shove_s": SHOVE_S, "reshove_s": RESHOVE_S}
        knocks |= {"shove_point": "the centre of the base box's top face"}
    return {
        "command": list(FORWARD_COMMAND),
        "knock": knock,
        **knocks,
        "walk_s": walk_s,
        "seconds_per_trial": seconds_per_trial,
        "hold_s": hold_s,
        "upright_tilt_deg": math.degrees(UPRIGHT_TILT_RAD),
        "latency_s": LATENCY_S,
        "randomized_model": True,
        "pushes": pushes,
        "sensor_noise": True,
    }


def summarize(rows) -> dict:
    """Trial rows -> success rate (with a 95 % Wilson interval), detected falls, median times [s]."""
    n = len(rows)
    wins = sum(r["success"] for r in rows)
    med = lambda key: float(np.median(v)) if (v := [r[key] for r in rows if r[key] is not None]) else None  # noqa: E731
    back = [r for r in rows if (r["tilt_at_getup_deg"] or 0.0) > 150.0]
    return {
        "trials": n,
        "successes": wins,
        "success_rate": wins / n,
        "success_rate_95": success_interval(wins, n),
        "detected": sum(r["detected"] for r in rows),
        "kicks": sum(len(r["kicks"]) for r in rows),
        "fell_before_kick": sum(r["fell_before_kick"] for r in rows),
        "walking_resumed": sum(r["t_walking_s"] is not None for r in rows),
        "median_t_detect_s": med("t_detect_s"),
        "median_t_standing_hold_s": med("t_standing_hold_s"),
        "median_t_walking_s": med("t_walking_s"),
        "attempts": sum(r["attempts"] for r in rows),
        "trials_with_timeout": sum(r["timeouts"] > 0 for r in rows),
        "on_back_at_getup": len(back),
        "successes_on_back": sum(r["success"] for r in back),
        "bad_target_ticks": sum(r["bad_target_ticks"] for r in rows),
    }


def run_knockdowns(
    walk_file,
    getup_file,
    n: int = 50,
    seed: int = 0,
    terrain: str = "flat",
    seconds_per_trial: float = 10.0,
    record=None,
    walk_s: float = 2.0,
    hold_s: float = 2.0,
    randomize: bool = True,
    progress=None,
    knock: str = "kick",
    first: int = 0,
    video=None,
    pushes: bool = False,
    supervisor=None,
    mirror_to: str | None = TRAINED,
) -> tuple[dict, list[dict]]:
    """n knock-downs (the module's docstring): trials first .. first + n - 1, trial i seeded by
    (seed, i) alone, so one trial of a run can be replayed by itself. record / video: None or an .mcap
    / .mp4 or .gif path for the first of them (sim2sim_record's Recorder). progress(i, row) after each.
    -> (summary, rows)."""
    if n < 1 or first < 0:
        raise ValueError(f"n {n}, first {first}: need at least 1 trial, from trial 0 on")
    if knock not in KNOCKS:
        raise ValueError(f"knock {knock!r}: choose from {', '.join(KNOCKS)}")
    sup, plant, env_cfg = build(
        walk_file, getup_file, terrain, randomize, pushes=pushes, supervisor=supervisor, mirror_to=mirror_to
    )
    rows = []
    for i in range(first, first + n):
        plant_ss, trial_ss = np.random.SeedSequence([seed, i]).spawn(2)
        plant.rng = np.random.default_rng(plant_ss)  # model, sensor biases and noise of this trial
        recorder = None
        if (record is not None or video is not None) and i == first:
            from quadson_mjx.sim2sim_record import Recorder

            job = {"policy_name": "knockdown", "terrain": terrain, "label": f"trial{i}", "seed": seed}
            adapter = SimpleNamespace(ctrl_dt=sup.dt, env_config=env_cfg)
            recorder = Recorder(record, video, plant, adapter, job)
        try:
            row = run_trial(
                sup, plant, np.random.default_rng(trial_ss), walk_s, seconds_per_trial, hold_s, recorder,
                knock,
            )  # fmt: skip
        finally:
            if recorder is not None:
                recorder.close()
        rows.append({"trial": i, **row})
        if progress is not None:
            progress(i, rows[-1])
    return summarize(rows), rows
