"""Seed 003's three experiments on the Caramel model, in CPU MuJoCo (open loop but for the stabilizer).

  * Table I (`leg_tracking_sample`): one leg follows a cycloid with the body held in the air.
  * Table II (`walk_sample`, command (0.05, 0, 0)): discontinuous trot on flat and rough ground, mean
    forward velocity and roll / pitch oscillation (max - min of the IMU), with and without the PID.
  * Table III (`walk_sample`, command (0, 0, 0.25), rough ground): turn in place, mean yaw rate and
    roll / pitch oscillation, with and without the PID.
  * The same walks driven by a trained foot-offset policy (`policy_driver` of a training run on
    `env_config(robot="caramel")`; `policy_rows`): the environment's gait, its offsets and IK, on the
    same perturbed models, start points and metrics as the planner's rows.
`table_1`, `table_2`, `table_3` run the samples and summarise them (mean and standard deviation);
PAPER_TABLE_* hold the published numbers (seed 003, Tables I-III), converted to SI and degrees.

Every planner tick (50 Hz) the commanded feet go through serial IK into the 12 position servos;
MuJoCo steps SIM_DT = 4 ms, 5 steps per tick. Samples differ by their seeded perturbations, named
at each function.
"""

from __future__ import annotations

import copy
import functools
import math

import jax
import mujoco
import numpy as np

from quadson_mjx import stabilizer, swing
from quadson_mjx.quat import quat_to_rpy
from quadson_mjx.robots.caramel import constants as C
from quadson_mjx.robots.caramel import gait as G
from quadson_mjx.robots.caramel import model as M

# --- the paper's numbers (seed 003), SI: m, s, m/s, rad/s; oscillations in degrees ---------------
PAPER_TABLE_1 = {  # seed 003, Table I (printed in s and cm), 30 samples per test
    "test1": {
        "displacement_m": (0.05, 0.03),
        "time_s": (0.557, 0.008),
        "apex_m": (0.04760, 0.00023),
        "final_x_m": (0.05034, 0.00009),
        "final_y_m": (0.02924, 0.00013),
    },
    "test2": {
        "displacement_m": (0.03, 0.05),
        "time_s": (0.557, 0.008),
        "apex_m": (0.04755, 0.00028),
        "final_x_m": (0.03024, 0.00013),
        "final_y_m": (0.04915, 0.00004),
    },
}
PAPER_TABLE_2 = {  # seed 003, Table II (velocity printed in cm/s), 10 samples per test
    "flat": {"velocity_mps": (0.0215, 0.0004), "roll_deg": (12.59, 2.54), "pitch_deg": (11.55, 1.89)},
    "flat_pid": {"velocity_mps": (0.0368, 0.00075), "roll_deg": (8.81, 2.36), "pitch_deg": (8.31, 2.63)},
    "rough": {"velocity_mps": (0.0203, 0.00016), "roll_deg": (13.37, 0.78), "pitch_deg": (15.19, 1.44)},
    "rough_pid": {"velocity_mps": (0.0239, 0.00047), "roll_deg": (11.13, 1.47), "pitch_deg": (12.09, 1.66)},
}
PAPER_TABLE_3 = {  # seed 003, Table III, uneven ground, 10 samples per test
    "rough": {"yaw_rate_radps": (0.19, 0.006), "roll_deg": (16.16, 1.88), "pitch_deg": (11.79, 1.05)},
    "rough_pid": {"yaw_rate_radps": (0.19, 0.007), "roll_deg": (16.84, 2.6), "pitch_deg": (12.89, 1.41)},
}

TABLE_1_LEG = "FL"
TABLE_1_ARRIVAL_TOL_M = 0.002  # the foot "reached the final point": within 2 mm of it (3-D distance)
TABLE_1_SAMPLE_S = 1.0  # recorded per sample from the first command; the cycloid ends at 0.48 s
TABLE_1_JOINT_NOISE_RAD = math.radians(0.5)  # std of the initial joint angles
# Servo-to-servo spread of the position gain: std 3 % of kp per servo (assumed; MX-28 units are not
# identical). With the joint noise, what varies between samples; the settle before each sample erases
# the joint noise alone (the P servos return to the same rest), so without it every sample is equal.
SERVO_KP_SPREAD = 0.03
SETTLE_S = 0.5  # hold the start pose before a Table I sample
WALK_SETTLE_S = 1.0  # stand in `home` before a walk
WALK_JOINT_NOISE_RAD = math.radians(0.5)
ROUGH_START_X = (0.5, 1.5)  # [m] rough start range: past the flat patch (|x|, |y| < 0.3 m) of the map
ROUGH_START_Y = (-1.5, 1.5)


