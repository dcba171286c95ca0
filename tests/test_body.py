"""Body kinematics against hand arithmetic, a literal numpy transcription of seed 003 eq. 11
((T_M T_leg)^-1 p with 4x4 matrices) and planted-feet round trips through the leg FK."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx.robots.quadson import body
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar as fb

N = 2048
w2s = jax.jit(jax.vmap(body.world_to_shoulder))
s2w = jax.jit(jax.vmap(body.shoulder_to_world))
bik = jax.jit(jax.vmap(body.body_ik))
fk = jax.jit(jax.vmap(jax.vmap(fb.leg_fk)))
rot = jax.jit(jax.vmap(body.body_rotation))
tf = jax.jit(jax.vmap(body.body_transform))

H = C.STANCE_HEIGHT


def np_rotation(roll, pitch, yaw):
    """Rz(yaw) Ry(pitch) Rx(roll) from the elementary matrices."""
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def np_homogeneous(r, p):
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, p
    return t


def np_world_to_shoulder(pose, feet):
    """Seed 003 eq. 11 literally: [x_IK, 1] = (T_M T_leg)^-1 [x, 1], one leg at a time."""
    t_m = np_homogeneous(np_rotation(*pose[3:]), pose[:3])
    out = []
    for leg in range(C.NUM_LEGS):
        t_leg = np_homogeneous(C.SHOULDER_ROT[leg], C.SHOULDER_POS[leg])
        out.append((np.linalg.inv(t_m @ t_leg) @ np.append(feet[leg], 1.0))[:3])
    return np.array(out)


def random_poses(rng, n, trans=0.02, ang=0.15):
    return np.concatenate(
        [rng.uniform(-trans, trans, (n, 3)) + [0, 0, H], rng.uniform(-ang, ang, (n, 3))], axis=-1
    )


# --- rotations and transforms ------------------------------------------------------------------


def test_body_rotation_hand_cases(float_dtype):
    q = np.pi / 2
    rpy = np.array([[0, 0, q], [q, 0, 0], [0, q, 0]], float_dtype)
    r = np.asarray(rot(rpy))
    assert r.shape == (3, 3, 3) and r.dtype == float_dtype
    np.testing.assert_allclose(r[0] @ [1, 0, 0], [0, 1, 0], atol=1e-7)  # yaw 90: x -> y
    np.testing.assert_allclose(r[1] @ [0, 1, 0], [0, 0, 1], atol=1e-7)  # roll 90: y -> z
    np.testing.assert_allclose(r[2] @ [0, 0, 1], [1, 0, 0], atol=1e-7)  # pitch 90: z -> x
    np.testing.assert_allclose(r[2] @ [1, 0, 0], [0, 0, -1], atol=1e-7)  # pitch 90: x -> -z


def test_body_rotation_is_zyx_product_and_orthonormal(float_dtype):
    rng = np.random.default_rng(0)
    rpy = rng.uniform(-np.pi, np.pi, (N, 3))
    r = np.asarray(rot(rpy.astype(float_dtype)))
    want = np.stack([np_rotation(*x) for x in rpy[:64]])
    tol = 1e-12 if float_dtype == np.float64 else 1e-6
    np.testing.assert_allclose(r[:64], want, atol=tol)
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=tol)
    np.testing.assert_allclose(np.linalg.det(r.astype(np.float64)), 1.0, atol=tol)


def test_body_transform(float_dtype):
    pose = np.array([[0.1, -0.2, 0.3, 0.4, -0.5, 0.6]], float_dtype)
    t = np.asarray(tf(pose))
    assert t.shape == (1, 4, 4) and t.dtype == float_dtype
    np.testing.assert_allclose(t[0, :3, :3], np_rotation(0.4, -0.5, 0.6), atol=1e-6)
    np.testing.assert_allclose(t[0, :3, 3], [0.1, -0.2, 0.3], atol=1e-7)
    np.testing.assert_array_equal(t[0, 3], [0, 0, 0, 1])


# --- world <-> shoulder -------------------------------------------------------------------------


def test_world_to_shoulder_matches_eq_11(float_dtype):
    rng = np.random.default_rng(1)
    pose = random_poses(rng, N, trans=0.5, ang=np.pi)
    feet = rng.uniform(-0.4, 0.4, (N, 4, 3))
    got = np.asarray(w2s(pose.astype(float_dtype), feet.astype(float_dtype)))
    assert got.shape == (N, 4, 3) and got.dtype == float_dtype
    want = np.stack([np_world_to_shoulder(p, f) for p, f in zip(pose[:64], feet[:64], strict=True)])
    tol = 1e-12 if float_dtype == np.float64 else 2e-6
    np.testing.assert_allclose(got[:64], want, atol=tol)
    back = np.asarray(s2w(pose.astype(float_dtype), got))
    np.testing.assert_allclose(back, feet, atol=tol)


def test_nominal_stance_hand_values():
    # Front legs: leg x = body -x, so the foot is at 15.3 - 4.08 = 11.22 cm; rear: -15.3 + 4.08.
    feet = body.nominal_feet_world()
    assert feet.shape == (4, 3) and feet.dtype == np.float64
    np.testing.assert_allclose(
        feet,
        [[0.1122, 0.112, 0.0], [0.1122, -0.112, 0.0], [-0.1122, 0.112, 0.0], [-0.1122, -0.112, 0.0]],
        atol=1e-12,
    )
    pose = np.array([[0, 0, H, 0, 0, 0]])
    np.testing.assert_allclose(np.asarray(w2s(pose, feet[None]))[0], [[C.L0 / 2, -H, 0.0]] * 4, atol=1e-7)


def test_raising_the_body_lowers_every_foot_in_its_shoulder_frame(float_dtype):
    feet = body.nominal_feet_world()[None].astype(float_dtype)
    pose = np.array([[0, 0, H + 0.01, 0, 0, 0]], float_dtype)
    got = np.asarray(w2s(pose, feet))[0]
    # Hand: 1 cm higher body, same feet: y = -(20 + 1) cm, x and z unchanged.
    np.testing.assert_allclose(got, [[C.L0 / 2, -(H + 0.01), 0.0]] * 4, atol=1e-7)


def test_yawing_the_body_90_degrees_hand_values(float_dtype):
    feet = body.nominal_feet_world()[None].astype(float_dtype)
    pose = np.array([[0, 0, 0.2, 0, 0, np.pi / 2]], float_dtype)
    got = np.asarray(w2s(pose, feet))[0]
    # Hand: body coords of a world point w are (w_y, -w_x, w_z - 0.2) after a 90 deg yaw.
    # FL: (0.112, -0.1122, -0.2) - (0.153, 0.112, 0) = (-0.041, -0.2242, -0.2); front legs read
    # (x, y, z)_leg = (-X, Z, Y) -> (0.041, -0.2, -0.2242).
    # FR: (-0.112, -0.1122, -0.2) - (0.153, -0.112, 0) = (-0.265, -0.0002, -0.2) -> (0.265, -0.2, -0.0002).
    # RL: (0.112, 0.1122, -0.2) - (-0.153, 0.112, 0) = (0.265, 0.0002, -0.2); rear legs read
    # (X, Z, -Y) -> (0.265, -0.2, -0.0002).
    # RR: (-0.112, 0.1122, -0.2) - (-0.153, -0.112, 0) = (0.041, 0.2242, -0.2) -> (0.041, -0.2, -0.2242).
    want = [[0.041, -0.2, -0.2242], [0.265, -0.2, -0.0002], [0.265, -0.2, -0.0002], [0.041, -0.2, -0.2242]]
    np.testing.assert_allclose(got, want, atol=1e-6)


# --- body IK with planted feet -------------------------------------------------------------------


MOVES = [
    ("x+1cm", [0.01, 0, 0, 0, 0, 0]),
    ("x-1cm", [-0.01, 0, 0, 0, 0, 0]),
    ("y+1cm", [0, 0.01, 0, 0, 0, 0]),
    ("z+1cm", [0, 0, 0.01, 0, 0, 0]),
    ("z-2cm", [0, 0, -0.02, 0, 0, 0]),
    ("roll+0.1", [0, 0, 0, 0.1, 0, 0]),
    ("roll-0.1", [0, 0, 0, -0.1, 0, 0]),
    ("pitch+0.1", [0, 0, 0, 0, 0.1, 0]),
    ("pitch-0.1", [0, 0, 0, 0, -0.1, 0]),
    ("yaw+0.1", [0, 0, 0, 0, 0, 0.1]),
    ("yaw-0.1", [0, 0, 0, 0, 0, -0.1]),
]


def test_body_moves_with_planted_feet(float_dtype):
    feet = np.broadcast_to(body.nominal_feet_world(), (len(MOVES), 4, 3)).astype(float_dtype)
    pose = (np.array([m[1] for m in MOVES]) + [0, 0, H, 0, 0, 0]).astype(float_dtype)
    angles, valid = map(np.asarray, bik(pose, feet))
    assert angles.shape == (len(MOVES), 4, 3) and angles.dtype == float_dtype
    assert valid.shape == (len(MOVES), 4) and valid.dtype == bool
    assert valid.all(), [m[0] for m, v in zip(MOVES, valid, strict=True) if not v.all()]
    back = np.asarray(s2w(pose, fk(angles)))
    tol = 1e-12 if float_dtype == np.float64 else 1e-6
    np.testing.assert_allclose(back, feet, atol=tol)
    # A pure translation leaves the abduction at zero; a roll tilts every leg plane.
    np.testing.assert_allclose(angles[[0, 1, 3, 4], :, 0], 0.0, atol=1e-7)
    assert np.all(np.abs(angles[5, :, 0]) > 0.05)


def test_random_body_poses_round_trip(float_dtype):
    rng = np.random.default_rng(2)
    pose = random_poses(rng, N).astype(float_dtype)
    feet = np.broadcast_to(body.nominal_feet_world(), (N, 4, 3)).astype(float_dtype)
    angles, valid = map(np.asarray, bik(pose, feet))
    assert np.all(np.isfinite(angles)) and valid.mean() > 0.5
    back = np.asarray(s2w(pose, fk(angles)))
    # float32: IK near acos(+-1) loses sqrt(eps) in angle, tens of um at the foot.
    tol = 1e-12 if float_dtype == np.float64 else 2e-4
    assert np.abs(back - feet)[valid].max() < tol


def test_world_to_shoulder_jacobian_matches_central_differences():
    rng = np.random.default_rng(3)
    with jax.enable_x64(True):
        pose = random_poses(rng, 16, ang=1.0)
        feet = rng.uniform(-0.3, 0.3, (16, 4, 3))
        j = np.asarray(jax.jit(jax.vmap(jax.jacfwd(body.world_to_shoulder)))(pose, feet))
        assert j.shape == (16, 4, 3, 6)
        h = 1e-6
        cols = [
            (np.asarray(w2s(pose + h * e, feet)) - np.asarray(w2s(pose - h * e, feet))) / (2 * h)
            for e in np.eye(6)
        ]
        np.testing.assert_allclose(j, np.stack(cols, axis=-1), atol=1e-8)  # h^2 + 1e-16 / h


def test_body_ik_gradients_finite():
    pose = np.array([[0, 0, H, 0.1, -0.1, 0.05], [0, 0, 0.5, 0, 0, 0]], np.float32)  # 2nd: out of reach
    feet = np.broadcast_to(body.nominal_feet_world(), (2, 4, 3)).astype(np.float32)
    g = jax.jit(jax.vmap(jax.grad(lambda p, f: jnp.sum(body.body_ik(p, f)[0]))))(pose, feet)
    assert np.all(np.isfinite(np.asarray(g)))
    assert not np.asarray(bik(pose, feet)[1])[1].any()


@pytest.mark.parametrize("shape", [(), (7,), (3, 5)])
def test_batch_shapes(shape, float_dtype):
    pose = np.broadcast_to(np.array([0, 0, H, 0.05, 0, 0]), shape + (6,)).astype(float_dtype)
    feet = np.broadcast_to(body.nominal_feet_world(), shape + (4, 3)).astype(float_dtype)
    angles, valid = jax.jit(body.body_ik)(pose, feet)
    t = jax.jit(body.body_transform)(pose)
    assert angles.shape == shape + (4, 3) and angles.dtype == float_dtype
    assert valid.shape == shape + (4,) and bool(np.all(valid))
    assert t.shape == shape + (4, 4) and t.dtype == float_dtype
