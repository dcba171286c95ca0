"""Start states of the get-up task (quadson_mjx.robots.quadson.getup_start).

References: MuJoCo C on the full-contact model of sim2sim (quadson_mjx.sim2sim_model), with the base
box made to collide with the legs: its contacts (none may exist at a sampled start), its geom
distances (mj_geomDistance; the sampler's gaps may only be smaller), its geoms' lowest point (the drop height), its
closure sites (the five-bar closed); the motor limits and toe-in guard of constants.py; segment
distances against dense sampling of the segments.
"""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx.robots import get_robot
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import getup_start as G
from quadson_mjx.robots.quadson import model as quadson_model
from quadson_mjx.sim2sim_model import plant_model

N = 256


@pytest.fixture(scope="module")
def mj_model():
    """sim2sim's full-contact model, whose base box also collides with every leg (it touches only
    the ground there)."""
    m = plant_model(get_robot("quadson"), "flat")
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
    legs = sum(1 << (1 + i) for i in range(4))
    m.geom_contype[base] = legs
    m.body_contype[m.geom_bodyid[base]] = legs  # the broad phase filters by body first
    return m


@pytest.fixture(scope="module")
def samples(mj_model):
    sample = jax.jit(jax.vmap(G.start_sampler(mj_model)))
    s = sample(jax.random.split(jax.random.key(0), N))
    return jax.tree.map(np.asarray, s)


def _rot(quat):
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(quat, np.float64))
    return r.reshape(3, 3)


def test_samples_inside_the_limits_and_their_classes(samples, mj_model):
    s = samples
    assert s.qpos.shape == (N, mj_model.nq) and s.qpos.dtype == np.float32 and np.all(np.isfinite(s.qpos))
    assert s.label.dtype == np.int32 and s.valid.all()
    a = s.motor_angles.astype(np.float64)
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    assert np.all(a >= lo) and np.all(a <= hi)
    assert np.all(a[..., 2] - a[..., 1] <= C.TOE_IN_MAX)  # the toe-in guard
    ids = quadson_model.model_ids(mj_model)
    np.testing.assert_array_equal(s.qpos[:, ids.motor_qposadr], s.motor_angles.reshape(N, 12))
    assert np.all((s.drop_height_m >= 0.2) & (s.drop_height_m <= 0.5))
    assert np.all(np.bincount(s.label, minlength=5) > 0) and s.label.max() == 4  # every class drawn
    np.testing.assert_allclose(np.linalg.norm(s.qpos[:, 3:7], axis=1), 1.0, atol=1e-6)
    # each class from the body axes in the world: z (3rd column) and y (2nd) against the vertical
    spread = math.radians(20.0) * math.sqrt(2.0) + 1e-3  # roll and pitch both at the edge
    for k in range(N):
        r = _rot(s.qpos[k, 3:7])
        up_z, up_y = r[2, 2], r[2, 1]
        name = G.CLASSES[s.label[k]]
        if name == "back":
            assert up_z <= -math.cos(spread)
        elif name == "belly":
            assert up_z >= math.cos(spread)
        elif name == "left_side":  # the left side (body +y) down
            assert up_y <= -math.cos(spread)
        elif name == "right_side":
            assert up_y >= math.cos(spread)
        else:
            assert math.radians(20) - 1e-4 <= math.acos(np.clip(up_z, -1, 1)) <= math.radians(160) + 1e-4


def test_mujoco_finds_no_contact_the_chains_closed_and_the_drop_height(samples, mj_model):
    d = mujoco.MjData(mj_model)
    pairs, _ = _pairs(mj_model)
    solid = (mj_model.geom_contype > 0) | (mj_model.geom_conaffinity > 0)
    solid[0] = False  # the floor
    for k in range(N):
        d.qpos[:] = samples.qpos[k]
        mujoco.mj_forward(mj_model, d)
        assert d.ncon == 0, [
            (d.contact[i].geom1, d.contact[i].geom2, d.contact[i].dist) for i in range(d.ncon)
        ]
        assert quadson_model.closure_residual(mj_model, d).max() < 2e-6  # float32 knee angles
        low = np.inf  # the lowest point of every collision geom: boxes, capsules, spheres
        for g in np.flatnonzero(solid):
            r, size, z = d.geom_xmat[g].reshape(3, 3), mj_model.geom_size[g], d.geom_xpos[g, 2]
            t = mj_model.geom_type[g]
            if t == mujoco.mjtGeom.mjGEOM_BOX:
                low = min(low, z - np.abs(r[2]) @ size)
            elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
                low = min(low, z - abs(r[2, 2]) * size[1] - size[0])
            else:
                assert t == mujoco.mjtGeom.mjGEOM_SPHERE
                low = min(low, z - size[0])
        assert low == pytest.approx(float(samples.drop_height_m[k]), abs=2e-6)


def _pairs(m):
    """The geom pairs the sampler keeps apart: every collision geom of a leg against those of every
    other leg (two hip boxes apart: they turn about fixed axes 9 cm apart), every link and foot
    against the base box -> (pairs (n, 2), hip pairs (6, 2))."""
    leg_of = {}
    for g in range(m.ngeom):
        name = m.body(m.geom_bodyid[g]).name
        if m.geom_contype[g] and name[:2] in C.LEGS:
            leg_of[g] = (name[:2], name.endswith("_hip"))
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
    pairs = [(base, g) for g, (_, hip) in leg_of.items() if not hip]
    hips = []
    for g1, (l1, h1) in leg_of.items():
        for g2, (l2, h2) in leg_of.items():
            if C.LEGS.index(l1) < C.LEGS.index(l2):
                (hips if h1 and h2 else pairs).append((g1, g2))
    assert len(pairs) == 20 + 6 * (36 - 1) and len(hips) == 6
    return np.array(pairs), np.array(hips)


