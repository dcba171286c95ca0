"""Can Quadson roll off its back dynamically? A search for open-loop motor motions that do, in MuJoCo C.

    python -m quadson_mjx.getup_rollover --rollouts 1024 --json back_rollover.json

getup_reach proves the quasi-static case: lying flat on its back, the legs reach 12.6 mm past the
top plate and shift the centre of mass 13 mm sideways, nothing near the 63 deg turn or the 80 mm
edge it takes to roll over. It does not cover fast leg swings, whose reaction torques can rock the
body. This module looks for such motions with the physics of sim2sim's plant (quadson_mjx.
sim2sim_plant: 2 ms MuJoCo C, every leg geom and the base touching the ground, the servo model with
its 3.44 N m peak, torque-speed line, deadband and 20 ms latency), driven open loop:

* a motion: K knots of the 12 get-up actions in [-1, 1], each held MOTION_S / K (zero-order hold,
  so a knot may swing a motor at the servo's full speed), every tick's target the get-up task's
  `chain_guard.getup_targets` (limits, toe-in guard, chain guard), so every target is one the robot
  may be sent; then the last target held HOLD_S;
* its score: the smallest tilt of the base (body z against world z) [deg] over the motion and the
  hold, sampled every control tick (0.02 s); lower is better (180 flat on the back, 0 upright);
  180 for a motion whose physics is not credible at some tick (a contact sunk deeper than
  PENETRATION_MAX_M, a five-bar opened wider than CLOSURE_MAX_M): without that check the search
  finds leg slams that sink a foot up to 32 mm into the floor and open the chain by 2-4 mm, and
  whose roll-over vanishes when the actions move by 1e-4;
* the search: the cross-entropy method (Gaussian over the K x 12 actions, clipped to [-1, 1], the
  mean as one member, the best fifth of each population refits it);
* starts (`starts`): flat on the back (roll 180 deg) on the home stance and on poses of
  getup_start's back class (roll and pitch spread +-20 deg, motor angles drawn as the task's),
  placed 2 mm above the ground and settled SETTLE_S, holding the pose; and a sweep of releases at
  rest at roll 90 ... 180 deg on the home stance, the motion starting at the release (the positive
  control: from the side the trained policy stands the robot up, and away from the back there are
  no resting poses, so these fall as they move);
* the robot's servos, and stronger ones (peak torque doubled, no speed limit) as a sensitivity bound.
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing
import sys
import time

import mujoco
import numpy as np

from quadson_mjx import sim2sim_plant as P
from quadson_mjx.deploy_supervisor import tilt
from quadson_mjx.quat import axis_quat
from quadson_mjx.robots import get_robot
from quadson_mjx.robots.quadson import chain_guard
from quadson_mjx.robots.quadson import model as quadson_model

DT = 0.02  # control period [s], the get-up task's
MOTION_S, HOLD_S, SETTLE_S = 2.0, 1.0, 1.0  # [s]
KNOTS = 8
CLEARANCE_M = 0.002  # a start's lowest point above the ground when placed [m]
SWEEP_DEG = (90.0, 110.0, 130.0, 150.0, 165.0, 180.0)
ELITE_SHARE, STD0, STD_MIN = 0.2, 0.6, 0.05  # CEM: elites, initial and smallest std (action units)
# a motion counts only while its physics stays as credible as a real get-up's at every tick: the
# committed get-up policy standing the robot up in MuJoCo C after a shove (8 knock-downs,
# results/getup_h100/knockdown_contact_depth.log) sank a contact up to 13.5 mm and opened a five-bar
# up to 1.18 mm; a body at rest sinks 0.03 mm and its chains stay closed [m]
PENETRATION_MAX_M, CLOSURE_MAX_M = 0.015, 0.0015
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclasses.dataclass(frozen=True)
class Start:
    name: str
    qpos: np.ndarray  # (nq,) placed CLEARANCE_M above the ground, chains closed
    angles: np.ndarray  # (12,) the motor pose held while settling and at the motion's start [rad]
    settle_s: float  # held this long before the motion (0: released at rest when it starts) [s]


def place(mj_model, quat, angles, settle_s: float, name: str) -> Start:
    """A Start at orientation quat (4,) wxyz with motor angles (4, 3) [rad]: the knees from the
    five-bar FK, the lowest collision point CLEARANCE_M above z = 0 (getup_start.lowest_point)."""
    import jax.numpy as jnp

    from quadson_mjx.robots.quadson import fivebar, getup_start

    ids = quadson_model.model_ids(mj_model)
    a = np.asarray(angles, np.float64).reshape(4, 3)
    pts = fivebar.leg_points(jnp.asarray(a))
    qpos = np.zeros(mj_model.nq)
    qpos[3:7] = np.asarray(quat, np.float64) / np.linalg.norm(quat)
    qpos[ids.motor_qposadr] = a.ravel()
    qpos[ids.passive_qposadr] = np.stack([np.asarray(pts.knee2), np.asarray(pts.knee4)], -1).ravel()
    qpos[2] = CLEARANCE_M - float(getup_start.lowest_point(jnp.asarray(qpos[3:7]), jnp.asarray(a)))
    return Start(name, qpos, a.ravel(), settle_s)


def starts(mj_model, back_draws: int = 3, seed: int = 0) -> dict[str, list[Start]]:
    """{"back": home at roll 180 and `back_draws` draws of getup_start's back class, settled;
    "sweep": home released at rest at each roll of SWEEP_DEG}."""
    import jax

    from quadson_mjx.robots.quadson import getup_start

    home = quadson_model.home_motor_angles()
    flip = lambda deg: axis_quat(0, math.radians(deg))  # noqa: E731 (roll > 90: right side lower)
    back = [place(mj_model, flip(180.0), home, SETTLE_S, "back_home")]
    if back_draws:
        cfg = getup_start.StartConfig(class_weights=(1.0, 0.0, 0.0, 0.0, 0.0))
        keys = jax.random.split(jax.random.key(seed), back_draws)
        s = jax.tree.map(np.asarray, jax.jit(jax.vmap(getup_start.start_sampler(mj_model, cfg)))(keys))
        for i in range(back_draws):  # the draw's orientation (roll, pitch +-20 deg, yaw) and pose
            back.append(place(mj_model, s.qpos[i, 3:7], s.motor_angles[i], SETTLE_S, f"back_draw{i}"))
    sweep = [place(mj_model, flip(deg), home, 0.0, f"roll{deg:g}") for deg in SWEEP_DEG]
    return {"back": back, "sweep": sweep}


def make_plant(strong: bool = False) -> P.Plant:
    """sim2sim's plant on flat ground, sensors off; strong: peak torque x2 and no speed limit."""
    robot = get_robot("quadson")
    servo = P.ServoParams(peak_scale=2.0 if strong else 1.0)
    plant = P.Plant(robot, P.plant_model(robot, "flat"), servo, P.SensorParams(enabled=False))
    if strong:
        plant.no_load_speed = None
    return plant