def _steps_per_tick(model: mujoco.MjModel) -> int:
    n = round(C.TICK_S / model.opt.timestep)
    if abs(n * model.opt.timestep - C.TICK_S) > 1e-9:
        raise ValueError(f"tick {C.TICK_S} s is not a multiple of the timestep {model.opt.timestep} s")
    return n


def perturbed_model(model: mujoco.MjModel, rng: np.random.Generator) -> mujoco.MjModel:
    """A copy of `model` with each servo's kp scaled by 1 + N(0, SERVO_KP_SPREAD) (gain and bias)."""
    out = copy.copy(model)
    act = M.actuator_ids(out)
    kp = model.actuator_gainprm[act, 0] * (1.0 + rng.normal(0.0, SERVO_KP_SPREAD, len(act)))
    out.actuator_gainprm[act, 0] = kp
    out.actuator_biasprm[act, 1] = -kp
    return out


# --- Table I ----------------------------------------------------------------------------------------


def leg_tracking_sample(
    displacement_m=(0.05, 0.03),
    seed: int = 0,
    height: float = C.STEP_HEIGHT,
    period_s: float = C.STEP_PERIOD,
    p_t: float = 1.0,
    p_n: float = 1.0,
    model: mujoco.MjModel | None = None,
    duration_s: float | None = None,
) -> dict:
    """One sample of seed 003's experiment 1: the TABLE_1_LEG foot follows the cycloid from its home
    point to home + (dx, dy, 0) [m], height H [m], period T [s], N = T / 20 ms points spaced by P_T,
    P_N, one per tick; the base is welded in the air ("fixed" model), the other legs hold home.

    What varies with `seed`: each servo's kp (`perturbed_model`) and the initial joint angles (home +
    N(0, 0.5 deg) on all 12 joints); each sample first holds the home command for SETTLE_S, so it
    starts from the servos' own rest. The arrival time is interpolated between physics steps.
    -> dict: time_s (first time after the first command that the foot is within
    TABLE_1_ARRIVAL_TOL_M of the final point; NaN if never), apex_m (highest foot point above its
    start), final_x_m / final_y_m (displacement at the end), over duration_s [s] from the first command
    (default TABLE_1_SAMPLE_S, or period_s + 0.5 s for a longer period), and the sampled
    trace t_s (n,), foot_m (n, 3) and the commanded points cmd_m (N, 3), all relative to the start.
    """
    rng = np.random.default_rng(seed)
    model = perturbed_model(M.load_model("fixed") if model is None else model, rng)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, M.home_key(model))
    qadr = M.joint_qposadr(model)
    act = M.actuator_ids(model)
    data.qpos[qadr] += rng.normal(0.0, TABLE_1_JOINT_NOISE_RAD, qadr.shape)
    home = model.key_ctrl[M.home_key(model)].copy()
    data.ctrl[act] = home
    leg = C.LEGS.index(TABLE_1_LEG)
    site = M.name_id(model, mujoco.mjtObj.mjOBJ_SITE, C.foot_name(TABLE_1_LEG))
    n_sub = _steps_per_tick(model)
    for _ in range(round(SETTLE_S / model.opt.timestep)):
        mujoco.mj_step(model, data)

    start_cmd = M.home_feet()[leg]  # hip frame
    land = start_cmd + np.array([displacement_m[0], displacement_m[1], 0.0])
    u = swing.cycloid_tick_times(period_s, p_t, p_n, C.TICK_S) / period_s
    cmd = G.cycloid_points(u, start_cmd, land, height)  # (N, 3) hip frame
    feet = np.repeat(M.home_feet()[None] + C.HIP_POS, len(cmd), axis=0)  # (N, 4, 3) body frame
    feet[:, leg] = cmd + C.HIP_POS[leg]
    targets = [np.asarray(G.stabilized_joint_targets(f, np.zeros(2))[0]).ravel() for f in feet]

    foot0 = data.site_xpos[site].copy()
    if duration_s is None:
        duration_s = max(TABLE_1_SAMPLE_S, period_s + 0.5)
    n_steps = round(duration_s / model.opt.timestep)
    trace = np.empty((n_steps + 1, 3))
    trace[0] = 0.0
    for s in range(n_steps):
        k = s // n_sub
        if s % n_sub == 0:
            data.ctrl[act] = targets[min(k, len(targets) - 1)]
        mujoco.mj_step(model, data)
        trace[s + 1] = data.site_xpos[site] - foot0
    t = np.arange(n_steps + 1) * model.opt.timestep
    goal = cmd[-1] - cmd[0]
    dist = np.linalg.norm(trace - goal, axis=-1)
    near = dist <= TABLE_1_ARRIVAL_TOL_M
    near[t < 0.5 * period_s] = False  # the start of a short move may lie within the tolerance
    arrival = float("nan")
    if near.any():
        i = int(np.argmax(near))  # first step within the tolerance; interpolate the crossing linearly
        a, b = dist[i - 1], dist[i]
        arrival = float(t[i - 1] + (t[i] - t[i - 1]) * (a - TABLE_1_ARRIVAL_TOL_M) / max(a - b, 1e-12))
    return {
        "time_s": arrival,
        "apex_m": float(trace[:, 2].max()),
        "final_x_m": float(trace[-1, 0]),
        "final_y_m": float(trace[-1, 1]),
        "t_s": t,
        "foot_m": trace,
        "cmd_m": cmd - cmd[0],
    }


