"""Start states of the get-up task: Quadson dropped in a random orientation with random motor angles.

    sample = start_sampler(mj_model)                    # once: names looked up, the config checked
    s = jax.jit(jax.vmap(sample))(jax.random.split(key, 1024))
    s.qpos (1024, nq), s.label (1024,) index into CLASSES, s.drop_height_m, s.valid

A draw picks an orientation class (CLASSES, weights StartConfig.class_weights): on the back (roll pi),
on the left side (roll -pi/2: the left side down), on the right side (roll +pi/2), on the belly
(roll 0), each with roll and pitch spread uniformly by +-spread_rad; or tilted (a tilt uniform in
tilted_rad about a random horizontal axis). Every class has a uniform random yaw. The 12 motor
angles are uniform inside the real motor limits (constants.MOTOR_RANGES); a draw tries
leg_candidates per leg at once and keeps each leg's first that passes the checks of one leg, then
tries robot_candidates such sets of four legs and keeps the first whose legs keep apart:
  * the toe-in guard t5 - t1 <= TOE_IN_MAX (fivebar.within_limits);
  * the five-bar assembles with chain_margin_m to spare: |L4 - L2| + m <= |p4 - p2| <= L2 + L4 - m
    (away from the lock-up pose), and the IK of the FK's foot returns the same angles (the robot's
    assembly branch, every IK check of fivebar.leg_ik);
  * no leg touches another leg or the base box: the collision geoms of the full-contact model
    (quadson_mjx.sim2sim_model: hip box, link capsules, foot sphere) keep clearance_m between
    every pair of legs and between the base box and every link and foot. A leg's own links are not
    checked against each other (they meet at their joints; the toe-in guard keeps the knees apart,
    as on the robot), nor a hip box against the base it is mounted on.
If no set passes, the draw keeps the home stance's motor angles in the drawn orientation and
returns valid False (the home stance passes every check): the caller counts those.
The base is then placed at x = y = 0 with the lowest point of the robot's collision geometry
drop_height_m above a flat ground at z = 0 (on a height field add the ground's height under
it), drop_height_m uniform in StartConfig.drop_height_m. The
passive knee angles come from the five-bar's FK (fivebar.leg_points), so the chains start closed.

JAX, jit- and vmap-friendly; shapes are static. Distances in the body frame: segment-segment
distances exact (Ericson, Real-Time Collision Detection, 5.1.9), capsule-box distances from the box's
signed distance at points along the capsule's axis, minus half their spacing (the distance along a
segment is 1-Lipschitz, so the check stays conservative).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx.quat import quat_mul, quat_rotate
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar
from quadson_mjx.robots.quadson import model as quadson_model

CLASSES: tuple[str, ...] = ("back", "left_side", "right_side", "belly", "tilted")
_CLASS_ROLL = (math.pi, -math.pi / 2, math.pi / 2, 0.0, 0.0)  # tilted: drawn separately
_BOX_POINTS = 16  # points along a capsule's axis for its distance to a box


@dataclasses.dataclass(frozen=True)
class StartConfig:
    """The start-state distribution. Checked when built: ValueError (one line) naming the value."""

    drop_height_m: tuple[float, float] = (0.2, 0.5)  # lowest point of the robot above the ground [m]
    class_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0)  # CLASSES order, any scale
    spread_rad: float = math.radians(20.0)  # roll and pitch about a class's orientation, +-
    tilted_rad: tuple[float, float] = (math.radians(20.0), math.radians(160.0))  # tilt of "tilted"
    leg_candidates: int = 16  # motor-angle draws per leg tried at once (each passes ~42 %)
    robot_candidates: int = 4  # sets of four legs tried at once against each other (each ~93 %)
    clearance_m: float = 0.003  # smallest gap between two legs, and between a leg and the base
    chain_margin_m: float = 0.005  # the five-bar this far from its folded or stretched lock-up

    def __post_init__(self):
        def bad(name, why):
            raise ValueError(f"StartConfig.{name} {getattr(self, name)!r}: {why}")

        lo, hi = self.drop_height_m
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
            bad("drop_height_m", "need 0 <= low <= high [m]")
        w = self.class_weights
        if len(w) != len(CLASSES) or not all(math.isfinite(x) and x >= 0 for x in w) or sum(w) <= 0:
            bad("class_weights", f"need {len(CLASSES)} finite weights >= 0 ({', '.join(CLASSES)}), not all 0")
        if not (math.isfinite(self.spread_rad) and 0.0 <= self.spread_rad <= math.pi / 2):
            bad("spread_rad", "need 0 <= spread <= pi/2")
        lo, hi = self.tilted_rad
        if not (0.0 <= lo <= hi <= math.pi):
            bad("tilted_rad", "need 0 <= low <= high <= pi")
        for name in ("leg_candidates", "robot_candidates"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                bad(name, "need an integer >= 1")
        for name in ("clearance_m", "chain_margin_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v < 0.05):
                bad(name, "need 0 <= value < 0.05 [m]")


class StartState(NamedTuple):
    qpos: jax.Array  # (nq,) free joint (x, y, z, qw, qx, qy, qz), then the legs' hinges
    label: jax.Array  # () int32, index into CLASSES
    drop_height_m: jax.Array  # () the lowest point of the robot above the ground [m]
    valid: jax.Array  # () bool: False when no candidate passed and the home stance was kept
    motor_angles: jax.Array  # (4, 3) (t0, t1, t5) per leg [rad]


def _rot_x(t0):
    c, s = jnp.cos(t0), jnp.sin(t0)
    one, zero = jnp.ones_like(t0), jnp.zeros_like(t0)
    rows = [jnp.stack([one, zero, zero], -1), jnp.stack([zero, c, -s], -1), jnp.stack([zero, s, c], -1)]
    return jnp.stack(rows, -2)


def leg_geometry(angles):
    """The collision geometry of the legs in the body frame. angles: (4, 3) (t0, t1, t5) [rad] ->
    (seg_a, seg_b) (4, 5, 3) ends of each leg's capsules link1 (p1-p2), link2 (p2-foot), link5
    (p5-p4), link4 (p4-p3) and the foot sphere (foot-foot) [m], radii (5,) [m], hip box centres
    (4, 3) [m] and rotations (4, 3, 3) (columns: the box's axes), half sizes (3,) [m]."""
    pts = fivebar.leg_points(angles)
    rot = jnp.asarray(C.SHOULDER_ROT, angles.dtype)  # (4, 3, 3)
    shoulder = jnp.asarray(C.SHOULDER_POS, angles.dtype)

    def body(p):  # shoulder frame (4, 3) -> body frame
        return shoulder + jnp.einsum("lij,lj->li", rot, p)

    p1, p2, p3, p4, p5, foot = (body(p) for p in (pts.p1, pts.p2, pts.p3, pts.p4, pts.p5, pts.foot))
    seg_a = jnp.stack([p1, p2, p5, p4, foot], axis=1)
    seg_b = jnp.stack([p2, foot, p4, p3, foot], axis=1)
    r = C.LINK_RADIUS
    radii = jnp.asarray([r, r, r, r, C.FOOT_RADIUS], angles.dtype)
    hip_rot = rot @ _rot_x(angles[:, 0])
    hip_center = shoulder + hip_rot[:, :, 0] * (C.L0 / 2)
    return seg_a, seg_b, radii, hip_center, hip_rot, jnp.asarray(C.HIP_HALF_SIZE, angles.dtype)


def _seg_seg_distance(p1, q1, p2, q2):
    """Distance between segments p1-q1 and p2-q2 (..., 3) -> (...) (Ericson 5.1.9; a segment may be
    a point)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = jnp.sum(d1 * d1, -1), jnp.sum(d2 * d2, -1)
    b, c, f = jnp.sum(d1 * d2, -1), jnp.sum(d1 * r, -1), jnp.sum(d2 * r, -1)
    eps = 1e-12  # [m^2]: a segment shorter than 1e-6 m is a point
    a_s, e_s = jnp.maximum(a, eps), jnp.maximum(e, eps)
    denom = a * e - b * b  # 0 for parallel segments, where any s in [0, 1] is a closest one
    s = jnp.where(
        denom > 1e-7 * a * e, jnp.clip((b * f - c * e) / jnp.maximum(denom, eps * eps), 0.0, 1.0), 0.0
    )
    t = (b * s + f) / e_s
    s = jnp.where(
        t < 0.0, jnp.clip(-c / a_s, 0.0, 1.0), jnp.where(t > 1.0, jnp.clip((b - c) / a_s, 0.0, 1.0), s)
    )
    t = jnp.clip(t, 0.0, 1.0)
    point1, point2 = a <= eps, e <= eps
    s = jnp.where(point1, 0.0, jnp.where(point2, jnp.clip(-c / a_s, 0.0, 1.0), s))
    t = jnp.where(point2, 0.0, jnp.where(point1, jnp.clip(f / e_s, 0.0, 1.0), t))
    d = (p1 + d1 * s[..., None]) - (p2 + d2 * t[..., None])
    return jnp.sqrt(jnp.sum(d * d, -1))


def _capsule_box_gap(seg_a, seg_b, radius, center, rot, half):
    """Conservative gap [m] between capsules (..., 3) ends, radius (...) and a box (centre (3,),
    rotation (3, 3), half sizes (3,)) -> (...): the box's signed distance at _BOX_POINTS points along
    the axis, minimum, minus half their spacing and the radius."""
    s = jnp.linspace(0.0, 1.0, _BOX_POINTS)
    pts = seg_a[..., None, :] + s[:, None] * (seg_b - seg_a)[..., None, :]  # (..., n, 3)
    local = jnp.abs((pts - center) @ rot) - half
    outside = jnp.sqrt(jnp.sum(jnp.maximum(local, 0.0) ** 2, -1))
    sdf = outside + jnp.minimum(jnp.max(local, -1), 0.0)
    spacing = jnp.sqrt(jnp.sum((seg_b - seg_a) ** 2, -1)) / (_BOX_POINTS - 1)
    return jnp.min(sdf, -1) - 0.5 * spacing - radius


_PAIRS = tuple(tuple(int(k) for k in side) for side in np.triu_indices(4, 1))  # the 6 leg pairs


def _rows(x, rows):
    """x's rows by static Python indices: static slices, not a gather (a gather traced under
    jax.enable_x64 after one traced without it mixes int32 and int64 indices in jax 0.10)."""
    return jnp.stack([x[k] for k in rows])


def _base_gaps(geometry):
    """(4,) smallest gap [m] between each leg's links and foot and the base box."""
    seg_a, seg_b, radii = geometry[:3]
    dtype = seg_a.dtype
    base_h = jnp.asarray(C.BASE_HALF_SIZE, dtype)
    gaps = _capsule_box_gap(seg_a, seg_b, radii, jnp.zeros(3, dtype), jnp.eye(3, dtype=dtype), base_h)
    return jnp.min(gaps, -1)