def motion_targets(actions) -> tuple[np.ndarray, np.ndarray]:
    """actions (K, 12) in [-1, 1] -> (targets (T, 12) [rad] per control tick over MOTION_S + HOLD_S,
    the knots held in turn then the last; guarded (T, 4) bool: legs the chain guard moved)."""
    a = np.clip(np.asarray(actions, np.float64), -1.0, 1.0)
    ticks, total = int(round(MOTION_S / DT)), int(round((MOTION_S + HOLD_S) / DT))
    knot = np.minimum(np.arange(total) * len(a) // ticks, len(a) - 1)
    home = quadson_model.home_motor_angles().ravel()
    return chain_guard.getup_targets(a[knot], home)


def settle(plant: P.Plant, start: Start) -> np.ndarray:
    """The start placed and held settle_s on plant -> MuJoCo's integration state."""
    m, d = plant.m, plant.d
    plant.reset()
    mujoco.mj_resetData(m, d)
    d.qpos[:] = start.qpos
    mujoco.mj_forward(m, d)
    plant.targets = start.angles.copy()
    if start.settle_s > 0:
        plant.advance(start.settle_s)
    state = np.zeros(mujoco.mj_stateSize(m, _STATE))
    mujoco.mj_getState(m, d, state, _STATE)
    return state


def rollout(plant: P.Plant, state: np.ndarray, start: Start, targets: np.ndarray) -> np.ndarray:
    """targets (T, 12) sent one per tick from the settled state -> tilt (T + 1,) [deg], from the start."""
    return rollout_checked(plant, state, start, targets)[0]


def rollout_checked(plant: P.Plant, state: np.ndarray, start: Start, targets: np.ndarray, on_tick=None):
    """rollout, and at every tick the deepest contact penetration and the largest five-bar closure
    residual -> (tilt (T + 1,) [deg], deepest penetration [m] (>= 0), largest residual [m]).
    on_tick: None or a function of MjData called after every tick."""
    m, d = plant.m, plant.d
    plant.reset()  # empties the latency queue
    mujoco.mj_setState(m, d, state, _STATE)
    mujoco.mj_forward(m, d)
    plant.targets = start.angles.copy()
    out, depth, gap = [tilt(d.qpos[3:7])], 0.0, 0.0
    for tgt in targets:
        plant.send(tgt)
        plant.advance(DT)
        out.append(tilt(d.qpos[3:7]))
        if d.ncon:
            depth = max(depth, -float(d.contact.dist[: d.ncon].min()))
        gap = max(gap, float(quadson_model.closure_residual(m, d).max()))
        if on_tick is not None:
            on_tick(d)
    return np.degrees(out), depth, gap


def physical(depth: float, gap: float) -> bool:
    """A tick's physics as credible as a real get-up's (PENETRATION_MAX_M, CLOSURE_MAX_M)."""
    return depth <= PENETRATION_MAX_M and gap <= CLOSURE_MAX_M


def replay(plant: P.Plant, start: Start, actions, video=None) -> dict:
    """One motion (K, 12) from `start`, checked tick by tick (0.02 s): the tilt [deg], the deepest
    contact penetration (MuJoCo's contact distance, negative inside) [m], the fastest motor
    [rad/s] and the five-bar closure residual [m], so that a roll-over found by the search can be
    told from a contact or constraint artefact; video: None or an .mp4/.gif path rendered at the
    control rate from a camera tracking the base."""
    ids = quadson_model.model_ids(plant.m)
    targets, guarded = motion_targets(actions)
    speed = [0.0]
    writer = renderer = None
    if video is not None:
        from quadson_mjx.video import Renderer, VideoWriter

        writer = VideoWriter(video, 640, 480, 1.0 / DT)
        renderer = Renderer(plant.m, 640, 480)

    def on_tick(d):
        speed[0] = max(speed[0], float(np.abs(d.qvel[ids.motor_dofadr]).max()))
        if writer is not None:
            writer.write(renderer.render(d.qpos))

    try:
        tilts, depth, gap = rollout_checked(plant, settle(plant, start), start, targets, on_tick)
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    if writer is not None:
        writer.close()
    return {
        "start": start.name,
        "tilt_deg": np.round(tilts, 1).tolist(),
        "min_tilt_deg": round(float(tilts.min()), 2),
        "final_tilt_deg": round(float(tilts[-1]), 2),
        "deepest_penetration_mm": round(1000.0 * depth, 2),
        "fastest_motor_rad_s": round(speed[0], 2),
        "largest_closure_residual_mm": round(1000.0 * gap, 3),
        "guarded_share": float(guarded.mean()),
    }


_WORKER: dict = {}  # per process: plants by strength, settled states by (start, strength)


def evaluate(job) -> np.ndarray:
    """(start, strong, actions (n, K, 12)) -> (n, 3): smallest tilt [deg] (180 when the motion is
    not physical: a contact sank deeper than PENETRATION_MAX_M or a five-bar opened more than
    CLOSURE_MAX_M at some tick), final tilt [deg], 1.0 if physical else 0.0."""
    start, strong, actions = job
    plant = _WORKER.get(strong) or _WORKER.setdefault(strong, make_plant(strong))
    key = (start.name, strong)
    if key not in _WORKER:
        _WORKER[key] = settle(plant, start)
    rows = []
    for a in actions:
        tilts, depth, gap = rollout_checked(plant, _WORKER[key], start, motion_targets(a)[0])
        ok = physical(depth, gap)
        rows.append((tilts.min() if ok else 180.0, tilts[-1], float(ok)))
    return np.asarray(rows)


def search(
    start: Start,
    strong: bool,
    rollouts: int,
    pop: int,
    seed: int,
    pool=None,
    workers: int = 1,
    knots: int = KNOTS,
) -> dict:
    """The cross-entropy search (module docstring) from `start`: rollouts // pop populations of pop.
    pool: None or a multiprocessing pool of `workers` processes. -> the record of the search (best motion, its tilt trace,
    counts of rollouts that got below 90 and 30 deg, and of those the physics checks refused)."""
    rng = np.random.default_rng(seed)
    t0, dim, n_elite = time.perf_counter(), knots * 12, max(2, int(round(ELITE_SHARE * pop)))
    mean, std = np.zeros(dim), np.full(dim, STD0)
    best_f, best_x, history, scores = math.inf, None, [], []
    for _ in range(max(1, rollouts // pop)):
        x = np.clip(mean + std * rng.standard_normal((pop, dim)), -1.0, 1.0)
        x[0] = mean
        jobs = [
            (start, strong, c.reshape(-1, knots, 12))
            for c in np.array_split(x, workers if pool is not None else 1)
        ]
        f = np.concatenate(pool.map(evaluate, jobs) if pool is not None else [evaluate(j) for j in jobs])
        scores.append(f)
        order = np.argsort(f[:, 0])
        if f[order[0], 0] < best_f:
            best_f, best_x = float(f[order[0], 0]), x[order[0]].copy()
        elite = x[order[:n_elite]]
        mean, std = elite.mean(0), np.maximum(elite.std(0), STD_MIN)
        history.append(round(best_f, 2))
    scores = np.concatenate(scores)
    plant = make_plant(strong)
    targets, guarded = motion_targets(best_x.reshape(knots, 12))
    trace = rollout(plant, settle(plant, start), start, targets)
    return {
        "start": start.name,
        "servos": "stronger (peak x2, no speed limit)" if strong else "robot",
        "placed_tilt_deg": round(math.degrees(tilt(start.qpos[3:7])), 2),
        "rest_tilt_deg": round(float(trace[0]), 2),
        "rollouts": int(len(scores)),
        "min_tilt_deg": round(best_f, 2),
        "best_final_tilt_deg": round(float(trace[-1]), 2),
        "rollouts_below_90_deg": int(np.sum(scores[:, 0] < 90.0)),
        "rollouts_below_30_deg": int(np.sum(scores[:, 0] < 30.0)),
        "rollouts_ending_below_30_deg": int(np.sum((scores[:, 1] < 30.0) & (scores[:, 2] > 0))),
        "rollouts_unphysical": int(np.sum(scores[:, 2] == 0)),
        "best_per_population_deg": history,
        "best_trace_deg": np.round(trace, 1).tolist(),
        "best_actions": best_x.reshape(knots, 12).tolist(),  # full precision: replays reproduce it
        "best_guarded_share": float(guarded.mean()),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def run(rollouts: int, pop: int, seed: int, workers: int, back_draws: int, log=print) -> dict:
    """Every search: the back starts and the sweep, each with the robot's and the stronger servos."""
    robot = get_robot("quadson")
    groups = starts(P.plant_model(robot, "flat"), back_draws, seed)
    ctx = multiprocessing.get_context("spawn")  # JAX ran in this process: no fork
    pool = ctx.Pool(workers) if workers > 1 else None
    records, t0 = [], time.perf_counter()
    try:
        for group in ("back", "sweep"):
            for strong in (False, True):
                for start in groups[group]:
                    r = search(start, strong, rollouts, pop, seed + 1000 * len(records), pool, workers)
                    records.append(r | {"group": group})
                    log(
                        f"{group:5s} {start.name:10s} {'strong' if strong else 'robot ':6s} rest"
                        f" {r['rest_tilt_deg']:6.1f} deg -> min {r['min_tilt_deg']:6.1f} deg (end"
                        f" {r['best_final_tilt_deg']:6.1f}), below 90/30: {r['rollouts_below_90_deg']}/"
                        f"{r['rollouts_below_30_deg']} of {r['rollouts']}, {r['wall_s']:.0f} s"
                    )
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    summary = {}
    for strong in (False, True):
        sweep = [r for r in records if r["group"] == "sweep" and (r["servos"] == "robot") != strong]
        rolled = [float(r["start"][4:]) for r in sweep if r["min_tilt_deg"] < 30.0]
        summary["stronger" if strong else "robot"] = {
            "sweep_min_tilt_deg": {r["start"]: r["min_tilt_deg"] for r in sweep},
            "largest_start_rolled_below_30_deg": max(rolled) if rolled else None,
            "back_min_tilt_deg": min(
                r["min_tilt_deg"]
                for r in records
                if r["group"] == "back" and (r["servos"] == "robot") != strong
            ),
        }
    settings = {"dt_s": DT, "motion_s": MOTION_S, "hold_s": HOLD_S, "settle_s": SETTLE_S, "knots": KNOTS}
    settings |= {"population": pop, "rollouts_per_search": rollouts, "seed": seed, "back_draws": back_draws}
    settings |= {"elite_share": ELITE_SHARE, "std0": STD0, "std_min": STD_MIN}
    return {
        "settings": settings,
        "summary": summary,
        "wall_s": round(time.perf_counter() - t0, 1),
        "searches": records,
    }


PERTURB, PERTURB_N = 0.01, 8  # replays' robustness check: uniform +-0.01 on every action, 8 draws


def perturbed(plant: P.Plant, start: Start, actions, seed: int = 0) -> list[float]:
    """The smallest tilt [deg] of PERTURB_N copies of the motion with every action moved by
    U(-PERTURB, PERTURB) (about 1 % of a motor's range): a roll-over a robot could repeat survives
    errors of that size; 180 where the physics checks refuse the copy."""
    rng = np.random.default_rng(seed)
    a = np.asarray(actions, np.float64)
    state, out = settle(plant, start), []
    for _ in range(PERTURB_N):
        noisy = a + rng.uniform(-PERTURB, PERTURB, a.shape)
        tilts, depth, gap = rollout_checked(plant, state, start, motion_targets(noisy)[0])
        ok = physical(depth, gap)
        out.append(round(float(tilts.min()), 1) if ok else 180.0)
    return out


def replay_report(path, out=None, video=None, log=print) -> int:
    """--replay: every search of the report at `path` whose best motion got below 90 deg, replayed
    from its start with `replay`'s checks; of the starts flat on the back (settled or released),
    the one whose best motion ends least tilted with the robot's servos is rendered to `video`. Writes {"report", "replays"} to `out`."""
    from quadson_mjx.errors import UsageError, check_readable, write_text_atomic

    check_readable(path, "--replay")
    try:
        report = json.loads(open(path).read())
        settings, searches = report["settings"], report["searches"]
        seed, draws = int(settings["seed"]), int(settings["back_draws"])
    except (ValueError, KeyError, TypeError) as e:
        raise UsageError(f"--replay {path}: not a report of this module ({e})") from None
    if settings.get("knots") != KNOTS or settings.get("dt_s") != DT or settings.get("motion_s") != MOTION_S:
        raise UsageError(f"--replay {path}: made with other motion settings than this version's")
    robot = get_robot("quadson")
    groups = starts(P.plant_model(robot, "flat"), draws, seed)
    by_name = {s.name: s for g in groups.values() for s in g}
    chosen = [r for r in searches if r["min_tilt_deg"] < 90.0]
    flat_on_back = [r for r in chosen if r["servos"] == "robot" and r["placed_tilt_deg"] >= 179.0]
    film = min(flat_on_back, key=lambda r: r["best_final_tilt_deg"], default=None)
    if video is not None and film is None:
        raise UsageError(
            f"--video: no start flat on the back in {path} got below 90 deg with the robot's servos"
        )
    rows = []
    for r in chosen:
        strong = r["servos"] != "robot"
        row = replay(
            make_plant(strong),
            by_name[r["start"]],
            np.asarray(r["best_actions"]),
            video if r is film else None,
        )
        row |= {"servos": r["servos"], "group": r["group"], "search_min_tilt_deg": r["min_tilt_deg"]}
        row["perturbed_min_tilt_deg"] = perturbed(make_plant(strong), by_name[r["start"]], r["best_actions"])
        rows.append(row)
        log(
            f"{r['group']:5s} {r['start']:10s} {'strong' if strong else 'robot ':6s} min tilt"
            f" {row['min_tilt_deg']:6.1f} deg (search {r['min_tilt_deg']:6.1f}), end {row['final_tilt_deg']:6.1f},"
            f" deepest contact {row['deepest_penetration_mm']:.2f} mm, fastest motor"
            f" {row['fastest_motor_rad_s']:.1f} rad/s, closure {row['largest_closure_residual_mm']:.3f} mm,"
            f" perturbed +-{PERTURB}: median min tilt {np.median(row['perturbed_min_tilt_deg']):.1f} deg"
        )
    if out is not None:
        write_text_atomic(out, json.dumps({"report": str(path), "replays": rows}, indent=1) + "\n")
    return 0


def main(argv=None) -> int:
    from quadson_mjx.errors import (
        ArgumentParser,
        UsageError,
        check_writable,
        one_line_errors,
        write_text_atomic,
    )

    @one_line_errors
    def cli(argv) -> int:
        p = ArgumentParser(prog="python -m quadson_mjx.getup_rollover", description=__doc__.split("\n\n")[0])
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--rollouts", type=int, default=1024, help="rollouts per search")
        p.add_argument("--pop", type=int, default=32, help="CEM population")
        p.add_argument("--back-draws", type=int, default=3, help="starts drawn from the back class")
        p.add_argument("--workers", type=int, default=2, help="processes (1: none)")
        p.add_argument("--json", default=None, help="write the report here")
        p.add_argument(
            "--replay",
            default=None,
            metavar="REPORT",
            help="replay the best motion of each search in REPORT (a --json report) that got below 90 deg, "
            "with its contact, speed and closure checks, instead of searching",
        )
        p.add_argument(
            "--video", default=None, help="with --replay: render the best motion flat on the back (.mp4/.gif)"
        )
        a = p.parse_args(argv)
        if a.video is not None and a.replay is None:
            raise UsageError("--video renders a replay: give --replay REPORT")
        if a.replay is not None:
            if a.json is not None:
                check_writable(a.json, "--json")
            if a.video is not None:
                from quadson_mjx.video import check_video_path

                check_video_path(a.video)
            return replay_report(a.replay, a.json, a.video)
        if a.pop < 4 or a.rollouts < a.pop:
            raise UsageError(f"--pop {a.pop}, --rollouts {a.rollouts}: need pop >= 4 and rollouts >= pop")
        if a.workers < 1 or a.back_draws < 0 or a.seed < 0:
            raise UsageError(
                f"--workers {a.workers}, --back-draws {a.back_draws}, --seed {a.seed}: need"
                " workers >= 1, back draws >= 0, seed >= 0"
            )
        if a.json is not None:
            check_writable(a.json, "--json")
        print("command: python -m quadson_mjx.getup_rollover " + " ".join(argv), flush=True)
        report = run(a.rollouts, a.pop, a.seed, a.workers, a.back_draws, log=lambda s: print(s, flush=True))
        report["command"] = "python -m quadson_mjx.getup_rollover " + " ".join(argv)
        print(json.dumps(report["summary"], indent=1))
        print(f"wall {report['wall_s']:.0f} s")
        if a.json is not None:
            write_text_atomic(a.json, json.dumps(report, indent=1) + "\n")
        return 0

    return cli(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    raise SystemExit(main())