def _summary(samples: list[dict], keys) -> dict:
    if not samples:  # a mean over no sample is NaN: a table of NaN
        raise ValueError("a summary needs at least one sample (n_samples >= 1)")
    out = {"n": len(samples)}
    for k in keys:
        v = np.array([s[k] for s in samples], float)
        out[k] = (float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0)
    return out


def table_1(n_samples: int = 30) -> dict:
    """Seed 003 Table I: Tests 1 and 2 (displacements (0.05, 0.03) and (0.03, 0.05) m), mean and
    sample std over n_samples seeds -> {"test1": {...}, "test2": {...}}."""
    model = M.load_model("fixed")
    out = {}
    for name, paper in PAPER_TABLE_1.items():
        samples = [
            leg_tracking_sample(paper["displacement_m"], seed=i, model=model) for i in range(n_samples)
        ]
        out[name] = _summary(samples, ("time_s", "apex_m", "final_x_m", "final_y_m"))
    return out


# --- Tables II and III --------------------------------------------------------------------------------


def _ground_height(model, data, xy) -> float:
    """Highest ground under the (k, 2) world points [m] (ray cast down from 1 m onto geom group 0, the
    floor's; the robot's geoms are in groups 2 and 3; 0 if none hit)."""
    geomid = np.zeros(1, np.int32)
    floor_only = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    top = 0.0
    for x, y in xy:
        d = mujoco.mj_ray(
            model, data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]), floor_only, 1, -1, geomid
        )
        if d >= 0:
            top = max(top, 1.0 - d)
    return top