def _cross_gap(geometry):
    """() smallest gap [m] between the collision geoms of two different legs."""
    seg_a, seg_b, radii, hip_c, hip_r, hip_h = geometry
    i, j = _PAIRS
    a_i, b_i, a_j, b_j = _rows(seg_a, i), _rows(seg_b, i), _rows(seg_a, j), _rows(seg_b, j)
    caps = _seg_seg_distance(a_i[:, :, None], b_i[:, :, None], a_j[:, None, :], b_j[:, None, :]) - (
        radii[:, None] + radii[None, :]
    )  # (6, 5, 5)
    box = jax.vmap(_capsule_box_gap, in_axes=(0, 0, None, 0, 0, None))
    hips = jnp.minimum(
        jnp.min(box(a_j, b_j, radii, _rows(hip_c, i), _rows(hip_r, i), hip_h)),
        jnp.min(box(a_i, b_i, radii, _rows(hip_c, j), _rows(hip_r, j), hip_h)),
    )
    return jnp.minimum(jnp.min(caps), hips)


def self_clearance(angles):
    """Smallest gap [m] between two legs' collision geoms, or a leg's links or foot and the base box
    (negative: they intersect). angles: (4, 3) [rad] -> ()."""
    geometry = leg_geometry(angles)
    return jnp.minimum(jnp.min(_base_gaps(geometry)), _cross_gap(geometry))