def _mj_gaps(m, d, pairs, distmax=0.1):
    """MuJoCo's distance of each geom pair (mj_geomDistance; distmax where farther)."""
    return np.array([mujoco.mj_geomDistance(m, d, int(a), int(b), distmax, None) for a, b in pairs])


def test_gaps_equal_mujocos_geom_distances_or_are_smaller(mj_model):
    """Motor angles drawn in the limits with no other check: the sampler's gap is at most MuJoCo's
    smallest geom distance (a conservative check), and within half the spacing of the box check's
    points of it where the legs are apart."""
    m = mj_model
    pairs, hip_pairs = _pairs(m)
    rng = np.random.default_rng(3)
    angles = rng.uniform(C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1], (120, 4, 3))
    with jax.enable_x64(True):
        gaps = np.asarray(jax.jit(jax.vmap(G.self_clearance))(jnp.asarray(angles)))
        pts = G.fivebar.leg_points(jnp.asarray(angles))
        knees = np.stack([np.asarray(pts.knee2), np.asarray(pts.knee4)], -1)
    ids = quadson_model.model_ids(m)
    d = mujoco.MjData(m)
    spacing = (C.L2 + C.L3) / (G._BOX_POINTS - 1)  # of the points on the longest capsule
    apart = 0
    for k in range(len(angles)):
        d.qpos[:] = 0.0
        d.qpos[2], d.qpos[3] = 2.0, 1.0  # high above the floor
        d.qpos[ids.motor_qposadr] = angles[k].ravel()
        d.qpos[ids.passive_qposadr] = knees[k].ravel()
        mujoco.mj_forward(m, d)
        assert np.all(_mj_gaps(m, d, hip_pairs) > 0.09)
        mj = _mj_gaps(m, d, pairs).min()
        assert gaps[k] <= mj + 1e-9
        if mj > 0:
            apart += 1
            assert gaps[k] >= mj - 0.5 * spacing - 1e-9
    assert 10 < apart < len(angles) - 10  # both kinds were drawn


def test_the_fallback_home_stance_passes_every_check():
    home = jnp.asarray(quadson_model.home_motor_angles(), jnp.float32)
    assert bool(G.pose_ok(home, G.StartConfig()))


def test_segment_distance_against_dense_sampling():
    rng = np.random.default_rng(1)
    u = np.linspace(0.0, 1.0, 801)
    for case in range(40):
        p1, q1, p2, q2 = rng.uniform(-0.1, 0.1, (4, 3))
        if case % 4 == 1:
            q1 = p1  # a point against a segment
        elif case % 4 == 2:
            q2 = p2 + 0.3 * (q1 - p1)  # parallel
        elif case % 4 == 3:
            q1, q2 = p1, p2  # two points
        a = p1 + u[:, None] * (q1 - p1)
        b = p2 + u[:, None] * (q2 - p2)
        brute = np.min(np.linalg.norm(a[:, None] - b[None], axis=-1))
        with jax.enable_x64(True):
            got = float(G._seg_seg_distance(*(jnp.asarray(v) for v in (p1, q1, p2, q2))))
        assert got <= brute + 1e-12 and got >= brute - 2e-4  # the grid's step is 0.25 mm


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"drop_height_m": (0.5, 0.2)}, "drop_height_m"),
        ({"class_weights": (1.0, 1.0)}, "class_weights"),
        ({"class_weights": (0.0,) * 5}, "class_weights"),
        ({"spread_rad": math.nan}, "spread_rad"),
        ({"tilted_rad": (0.0, 4.0)}, "tilted_rad"),
        ({"leg_candidates": 0}, "leg_candidates"),
        ({"robot_candidates": 2.0}, "robot_candidates"),
        ({"clearance_m": -0.001}, "clearance_m"),
    ],
)
def test_config_errors_are_one_line(kwargs, name):
    with pytest.raises(ValueError, match=f"StartConfig.{name}") as e:
        G.StartConfig(**kwargs)
    assert "\n" not in str(e.value)


def test_sampled_drops_land_and_come_to_rest_in_mujoco_c(samples):
    """Eight sampled starts dropped on sim2sim's plant (MuJoCo C, full contacts, servo model) with
    the servos holding the sampled angles: the state stays finite, the five-bar chains closed
    within 2 mm through the impact, and after 2 s the base is at rest on the ground."""
    from quadson_mjx import sim2sim_plant as P

    robot = get_robot("quadson")
    plant = P.Plant(robot, plant_model(robot, "flat"), P.ServoParams(), P.SensorParams(enabled=False))
    m, d = plant.m, plant.d
    for k in range(8):
        plant.reset()
        mujoco.mj_resetData(m, d)
        d.qpos[:] = samples.qpos[k]
        mujoco.mj_forward(m, d)
        plant.send(samples.motor_angles[k].reshape(12))
        gaps = []
        for _ in range(100):  # 2 s of 20 ms ticks
            plant.advance(0.02)
            gaps.append(np.max(plant.closure_gaps()))
        assert np.all(np.isfinite(d.qpos)) and max(gaps) < 2e-3
        assert np.linalg.norm(d.qvel[:6]) < 0.2 and d.qpos[2] < 0.2  # at rest, on the ground