def walk_sample(
    scene: str = "flat",
    command=(0.05, 0.0, 0.0),
    pid: bool = False,
    policy=None,
    seed: int = 0,
    distance_m: float = 1.5,
    turn_rad: float = 2.0 * math.pi,
    max_time_s: float = 90.0,
    height: float = C.STEP_HEIGHT,
    p_t: float = C.TROT_P_T,
    p_n: float = C.TROT_P_N,
) -> dict:
    """One walk of seed 003's experiments 2 and 3: the discontinuous trot with `command` (vx [m/s], vy
    [m/s], yaw_rate [rad/s]) until the base has travelled distance_m along its start heading (a
    forward command) or turned turn_rad (a turning command: |vx|, |vy| zero), or max_time_s.

    pid: seed 003's roll / pitch stabilizer (stabilizer.pid_step at 50 Hz on the IMU's roll and
    pitch; its output tilts the feet about the body centre before IK, gait.tilt_feet).
    policy: None (seed 003's planner, trot_feet) or a `policy_driver`: every tick it maps the state,
    tick and command to the 12 joint targets as the training environment does.
    What varies with `seed`: each servo's kp (`perturbed_model`), the initial joint angles (home +
    N(0, 0.5 deg)) and, on the rough
    scene, the start point, uniform in ROUGH_START_X x ROUGH_START_Y (on flat ground, in +-0.5 m).
    The robot is placed with its feet just above the ground and stands WALK_SETTLE_S in `home`.
    -> dict: velocity_mps (travel along the start heading / time), yaw_rate_radps (yaw turned / time),
    roll_deg / pitch_deg (max - min of the IMU's roll / pitch at the 50 Hz ticks, seed 003's
    oscillation), time_s, fell (tilt over 45 deg or base below 0.08 m), invalid_ticks (ticks with a
    foot target out of reach or limits; the servos get the clipped angles).
    """
    if pid and policy is not None:
        raise ValueError("walk_sample drives the planner with the PID or the policy, not both")
    rng = np.random.default_rng(seed)
    model = perturbed_model(M.load_model(scene), rng)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, M.home_key(model))
    qadr = M.joint_qposadr(model)
    act = M.actuator_ids(model)
    data.qpos[qadr] += rng.normal(0.0, WALK_JOINT_NOISE_RAD, qadr.shape)
    if scene == "rough":
        xy = np.array([rng.uniform(*ROUGH_START_X), rng.uniform(*ROUGH_START_Y)])
    else:
        xy = rng.uniform(-0.5, 0.5, 2)
    data.qpos[:2] = xy
    mujoco.mj_forward(model, data)
    feet_xy = xy + G.nominal_feet()[:, :2]
    ground = _ground_height(model, data, np.concatenate([feet_xy, feet_xy + 0.01, feet_xy - 0.01]))
    data.qpos[2] = ground + M.HOME_BASE_HEIGHT + 0.003
    data.ctrl[act] = model.key_ctrl[M.home_key(model)]
    for _ in range(round(WALK_SETTLE_S / model.opt.timestep)):
        mujoco.mj_step(model, data)

    n_sub = _steps_per_tick(model)
    n_ticks = round(max_time_s / C.TICK_S)
    feet = G.trot_feet(n_ticks, command, height=height, p_t=p_t, p_n=p_n) if policy is None else None
    pid_state = stabilizer.pid_init()
    pid_step = _jitted_pid_step()
    start_pos = data.qpos[:2].copy()
    yaw0 = quat_to_rpy(data.qpos[3:7])[2]
    heading = np.array([math.cos(yaw0), math.sin(yaw0)])
    turning = command[0] == 0.0 and command[1] == 0.0
    rolls, pitches = [], []
    yaw_prev, yaw_turned, travel = yaw0, 0.0, 0.0
    invalid, fell, k = 0, False, 0
    for k in range(n_ticks):
        r, p, y = quat_to_rpy(data.qpos[3:7])
        rolls.append(r)
        pitches.append(p)
        yaw_turned += (y - yaw_prev + math.pi) % (2 * math.pi) - math.pi
        yaw_prev = y
        travel = float((data.qpos[:2] - start_pos) @ heading)
        if abs(r) > math.radians(45) or abs(p) > math.radians(45) or data.qpos[2] - ground < 0.08:
            fell = True
            break
        if (turning and abs(yaw_turned) >= turn_rad) or (not turning and travel >= distance_m):
            break
        if policy is not None:
            ctrl, n_invalid = policy(data.qpos, data.qvel, k, command)
            invalid += int(n_invalid > 0)
            data.ctrl[:] = ctrl
        else:
            u = np.zeros(2)
            if pid:
                pid_state, u = pid_step(pid_state, np.array([r, p]))
            q, valid = G.stabilized_joint_targets(feet[k], np.asarray(u))
            invalid += int(not bool(np.all(valid)))
            data.ctrl[act] = np.asarray(q).ravel()
        for _ in range(n_sub):
            mujoco.mj_step(model, data)
    time_s = max(k, 1) * C.TICK_S
    return {
        "velocity_mps": travel / time_s,
        "yaw_rate_radps": yaw_turned / time_s,
        "roll_deg": math.degrees(max(rolls) - min(rolls)),
        "pitch_deg": math.degrees(max(pitches) - min(pitches)),
        "time_s": time_s,
        "fell": fell,
        "invalid_ticks": invalid,
    }