def legs_ok(angles, config: StartConfig):
    """The checks of one leg (limits and toe-in guard, chain margin, assembly branch, gap to the
    base box) for motor angles (4, 3) [rad] -> (4,) bool."""
    limits = fivebar.within_limits(angles)
    pts = fivebar.leg_points(angles)
    l24 = jnp.sqrt(jnp.sum((pts.p4 - pts.p2) ** 2, -1))
    m = config.chain_margin_m
    chain = (l24 >= abs(C.L4 - C.L2) + m) & (l24 <= C.L2 + C.L4 - m)
    back, ik_ok = fivebar.leg_ik(pts.foot)
    branch = ik_ok & jnp.all(jnp.abs(back - angles) < 1e-3, -1)
    return limits & chain & branch & (_base_gaps(leg_geometry(angles)) >= config.clearance_m)


def pose_ok(angles, config: StartConfig):
    """Every check of the module's docstring for motor angles (..., 4, 3) [rad] -> (...) bool."""

    def one(a):
        return jnp.all(legs_ok(a, config)) & (_cross_gap(leg_geometry(a)) >= config.clearance_m)

    return jnp.vectorize(one, signature="(4,3)->()")(angles)


def _axis_angle(axis, angle):
    half = 0.5 * angle
    return jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * axis])


