"""Caramel's discontinuous trot (seed 003 section II-B/C) and body kinematics for the stabilizer.

The planner runs at 50 Hz in phases of T = 0.5 s (N = 25 ticks each), cycling
    swing FR + RL -> body shift -> swing FL + RR -> body shift
(seed 003 Fig. 2: "the robot's body moves only when all the legs are on the ground"; robots.md lists
the cycle from a body shift, we start it with a swing so that the first step is a half step from the
standing pose). Every phase replays seed 003's N trajectory points one per tick, spaced by P_T / P_N
(`swing.cycloid_tick_times`). Swing: the cycloid of seed 003 eq. 1-4 (`swing.cycloid_swing`) from
the lift-off point to the landing point, height H. Body shift: all four feet stay on the ground and
the body moves along the same cycloid profile (height 0) by one shift of the body twist
(vx, vy, yaw_rate) x 2T: the average body velocity over a 4T cycle is the command.

Landing point of a swinging foot (body frame): R(theta) p + t, with p its nominal foot (under the
leg plane, STANCE_HEIGHT below the hip), t = (vx, vy) 2T and theta = yaw_rate 2T one shift's
translation and yaw: after the next shift it is at p, after the one after at R(-theta)(p - t).

Frames: feet are (..., 4, 3) in the body frame [m] (x forward, y left, z up, origin at the hips'
centre); joint angles (..., 4, 3) serial.py's q [rad], leg order constants.LEGS.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import gait as base_gait
from quadson_mjx import pose, serial, swing
from quadson_mjx.robots.caramel import constants as C

PHASES_PER_CYCLE = 4  # swing A, shift, swing B, shift
_SWING_PAIRS = tuple(np.array([leg in pair for leg in C.LEGS]) for pair in C.TROT_PAIRS)  # (4,) masks


def nominal_feet() -> np.ndarray:
    """(4, 3) nominal feet in the body frame [m]: (hip x, hip y + side L1, -STANCE_HEIGHT)."""
    off = np.stack([np.zeros(4), C.SIDE * C.LEG.hip_offset, np.full(4, -C.STANCE_HEIGHT)], axis=-1)
    return C.HIP_POS + off


def _rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def cycloid_points(u: np.ndarray, lift: np.ndarray, land: np.ndarray, height: float) -> np.ndarray:
    """swing.cycloid_swing in Caramel's z-up frame: u (n,), lift, land (..., 3) -> (n, ..., 3).

    swing.py's curves lift along its frame's +y; swapping y and z (its own inverse) maps ours onto it.
    """
    perm = [0, 2, 1]
    u = np.asarray(u, float).reshape((-1,) + (1,) * (np.ndim(lift) - 1))
    out = swing.cycloid_swing(u, np.asarray(lift)[..., perm], np.asarray(land)[..., perm], height)
    return np.asarray(out, float)[..., perm]


def trot_feet(
    n_ticks: int,
    command=(0.05, 0.0, 0.0),
    height: float = C.STEP_HEIGHT,
    period_s: float = C.STEP_PERIOD,
    p_t: float = C.TROT_P_T,
    p_n: float = C.TROT_P_N,
) -> np.ndarray:
    """Foot targets of the discontinuous trot, one per 50 Hz tick.

    n_ticks: number of ticks from the start (standing at nominal_feet); command: (vx [m/s],
    vy [m/s], yaw_rate [rad/s]) body twist averaged over a cycle; height H [m], period T [s],
    P_T, P_N: seed 003's trajectory parameters -> (n_ticks, 4, 3) feet in the body frame [m].
    """
    tick_times = swing.cycloid_tick_times(period_s, p_t, p_n, C.TICK_S)
    n = len(tick_times)
    u = tick_times / period_s  # (n,) trajectory progress of each tick of a phase
    vx, vy, wz = (float(c) for c in command)
    shift_s = 2.0 * period_s  # body moves during one of every two phases
    t = np.array([vx, vy, 0.0]) * shift_s
    theta = wz * shift_s
    p = nominal_feet()
    land = p @ _rot_z(theta).T + t
    along = cycloid_points(u, np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.0)[:, 0]  # (n,) shift profile 0 -> 1

    feet = nominal_feet()
    out = []
    n_phases = -(-n_ticks // n)
    for k in range(n_phases):
        if k % 2 == 0:  # swing of pair A (k = 0, 4, ...) or B (k = 2, 6, ...)
            moving = _SWING_PAIRS[(k // 2) % 2]
            curve = cycloid_points(u, feet, land, height)  # (n, 4, 3)
            phase = np.where(moving[None, :, None], curve, feet[None])
        else:  # body shift: R(-s theta)(f - s t), s the cycloid profile
            rel = feet[None] - along[:, None, None] * t
            phase = np.stack([rel[i] @ _rot_z(-along[i] * theta).T for i in range(n)])
            phase[..., 2] = feet[..., 2]
        out.append(phase)
        feet = phase[-1].copy()
    return np.concatenate(out)[:n_ticks]


def tilt_feet(feet: jax.Array, roll_pitch: jax.Array) -> jax.Array:
    """Body kinematics: feet (..., 4, 3) [m] for a level body -> the same ground points seen from a
    body rotated by roll_pitch (..., 2) [rad] about its centre (R = Ry(pitch) Rx(roll)): R^T f."""
    roll_pitch = jnp.asarray(roll_pitch)
    rpy = jnp.concatenate([roll_pitch, jnp.zeros_like(roll_pitch[..., :1])], axis=-1)
    rot = pose.body_rotation(rpy)  # (..., 3, 3) Rz(0) Ry Rx
    return jnp.einsum("...ji,...lj->...li", rot, feet)  # R^T f for each foot


def joint_targets(feet: jax.Array) -> tuple[jax.Array, jax.Array]:
    """feet (..., 4, 3) in the body frame [m] -> angles (..., 4, 3) [rad] (serial_ik in each hip frame,
    clipped to the joint limits as the position actuators' ctrlrange does), valid (..., 4)."""
    feet = jnp.asarray(feet)
    hip = jnp.asarray(C.HIP_POS, feet.dtype)
    side = jnp.asarray(C.SIDE, feet.dtype)
    q, valid = serial.serial_ik(feet - hip, C.LEG, side, limits=C.JOINT_LIMITS)
    lim = jnp.asarray(C.JOINT_LIMITS, q.dtype)
    return jnp.clip(q, lim[:, 0], lim[:, 1]), valid


@jax.jit
def stabilized_joint_targets(feet: jax.Array, roll_pitch: jax.Array) -> tuple[jax.Array, jax.Array]:
    """feet (4, 3) [m], stabilizer's body roll/pitch command (2,) [rad] -> angles (4, 3), valid (4,)."""
    return joint_targets(tilt_feet(feet, roll_pitch))


# --- the same trot for the environment: JAX, a function of time ----------------------------------------
# The environment asks for the feet of gait time t (a multiple of the 20 ms tick) with no planner state.
# In steady state the cycle of `trot_feet` repeats: pair A lifts off from R(-theta)(p - t) (where the
# two shifts since its last landing left it), pair B from the same point half a cycle later. Only the
# first swing of a walk differs (trot_feet lifts pair A from p, a half step); the environment blends
# its first gait_ramp_s from the standing pose instead. As a GaitParams (quadson_mjx.gait): cycle 4T,
# duty 3/4 (each leg swings one phase of four), pair A's swing the last quarter of its phase (offset
# 3/4, so its stance starts at t = T), pair B's half a cycle later; step_length_m is the distance a
# foot travels per cycle at the gait's own speed, 0.05 m/s (seed 003's forward command).
GAIT_NAMES: tuple[str, ...] = ("trot_discontinuous",)
SEED_SPEED = 0.05  # [m/s] seed 003's forward command (experiment 2)
TROT = {
    "phase_offset": np.where([leg in C.TROT_PAIRS[0] for leg in C.LEGS], 0.75, 0.25),
    "cycle_s": PHASES_PER_CYCLE * C.STEP_PERIOD,
    "duty": 0.75,
    "step_height_m": C.STEP_HEIGHT,
    "step_length_m": SEED_SPEED * PHASES_PER_CYCLE * C.STEP_PERIOD,
    "swing": "cycloid",
    "p_t": C.TROT_P_T,
    "p_n": C.TROT_P_N,
    "discontinuous": True,
}


def gait_params(name: str = "trot_discontinuous", **overrides) -> base_gait.GaitParams:
    """Caramel's gait `name` (GAIT_NAMES) as a GaitParams, with field overrides (cycle_s, step
    length and height, p_t, p_n). Raises ValueError on another gait, another swing than the cycloid
    or another pair timing (the planner below implements seed 003's trot only), and on a phase
    T = cycle_s / 4 that is not a whole number (>= 2) of 20 ms ticks."""
    if name not in GAIT_NAMES:
        raise ValueError(f"unknown gait {name!r} for caramel; choose from {GAIT_NAMES}")
    fixed = {"phase_offset", "duty", "discontinuous"}
    if fixed & set(overrides):
        raise ValueError(f"caramel's trot fixes {sorted(fixed)}; got overrides {sorted(overrides)}")
    if overrides.get("swing", "cycloid") not in ("cycloid", swing.swing_shape_index("cycloid")):
        raise ValueError(f"caramel's trot swings on seed 003's cycloid; got swing {overrides['swing']!r}")
    p = base_gait.params_from(TROT, **overrides)
    swing.cycloid_tick_times(p.cycle_s / PHASES_PER_CYCLE, p.p_t, p.p_n, C.TICK_S)  # raises if not
    return p


def _rot_z_jnp(theta: jax.Array) -> jax.Array:
    """theta (...) -> (..., 3, 3) rotation about z (pose.body_rotation of yaw theta)."""
    zero = jnp.zeros_like(theta)
    return pose.body_rotation(jnp.stack([zero, zero, theta], axis=-1))


def foot_targets(t: jax.Array, command: jax.Array, params: base_gait.GaitParams) -> jax.Array:
    """The steady-state discontinuous trot at gait time t, in JAX.

    t: (...) gait time [s], rounded to the nearest 20 ms tick (round(t / tick)); command: (..., 3) or (3,)
    (vx, vy [m/s], yaw_rate [rad/s]) averaged over a cycle; params: gait_params() with concrete
    cycle_s, p_t, p_n (the tick table is built in numpy) -> (..., 4, 3) feet in the body frame [m].
    Equals trot_feet tick for tick from the second phase on (tests/test_caramel_env.py).
    """
    period_s = float(params.cycle_s) / PHASES_PER_CYCLE
    tick_times = swing.cycloid_tick_times(period_s, float(params.p_t), float(params.p_n), C.TICK_S)
    n = len(tick_times)
    u_table = tick_times / period_s
    # the body shift's profile: the cycloid's horizontal progress (K - sin K) / 2 pi, K = 2 pi u (seed
    # 003 eq. 1; swing.cycloid_swing), in numpy: a constant of the trace like the tick table
    along_table = u_table - np.sin(2.0 * np.pi * u_table) / (2.0 * np.pi)
    t = jnp.asarray(t, dtype=jnp.result_type(float))
    command = jnp.asarray(command, t.dtype)
    tick = jnp.mod(jnp.round(t / C.TICK_S).astype(jnp.int32), PHASES_PER_CYCLE * n)
    phase, i = tick // n, tick % n  # (...)
    u = jnp.asarray(u_table, t.dtype)[i][..., None]  # (..., 1): one value for the 4 legs
    s = jnp.asarray(along_table, t.dtype)[i][..., None, None]  # (..., 1, 1)
    shift_s = 2.0 * period_s
    trans = jnp.stack([command[..., 0], command[..., 1], jnp.zeros_like(command[..., 0])], -1) * shift_s
    trans = trans[..., None, :]  # (..., 1, 3)
    theta = command[..., 2] * shift_s  # (...)
    p = jnp.asarray(nominal_feet(), t.dtype)  # (4, 3)
    rot = lambda a, f: jnp.einsum("...ij,...lj->...li", _rot_z_jnp(a), f)  # noqa: E731
    land = rot(theta, p) + trans  # (..., 4, 3)
    lift = rot(-theta, p - trans)
    perm = jnp.array([0, 2, 1])  # swing.py lifts along its +y: swap y and z (cycloid_points)
    swinging = swing.cycloid_swing(u, lift[..., perm], land[..., perm], params.step_height_m)[..., perm]
    ang = (-s[..., 0, 0] * theta)[..., None]  # (..., 1)
    after_landing = jnp.einsum("...ij,...lj->...li", _rot_z_jnp(ang[..., 0]), land - s * trans)
    before_lift = jnp.einsum("...ij,...lj->...li", _rot_z_jnp(ang[..., 0]), p - s * trans)
    after_landing = after_landing.at[..., 2].set(p[:, 2])
    before_lift = before_lift.at[..., 2].set(p[:, 2])
    pair_b = jnp.asarray([leg in C.TROT_PAIRS[1] for leg in C.LEGS])
    local = jnp.where(pair_b, (phase[..., None] + 2) % PHASES_PER_CYCLE, phase[..., None])[..., None]
    return jnp.where(
        local == 0,
        swinging,
        jnp.where(
            local == 1, after_landing, jnp.where(local == 2, jnp.broadcast_to(p, land.shape), before_lift)
        ),
    )