def policy_driver(run_dir, checkpoint=None):
    """A training run's policy as walk_sample's `policy`: (qpos, qvel, tick k, command) -> (ctrl (nu,),
    number of legs whose target was clamped). The observation, the gait at tick k (gait progress
    k ctrl_dt / cycle, the start ramp), the offsets and the IK are the environment's own
    (LocomotionEnv.observation and its motor targets), without sensor noise; the action is the
    policy's mean. Raises ValueError for a run of another robot or another control period."""
    from quadson_mjx import training
    from quadson_mjx.config import apply_overrides
    from quadson_mjx.env import LocomotionEnv
    from quadson_mjx.env_config import with_added_keys

    policy, env_cfg, _, _ = training.load_policy(run_dir, checkpoint)
    env_cfg = with_added_keys(env_cfg)
    if env_cfg.robot != "caramel" or abs(env_cfg.ctrl_dt - C.TICK_S) > 1e-12:
        raise ValueError(
            f"{run_dir}: a {env_cfg.robot} run at {env_cfg.ctrl_dt} s; need caramel at {C.TICK_S} s"
        )
    env = LocomotionEnv(apply_overrides(env_cfg, ["randomize=False"]))  # no sensor noise
    cycle_s = float(env.gait_params.cycle_s)

    @jax.jit
    def step(qpos, qvel, tick, command):
        time_s = tick * env.ctrl_dt
        info = {
            "gait_progress": jax.numpy.mod(time_s / cycle_s, 1.0),
            "episode_time": time_s,
            "command": command,
        }
        action = jax.numpy.clip(policy(env.observation(qpos, qvel, info), jax.random.PRNGKey(0))[0], -1, 1)
        ctrl, n_invalid, _, _ = env._motor_targets(info, action)
        return ctrl, n_invalid

    def drive(qpos, qvel, tick, command):
        ctrl, n_invalid = step(
            np.asarray(qpos, np.float32), np.asarray(qvel, np.float32), tick, np.asarray(command, np.float32)
        )
        return np.asarray(ctrl, np.float64), int(n_invalid)

    return drive


POLICY_ROWS = {  # name -> (table, scene, command) of seed 003's walks, driven by a policy
    "flat_policy": ("table_2", "flat", (0.05, 0.0, 0.0)),
    "rough_policy": ("table_2", "rough", (0.05, 0.0, 0.0)),
    "turn_rough_policy": ("table_3", "rough", (0.0, 0.0, 0.25)),
}


def policy_rows(policy, n_samples: int = 10, **kw) -> dict:
    """Tables II and III's walks driven by `policy` (policy_driver), seeds 0..n_samples - 1 as the
    planner's rows -> {"table_2": {"flat_policy", "rough_policy"}, "table_3": {"rough_policy"}}."""
    out = {"table_2": {}, "table_3": {}}
    for name, (table, scene, command) in POLICY_ROWS.items():
        samples = [walk_sample(scene, command, policy=policy, seed=i, **kw) for i in range(n_samples)]
        key = "velocity_mps" if table == "table_2" else "yaw_rate_radps"
        row = _summary(samples, (key, "roll_deg", "pitch_deg", "time_s"))
        row["fell"] = int(sum(s["fell"] for s in samples))
        row["invalid_ticks"] = int(sum(s["invalid_ticks"] for s in samples))
        out[table][name.replace("turn_", "")] = row
    return out


@functools.cache
def _jitted_pid_step():
    return jax.jit(stabilizer.pid_step)


def table_2(n_samples: int = 10, **kw) -> dict:
    """Seed 003 Table II: forward 0.05 m/s on flat and rough ground, without and with the PID."""
    out = {}
    for name in PAPER_TABLE_2:
        scene, pid = name.split("_")[0], name.endswith("_pid")
        samples = [walk_sample(scene, (0.05, 0.0, 0.0), pid, seed=i, **kw) for i in range(n_samples)]
        out[name] = _summary(samples, ("velocity_mps", "roll_deg", "pitch_deg", "time_s"))
        out[name]["fell"] = int(sum(s["fell"] for s in samples))
        out[name]["invalid_ticks"] = int(sum(s["invalid_ticks"] for s in samples))
    return out


def table_3(n_samples: int = 10, **kw) -> dict:
    """Seed 003 Table III: turn in place at 0.25 rad/s on rough ground, without and with the PID."""
    out = {}
    for name in PAPER_TABLE_3:
        pid = name.endswith("_pid")
        samples = [walk_sample("rough", (0.0, 0.0, 0.25), pid, seed=i, **kw) for i in range(n_samples)]
        out[name] = _summary(samples, ("yaw_rate_radps", "roll_deg", "pitch_deg", "time_s"))
        out[name]["fell"] = int(sum(s["fell"] for s in samples))
        out[name]["invalid_ticks"] = int(sum(s["invalid_ticks"] for s in samples))
    return out