def _orientation(key, label, config: StartConfig):
    """wxyz of the class `label`: yaw uniform, then roll and pitch (or the tilted class's tilt)."""
    k_yaw, k_roll, k_pitch, k_tilt, k_axis = jax.random.split(key, 5)
    spread = config.spread_rad
    roll = jnp.asarray(_CLASS_ROLL)[label] + jax.random.uniform(k_roll, (), minval=-spread, maxval=spread)
    pitch = jax.random.uniform(k_pitch, (), minval=-spread, maxval=spread)
    ex, ey = jnp.asarray([1.0, 0.0, 0.0]), jnp.asarray([0.0, 1.0, 0.0])
    q_class = quat_mul(_axis_angle(ey, pitch), _axis_angle(ex, roll))  # R = Ry(pitch) Rx(roll)
    phi = jax.random.uniform(k_axis, (), minval=-jnp.pi, maxval=jnp.pi)
    tilt = jax.random.uniform(k_tilt, (), minval=config.tilted_rad[0], maxval=config.tilted_rad[1])
    q_tilt = _axis_angle(jnp.stack([jnp.cos(phi), jnp.sin(phi), 0.0]), tilt)
    q = jnp.where(label == CLASSES.index("tilted"), q_tilt, q_class)
    yaw = jax.random.uniform(k_yaw, (), minval=-jnp.pi, maxval=jnp.pi)
    return quat_mul(_axis_angle(jnp.asarray([0.0, 0.0, 1.0]), yaw), q)


def lowest_point(quat, angles):
    """Height [m] of the lowest point of the robot's collision geometry below (negative) or above
    the base origin, for the base at orientation quat (4,) wxyz and motor angles (4, 3)."""
    seg_a, seg_b, radii, hip_c, hip_r, hip_h = leg_geometry(angles)
    world = quat_rotate(quat, jnp.eye(3)).T  # columns: the body axes in the world
    z = world[2]  # the world z of body-frame vectors: z @ v
    caps = jnp.minimum(seg_a @ z, seg_b @ z) - radii
    base = -jnp.sum(jnp.abs(z) * jnp.asarray(C.BASE_HALF_SIZE))
    hips = hip_c @ z - jnp.sum(jnp.abs(jnp.einsum("j,ljk->lk", z, hip_r)) * hip_h, -1)
    return jnp.minimum(jnp.minimum(jnp.min(caps), base), jnp.min(hips))


def start_sampler(mj_model, config: StartConfig | None = None):
    """The sampler for this model (names looked up once): key -> StartState. mj_model: any Quadson
    model (its joints' qpos addresses are read by name)."""
    config = config if config is not None else StartConfig()
    if not isinstance(config, StartConfig):
        raise ValueError(f"config must be a StartConfig, got {type(config).__name__}")
    ids = quadson_model.model_ids(mj_model)
    if ids.root_qposadr != 0:
        raise ValueError("the base's free joint must come first in qpos")
    nq = int(mj_model.nq)
    motor_adr = jnp.asarray(ids.motor_qposadr.reshape(4, 3))
    knee_adr = jnp.asarray(ids.passive_qposadr.reshape(4, 2))
    home = jnp.asarray(quadson_model.home_motor_angles(), jnp.float32)
    lo = jnp.asarray(C.MOTOR_RANGES[:, 0], jnp.float32)
    hi = jnp.asarray(C.MOTOR_RANGES[:, 1], jnp.float32)
    logits = jnp.log(jnp.asarray(config.class_weights, jnp.float32) / sum(config.class_weights))

    def sample(key) -> StartState:
        k_class, k_orient, k_motor, k_drop = jax.random.split(key, 4)
        label = jax.random.categorical(k_class, logits).astype(jnp.int32)
        quat = _orientation(k_orient, label, config)
        shape = (config.robot_candidates, config.leg_candidates, 4, 3)
        cand = jax.random.uniform(k_motor, shape, minval=lo, maxval=hi)
        leg_pass = jax.vmap(jax.vmap(lambda a: legs_ok(a, config)))(cand)  # (R, K, 4)
        first = jnp.argmax(leg_pass, axis=1)  # (R, 4): each leg's first passing draw
        picked = jnp.take_along_axis(cand, first[:, None, :, None], axis=1)[:, 0]  # (R, 4, 3)
        found = jnp.all(jnp.any(leg_pass, axis=1), axis=-1)  # (R,)
        cross = jax.vmap(lambda a: _cross_gap(leg_geometry(a)))(picked) >= config.clearance_m
        ok = found & cross
        valid = jnp.any(ok)
        angles = jnp.where(valid, picked[jnp.argmax(ok)], home)
        pts = fivebar.leg_points(angles)
        drop = jax.random.uniform(k_drop, (), minval=config.drop_height_m[0], maxval=config.drop_height_m[1])
        z = drop - lowest_point(quat, angles)
        qpos = jnp.zeros(nq, jnp.float32).at[2].set(z).at[3:7].set(quat)
        qpos = qpos.at[motor_adr].set(angles)
        qpos = qpos.at[knee_adr].set(jnp.stack([pts.knee2, pts.knee4], -1))
        return StartState(qpos, label, drop, valid, angles)

    return sample
