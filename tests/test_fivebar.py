"""Leg kinematics against the published vectors, a plain numpy transcription of seed 000
Algorithms 1-2, hand arithmetic and finite differences; run as production runs it (jit, vmap)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar as fb

L0, L1, L2, L3, L4, L5 = C.LINK_LENGTHS
N = 4096  # one fixed batch size for the random tests: one compile per function and dtype

fk = jax.jit(jax.vmap(fb.leg_fk))
ik = jax.jit(jax.vmap(fb.leg_ik))
points = jax.jit(jax.vmap(fb.leg_points))
jac = jax.jit(jax.vmap(fb.leg_jacobian))
jac_fd = jax.jit(jax.vmap(fb.leg_jacobian_fd))
qdot = jax.jit(jax.vmap(fb.joint_velocities))
limits_ok = jax.jit(jax.vmap(fb.within_limits))
closes = jax.jit(jax.vmap(fb.chain_closes))

# robots.md, "Forward kinematics vectors" (seed 000): (t0, t1, t5) [rad] -> foot [cm].
FK_VECTORS = [
    ((0.0, math.pi, math.pi / 2), (-2.1640, -17.0277, 0.0)),
    ((0.0, 2.6, 1.35), (1.7928, -19.9105, 0.0)),
    ((0.2, 2.6, 1.35), (1.7928, -19.5136, -3.9556)),
    ((0.0, 3.0, 1.7), (-3.6382, -18.6123, 0.0)),
]
# robots.md, "Inverse (t0 = 0)": planar foot [cm] -> (t1, t5) [rad], printed to 4 decimals.
IK_VECTORS = [((-4.0, -20.0), (2.8406, 1.7611)), ((13.0, -20.0), (1.6217, 0.5686))]


# --- plain numpy transcription of seed 000 (the reference) ------------------------------------


def _cw(v):
    return np.arctan2(-v[..., 1], v[..., 0])


def _dir(phi):
    return np.stack([np.cos(phi), -np.sin(phi)], axis=-1)


def ref_fk(a):
    """Algorithm 1 as printed (acos sum for theta2), rotated with the sign of robots.md."""
    t0, t1, t5 = a[..., 0], a[..., 1], a[..., 2]
    p2 = L1 * _dir(t1)
    p4 = np.array([L0, 0.0]) + L5 * _dir(t5)
    l14, l24 = np.linalg.norm(p4, axis=-1), np.linalg.norm(p4 - p2, axis=-1)
    with np.errstate(invalid="ignore"):  # NaN where the chain cannot close; callers mask those
        theta2 = (
            np.arccos((L2**2 + l24**2 - L4**2) / (2 * L2 * l24))
            + np.arccos((L1**2 + l24**2 - l14**2) / (2 * L1 * l24))
            - (np.pi - t1)
        )
    pe = p2 + (L2 + L3) * _dir(theta2)
    return np.stack([pe[..., 0], pe[..., 1] * np.cos(t0), pe[..., 1] * np.sin(t0)], axis=-1)


def seed_formula_applies(a):
    """Algorithm 1's acos sum is the angle of p2->p4 only while p4 is clockwise of p2->p1."""
    p2 = L1 * _dir(a[..., 1])
    p4 = np.array([L0, 0.0]) + L5 * _dir(a[..., 2])
    u, v = -p2, p4 - p2
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0] <= 0


def ref_ik(f):
    """Algorithm 2 as printed, with atan2 for its atan(-y'/x') and atan(-p3y/(L0 - p3x))."""
    x, y, z = f[..., 0], f[..., 1], f[..., 2]
    t0 = -np.arctan2(z, -y)
    yp = np.cos(t0) * y + np.sin(t0) * z  # second row of R(-t0) times (x, y, z)
    l1e = np.hypot(x, yp)
    c12 = (L1**2 + l1e**2 - (L2 + L3) ** 2) / (2 * L1 * l1e)
    t1 = np.arctan2(-yp, x) + np.arccos(np.clip(c12, -1, 1))
    p2 = L1 * _dir(t1)
    pe = np.stack([x, yp], axis=-1)
    p3 = (pe * L2 + p2 * L3) / (L2 + L3)
    l35 = np.hypot(L0 - p3[..., 0], p3[..., 1])
    c354 = (l35**2 + L5**2 - L4**2) / (2 * l35 * L5)
    t5 = np.pi - (np.arctan2(-p3[..., 1], L0 - p3[..., 0]) + np.arccos(np.clip(c354, -1, 1)))
    reachable = (np.abs(c12) <= 1) & (np.abs(c354) <= 1)
    return np.stack([t0, t1, t5], axis=-1), reachable


def sample_angles(rng, n):
    """Motor angles uniform within the joint limits, then the toe-in guard applied by hand."""
    a = rng.uniform(C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1], size=(n, 3))
    return a, a[:, 2] - a[:, 1] <= C.TOE_IN_MAX


# --- published vectors --------------------------------------------------------------------------


def test_fk_published_vectors(float_dtype):
    angles = np.array([v[0] for v in FK_VECTORS], float_dtype)
    foot = fk(angles)
    assert foot.shape == (4, 3) and foot.dtype == float_dtype
    # robots.md prints 4 decimals of a cm: 1e-4 cm = 1e-6 m.
    np.testing.assert_allclose(np.asarray(foot) / C.CM, [v[1] for v in FK_VECTORS], atol=1e-4, rtol=0)


def test_ik_published_vectors(float_dtype):
    foot = np.array([[x * C.CM, y * C.CM, 0.0] for (x, y), _ in IK_VECTORS], float_dtype)
    angles, valid = ik(foot)
    assert angles.shape == (2, 3) and angles.dtype == float_dtype and valid.dtype == bool
    assert np.all(valid)
    # Printed to 4 decimals: rounding is 5e-5, plus float32 rounding of the solution.
    np.testing.assert_allclose(np.asarray(angles)[:, 1:], [v[1] for v in IK_VECTORS], atol=6e-5, rtol=0)
    np.testing.assert_allclose(np.asarray(angles)[:, 0], 0.0, atol=1e-7)


def test_initial_pose_is_published_foot():
    # robots.md: the initial pose (0, pi, pi/2) puts the foot at (-2.1640, -17.0277, 0) cm.
    foot = fk(C.INITIAL_MOTOR_ANGLES[None].astype(np.float32))[0]
    np.testing.assert_allclose(np.asarray(foot) / C.CM, [-2.1640, -17.0277, 0.0], atol=1e-4)


# --- FK against the numpy seed algorithm and the geometry of the closed chain ------------------


def test_fk_matches_numpy_seed_algorithm(float_dtype):
    rng = np.random.default_rng(0)
    a, ok = sample_angles(rng, N)
    with jax.enable_x64(True):
        ok &= np.asarray(closes(a))
    ok &= seed_formula_applies(a)
    assert ok.sum() > N // 2
    got = np.asarray(fk(a.astype(float_dtype)))
    want = ref_fk(np.where(ok[:, None], a, C.INITIAL_MOTOR_ANGLES))
    # float64: rounding only (1e-12 m). float32: angle rounding (2e-7 rad) times lever arms
    # of up to a few tens of cm through the chain, amplified near lock-up poses.
    tol = 1e-12 if float_dtype == np.float64 else 2e-5
    err = np.abs(got - want).max(axis=-1)[ok]
    assert err.max() < tol, err.max()


def test_leg_points_close_the_chain(float_dtype):
    rng = np.random.default_rng(1)
    a, ok = sample_angles(rng, N)
    with jax.enable_x64(True):
        ok &= np.asarray(closes(a))
    lp = jax.tree.map(np.asarray, points(a.astype(float_dtype)))
    for name in ("p1", "p2", "p3", "p4", "p5", "foot"):
        assert getattr(lp, name).shape == (N, 3) and getattr(lp, name).dtype == float_dtype
    for name in ("theta2", "theta4", "knee2", "knee4"):
        assert getattr(lp, name).shape == (N,)
    tol = 1e-12 if float_dtype == np.float64 else 1e-6
    dist = lambda p, q: np.linalg.norm(p - q, axis=-1)[ok]  # noqa: E731
    for got, want in [
        (dist(lp.p2, lp.p1), L1),
        (dist(lp.p3, lp.p2), L2),
        (dist(lp.foot, lp.p3), L3),
        (dist(lp.p3, lp.p4), L4),
        (dist(lp.p4, lp.p5), L5),
        (dist(lp.p5, lp.p1), L0),
        (dist(lp.foot, lp.p2), L2 + L3),  # p2, p3, foot on one straight link
    ]:
        np.testing.assert_allclose(got, want, atol=tol)
    # Every point lies in the leg plane rotated by t0: its normal is (0, -sin t0, cos t0).
    normal = np.stack([0 * a[:, 0], -np.sin(a[:, 0]), np.cos(a[:, 0])], axis=-1)
    for p in (lp.p2, lp.p3, lp.p4, lp.foot):
        np.testing.assert_allclose(np.sum(p * normal, axis=-1), 0.0, atol=tol)
    # theta2/theta4 point along the links; knee = link angle - motor angle, wrapped to (-pi, pi].
    planar_y = lambda p: p[:, 1] * np.cos(a[:, 0]) + p[:, 2] * np.sin(a[:, 0])  # noqa: E731
    d23 = np.stack([lp.p3[:, 0] - lp.p2[:, 0], planar_y(lp.p3) - planar_y(lp.p2)], -1)
    d43 = np.stack([lp.p3[:, 0] - lp.p4[:, 0], planar_y(lp.p3) - planar_y(lp.p4)], -1)
    np.testing.assert_allclose((L2 * _dir(lp.theta2))[ok], d23[ok], atol=tol)
    np.testing.assert_allclose((L4 * _dir(lp.theta4))[ok], d43[ok], atol=tol)
    wrap = lambda x: np.angle(np.exp(1j * x))  # noqa: E731
    atol_ang = 1e-9 if float_dtype == np.float64 else 2e-5
    np.testing.assert_allclose(wrap(lp.knee2 - (lp.theta2 - a[:, 1])), 0.0, atol=atol_ang)
    np.testing.assert_allclose(wrap(lp.knee4 - (lp.theta4 - a[:, 2])), 0.0, atol=atol_ang)
    assert np.all(np.abs(lp.knee2) <= np.pi) and np.all(np.abs(lp.knee4) <= np.pi)
    np.testing.assert_allclose(lp.foot, np.asarray(fk(a.astype(float_dtype))), atol=tol)


def test_fk_keeps_the_chain_closed_where_the_seed_formula_does_not():
    """Regression: Algorithm 1's acos sum assumes p4 lies clockwise of p2->p1. At (0, 3.7, 1.0),
    inside the joint limits, it does not, and the printed formula puts p3 off the L4 circle."""
    a = np.array([0.0, 3.7, 1.0])
    assert not seed_formula_applies(a)
    p2, p4 = L1 * _dir(a[1]), np.array([L0, 0.0]) + L5 * _dir(a[2])
    seed_p3 = p2 + L2 / (L2 + L3) * (ref_fk(a)[:2] - p2)
    assert abs(np.linalg.norm(seed_p3 - p4) - L4) > 4e-3  # printed formula: off by 4.7 mm
    with jax.enable_x64(True):
        lp = points(a[None])
        assert limits_ok(a[None])[0] and closes(a[None])[0]
        np.testing.assert_allclose(np.linalg.norm(np.asarray(lp.p3 - lp.p4)), L4, atol=1e-12)


# --- inverse kinematics -----------------------------------------------------------------------


def test_fk_then_ik_round_trip(float_dtype):
    rng = np.random.default_rng(2)
    a, ok = sample_angles(rng, N)
    with jax.enable_x64(True):
        ok &= np.asarray(closes(a))
    foot = np.asarray(fk(a.astype(float_dtype)))
    angles, valid = map(np.asarray, ik(foot))
    assert angles.shape == (N, 3) and angles.dtype == float_dtype and valid.shape == (N,)
    assert np.all(np.isfinite(angles))
    # The robot's branch (Algorithm 2 takes +acos twice): p2 clockwise of p1->foot, p4
    # counter-clockwise of p5->p3. Poses of the other working modes map to another solution.
    pe, p3 = ref_fk(a), None
    pe_planar = np.stack([pe[:, 0], -np.hypot(pe[:, 1], pe[:, 2])], -1)
    p2 = L1 * _dir(a[:, 1])
    p3 = p2 + L2 / (L2 + L3) * (pe_planar - p2)
    wrap = lambda x: np.angle(np.exp(1j * x))  # noqa: E731
    on_branch = (
        ok
        & seed_formula_applies(a)
        & (wrap(a[:, 1] - _cw(pe_planar)) >= 0)
        & (wrap(_cw(p3 - np.array([L0, 0.0])) - a[:, 2]) >= 0)
    )
    assert on_branch.sum() > N // 2
    # Every pose of the robot's branch is recovered and flagged valid.
    assert np.all(valid[on_branch])
    ang_tol = 1e-9 if float_dtype == np.float64 else 5e-3  # float32: acos near +-1 loses digits
    err = np.abs(wrap(angles - a)).max(axis=-1)[on_branch]
    assert err.max() < ang_tol, err.max()
    if float_dtype == np.float32:
        assert np.median(err) < 1e-5
    # Any pose flagged valid, on the branch or not, reaches the same foot.
    foot_back = np.asarray(fk(angles))
    # Near acos(+-1) rounding is amplified by 1/sqrt(1 - c^2): float32 angles lose up to
    # sqrt(eps) ~ 3e-4 rad (about 60 um at the foot), float64 ones about 1e-8 (1e-12 m seen).
    tol = 1e-10 if float_dtype == np.float64 else 2e-4
    foot_err = np.abs(foot_back - foot).max(axis=-1)[valid]
    assert foot_err.max() < tol and np.median(foot_err) < 1e-6
    assert np.all(np.asarray(limits_ok(angles))[valid])


def test_ik_then_fk_round_trip_on_random_targets(float_dtype):
    rng = np.random.default_rng(3)
    # Feet of random valid poses, and a box of targets around the whole workspace.
    a, ok = sample_angles(rng, N)
    with jax.enable_x64(True):
        ok &= np.asarray(closes(a))
        reachable_feet = np.asarray(fk(a))[ok][: N // 2]
    box = rng.uniform([-0.30, -0.30, -0.20], [0.30, 0.10, 0.20], size=(N - len(reachable_feet), 3))
    target = np.concatenate([reachable_feet, box]).astype(float_dtype)
    angles, valid = map(np.asarray, ik(target))
    assert angles.dtype == float_dtype and np.all(np.isfinite(angles))
    assert valid[: len(reachable_feet)].mean() > 0.9 and 0.05 < valid[len(reachable_feet) :].mean() < 0.9
    tol = 1e-12 if float_dtype == np.float64 else 2e-5
    assert np.abs(np.asarray(fk(angles)) - target)[valid].max() < tol
    # Angles and validity agree with the numpy Algorithm 2 plus the limit checks written out here.
    ref, reachable = ref_ik(target.astype(np.float64))
    in_limits = np.all((ref >= C.MOTOR_RANGES[:, 0]) & (ref <= C.MOTOR_RANGES[:, 1]), axis=-1)
    ref_valid = reachable & in_limits & (ref[:, 2] - ref[:, 1] <= C.TOE_IN_MAX)
    wrap = lambda x: np.angle(np.exp(1j * x))  # noqa: E731
    ang_tol = 1e-9 if float_dtype == np.float64 else 5e-3
    assert np.abs(wrap(angles - ref))[valid].max() < ang_tol
    # The branch check is the one check that numpy reference lacks; it only removes targets.
    assert not np.any(valid & ~ref_valid)
    if float_dtype == np.float64:
        assert (ref_valid & ~valid).mean() < 0.01


@pytest.mark.parametrize(
    ("target", "reason"),
    [
        # |pe| = 30 cm > L1 + L2 + L3 = 26 cm.
        ((0.0, -0.30, 0.0), "out of reach of the p1-p2-foot chain"),
        ((-0.07, -0.23, -0.01), "out of reach of the p5-p4-p3 chain"),
        # y > 0, z = 0: t0 = -atan2(0, -0.2) = -pi, beyond -pi/2.
        ((0.0, 0.2, 0.0), "t0 beyond its joint limit"),
        ((-0.09, -0.02, -0.04), "t1 beyond its joint limit"),
        ((0.23, -0.04, 0.01), "t5 beyond its joint limit"),
        ((-0.04, -0.25, -0.05), "toe-in guard"),
    ],
)
def test_invalid_targets_are_flagged_and_named(target, reason):
    ref, reachable = ref_ik(np.array(target))
    # The numpy reference confirms each target fails for the stated reason.
    expected = {
        "out of reach of the p1-p2-foot chain": np.linalg.norm(target) > L1 + L2 + L3,
        "out of reach of the p5-p4-p3 chain": not reachable,
        "t0 beyond its joint limit": not C.T0_RANGE[0] <= ref[0] <= C.T0_RANGE[1],
        "t1 beyond its joint limit": not C.T1_RANGE[0] <= ref[1] <= C.T1_RANGE[1],
        "t5 beyond its joint limit": not C.T5_RANGE[0] <= ref[2] <= C.T5_RANGE[1],
        "toe-in guard": ref[2] - ref[1] > C.TOE_IN_MAX,
    }[reason]
    assert expected
    angles, valid = ik(np.asarray([target], np.float32))
    assert not bool(valid[0]) and np.all(np.isfinite(np.asarray(angles)))
    with pytest.raises(ValueError, match=reason) as info:
        fb.leg_ik_checked(np.array(target))
    assert str(list(target)) in str(info.value)  # names the target, in m


def test_leg_ik_checked_batches_and_names_the_bad_index():
    good = np.array([[-0.04, -0.20, 0.0], [0.13, -0.20, 0.0]])
    out = fb.leg_ik_checked(good)
    assert out.shape == (2, 3) and out.dtype == np.float64 and isinstance(out, np.ndarray)
    np.testing.assert_allclose(out[:, 1:], [v[1] for v in IK_VECTORS], atol=6e-5)
    with pytest.raises(ValueError, match=r"index \(1,\).*out of reach"):
        fb.leg_ik_checked(np.array([good[0], [0.0, -0.3, 0.0]]))


def test_within_limits_hand_cases():
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    cases = [
        (C.INITIAL_MOTOR_ANGLES, True),
        ((0.0, 2.6, 1.35), True),
        ((0.0, lo[1] - 1e-3, 0.5), False),  # t1 below 0.25 pi
        ((0.0, 2.0, hi[2] + 1e-3), False),  # t5 above 0.75 pi
        ((hi[0] + 1e-3, 2.0, 1.0), False),  # t0 above pi/2
        ((0.0, 2.0, 2.0 + C.TOE_IN_MAX - 1e-3), True),  # toe-in just inside
        ((0.0, 2.0, 2.0 + C.TOE_IN_MAX + 1e-3), False),  # toe-in just outside
    ]
    got = np.asarray(limits_ok(np.array([c[0] for c in cases], np.float32)))
    assert got.dtype == bool
    np.testing.assert_array_equal(got, [c[1] for c in cases])


# --- differential kinematics ------------------------------------------------------------------


def _valid_poses(n, seed):
    rng = np.random.default_rng(seed)
    a, ok = sample_angles(rng, 4 * n)
    with jax.enable_x64(True):
        ok &= np.asarray(closes(a))
    # keep away from the lock-up pose, where the derivative is infinite
    lp = ref_fk(a)
    return a[ok & np.all(np.isfinite(lp), -1)][:n]


def test_jacobian_matches_central_differences():
    a = _valid_poses(256, seed=4)
    with jax.enable_x64(True):
        j = np.asarray(jac(a))
        assert j.shape == (256, 3, 3) and j.dtype == np.float64
        h = 1e-6
        cols = []
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            cols.append((np.asarray(fk(a + e)) - np.asarray(fk(a - e))) / (2 * h))
        central = np.stack(cols, axis=-1)
        # Central differences: truncation h^2 |f'''| ~ 1e-12 * O(1 m) and rounding
        # 1e-16 m / 1e-6 = 1e-10 m/rad; near lock-up poses f''' grows, so a relative bound.
        err = np.abs(j - central).max(axis=(-1, -2)) / (1.0 + np.abs(j).max(axis=(-1, -2)))
        assert err.max() < 1e-6, err.max()
        # The seed's forward differences agree to O(delta).
        fwd = np.asarray(jac_fd(a))
        err_fd = np.abs(j - fwd).max(axis=(-1, -2)) / (1.0 + np.abs(j).max(axis=(-1, -2)))
        assert np.median(err_fd) < 1e-5


def test_ik_jacobian_is_the_inverse_of_the_fk_jacobian():
    # IK(FK(t)) = t on the branch, so d IK / d foot = J^-1 wherever J is invertible.
    a = _valid_poses(256, seed=8)
    with jax.enable_x64(True):
        back, valid = map(np.asarray, ik(np.asarray(fk(a))))
        j_ik = np.asarray(jax.jit(jax.vmap(jax.jacfwd(lambda f: fb.leg_ik(f)[0])))(np.asarray(fk(back))))
        j_fk = np.asarray(jac(back))
    sigma_min = np.linalg.svd(j_fk, compute_uv=False)[:, -1]
    keep = valid & (sigma_min > 0.01)  # m/rad
    assert keep.mean() > 0.8
    np.testing.assert_allclose((j_ik @ j_fk)[keep], np.broadcast_to(np.eye(3), (keep.sum(), 3, 3)), atol=1e-8)


def test_joint_velocities_invert_the_jacobian(float_dtype):
    a = _valid_poses(256, seed=5).astype(float_dtype)
    rng = np.random.default_rng(6)
    v = rng.normal(size=(256, 3)).astype(float_dtype) * 0.1  # m/s
    w = np.asarray(qdot(a, v))
    assert w.shape == (256, 3) and w.dtype == float_dtype
    j = np.asarray(jac(a)).astype(np.float64)
    sigma_min = np.linalg.svd(j, compute_uv=False)[:, -1]
    well = sigma_min > 0.02  # m/rad; damping 1e-3 changes the answer by (1e-3 / 0.02)^2 = 0.25 %
    assert well.mean() > 0.8
    w_exact = np.linalg.solve(j, v.astype(np.float64)[:, :, None])[..., 0]
    rel = np.linalg.norm(w - w_exact, axis=-1) / np.linalg.norm(w_exact, axis=-1)
    assert rel[well].max() < 5e-3


# --- boundaries, singular poses, NaN-free gradients --------------------------------------------


def _lockup_t5(t1):
    """t5 with |p4 - p2| = L2 + L4 (p2, p3, p4 collinear): 16.16^2 + 64 + 2 (16.16)(8) cos t5 = 23^2
    in cm for t1 = pi; solved in numpy for general t1 by bisection on the closed form."""
    lo, hi = 0.0, np.pi
    p2 = L1 * _dir(t1)
    f = lambda t5: np.linalg.norm(np.array([L0, 0.0]) + L5 * _dir(t5) - p2) - (L2 + L4)  # noqa: E731
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) > 0 else (lo, mid)
    return lo


def test_lockup_t5_hand_value():
    # cm: (16.16^2 + 64 + 258.56 cos t5) = 529 -> cos t5 = (529 - 325.1456) / 258.56.
    assert abs(_lockup_t5(np.pi) - math.acos((529 - 16.16**2 - 64) / 258.56)) < 1e-12


def test_gradients_finite_at_boundaries_and_singular_poses(float_dtype):
    lockup = np.array([0.1, np.pi, _lockup_t5(np.pi)])
    lockup_out = lockup + np.array([0.0, 0.0, -0.05])  # chain cannot close: clamped
    stretched_target = np.array([0.0, -(L1 + L2 + L3), 0.0])  # IK acos argument exactly -1... +1
    folded_target = np.array([0.0, -(L2 + L3 - L1), 0.0])
    on_axis_target = np.array([-0.15, 0.0, 0.0])  # y = z = 0: t0 = atan2(0, 0)
    far_target = np.array([0.0, -0.5, 0.1])
    angles = np.stack([lockup, lockup_out, C.INITIAL_MOTOR_ANGLES]).astype(float_dtype)
    targets = np.stack([stretched_target, folded_target, on_axis_target, far_target]).astype(float_dtype)

    fk_sum = jax.jit(jax.vmap(jax.grad(lambda a: jnp.sum(fb.leg_fk(a)))))
    ik_sum = jax.jit(jax.vmap(jax.grad(lambda f: jnp.sum(fb.leg_ik(f)[0]))))
    for g in (fk_sum(angles), ik_sum(targets), jac(angles), qdot(angles, np.ones_like(angles))):
        assert np.all(np.isfinite(np.asarray(g)))
    out, valid = map(np.asarray, ik(targets))
    assert np.all(np.isfinite(out)) and not valid[3]
    with jax.enable_x64(True):
        assert list(np.asarray(closes(np.stack([lockup_out, lockup + [0, 0, 1e-6]])))) == [False, True]


def test_joint_velocities_bounded_at_the_stretched_leg(float_dtype):
    # Foot straight below p1 at full reach: p1, p2, foot collinear, so d foot / d t1 is along the
    # leg and J loses rank in the plane.
    angles = ik(np.asarray([[0.0, -(L1 + L2 + L3), 0.0]], float_dtype))[0][0]
    # hand: theta_e15 = pi/2, theta_e12 = acos(1) = 0; float32 acos near 1 keeps sqrt(eps) ~ 5e-4.
    np.testing.assert_allclose(float(angles[1]), np.pi / 2, atol=1e-6 if float_dtype == np.float64 else 1e-3)
    j = np.asarray(jac(angles[None])[0], np.float64)
    assert np.linalg.svd(j, compute_uv=False)[-1] < 1e-4  # vs > 0.02 m/rad at ordinary poses
    v = np.array([0.0, -1.0, 0.0], float_dtype)  # 1 m/s along the stretched leg
    w = np.asarray(qdot(angles[None], v[None])[0])  # default damping 1e-3 m/rad
    assert np.all(np.isfinite(w)) and np.linalg.norm(w) <= 1.0 / (2 * 1e-3) * 1.001


# --- batch shapes and dtypes ------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(), (7,), (3, 5), (1000,)])
def test_batch_shapes(shape, float_dtype):
    rng = np.random.default_rng(7)
    a = np.broadcast_to(C.INITIAL_MOTOR_ANGLES, shape + (3,)) + rng.uniform(-0.05, 0.05, shape + (3,))
    a = a.astype(float_dtype)

    @jax.jit
    def everything(a):
        foot = fb.leg_fk(a)
        back, valid = fb.leg_ik(foot)
        return foot, back, valid, fb.leg_jacobian(a), fb.joint_velocities(a, foot), fb.within_limits(a)

    foot, back, valid, j, w, lim = everything(a)
    assert foot.shape == shape + (3,) and foot.dtype == float_dtype
    assert back.shape == shape + (3,) and back.dtype == float_dtype
    assert valid.shape == shape and valid.dtype == bool and lim.shape == shape
    assert j.shape == shape + (3, 3) and j.dtype == float_dtype
    assert w.shape == shape + (3,) and w.dtype == float_dtype
    assert np.all(np.asarray(valid))
    tol = 1e-9 if float_dtype == np.float64 else 1e-4
    np.testing.assert_allclose(np.asarray(back), a, atol=tol)
    np.testing.assert_allclose(np.asarray(foot), ref_fk(a.astype(np.float64)), atol=10 * tol)


def test_leg_ik_non_finite_and_huge_targets_give_finite_angles_regression():
    # Regression (issue 13, item 6): NaN, inf and 1e30 m targets gave NaN angles inside jit. The
    # docstring's promise: finite angles, valid False. A NaN/inf target falls back to the home
    # stance's angles (INITIAL_MOTOR_ANGLES); a 1e30 m target, clipped to 1 m per coordinate,
    # stretches the leg toward it like any out-of-reach target (the 0.30 m case above), so its
    # direction must match that of a 10 m target in the same direction.
    targets = np.array(
        [[np.nan, -0.2, 0.0], [0.0, np.inf, 0.0], [0.0, -1e30, 0.0], [0.0, -10.0, 0.0], [1e30, 1e30, -1e30]],
        np.float32,
    )
    angles, valid = map(np.asarray, ik(targets))
    assert np.all(np.isfinite(angles)) and not valid.any()
    np.testing.assert_allclose(angles[0], C.INITIAL_MOTOR_ANGLES, atol=1e-6)
    np.testing.assert_allclose(angles[1], C.INITIAL_MOTOR_ANGLES, atol=1e-6)
    np.testing.assert_allclose(angles[2], angles[3], atol=1e-6)
    grads = jax.jit(jax.vmap(jax.grad(lambda f: jnp.sum(fb.leg_ik(f)[0]))))(targets)
    assert np.all(np.isfinite(np.asarray(grads)))


@pytest.mark.parametrize("shape", [(2,), (4,), (5, 2)])
def test_leg_ik_rejects_a_last_axis_other_than_3_regression(shape):
    # Regression (issue 13, item 6): (2,) and (4,) were accepted (jnp indexing clamps foot[..., 2]).
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        fb.leg_ik(np.zeros(shape, np.float32))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        jax.jit(fb.leg_ik)(np.zeros(shape, np.float32))


def test_leg_ik_checked_names_a_nan_target_as_not_finite_regression():
    # Regression (issue 13, item 6): a NaN target was explained as "out of reach".
    with pytest.raises(ValueError, match="not a finite number") as info:
        fb.leg_ik_checked(np.array([[-0.04, -0.20, 0.0], [np.nan, -0.2, 0.0]]))
    assert "out of reach" not in str(info.value) and "index (1,)" in str(info.value)


def test_regression_leg_ik_gradient_finite_at_the_shoulder_origin(float_dtype):
    # Regression: jax.grad of leg_ik was NaN at the foot target (0, 0, 0). _safe_norm floored the
    # squared norm with `maximum(sq, tiny)`; at v = 0 the two tie, half the gradient went through
    # sqrt' = 1 / (2 sqrt(tiny)), and the law of cosines' 1 / |pe|^2 overflowed (inf * 0 = NaN).
    # The target is far out of reach (too close): valid False, angles and gradients finite.
    targets = np.array(
        [[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 1e-12, 0.0], [0.0, 0.0, -1e-30]], float_dtype
    )
    grad = jax.jit(jax.vmap(jax.grad(lambda f: jnp.sum(fb.leg_ik(f)[0]))))
    jrev = jax.jit(jax.vmap(jax.jacrev(lambda f: fb.leg_ik(f)[0])))
    angles, valid = map(np.asarray, ik(targets))
    assert np.all(np.isfinite(angles)) and not valid.any()
    assert np.all(np.isfinite(np.asarray(grad(targets))))
    assert np.all(np.isfinite(np.asarray(jrev(targets))))


def test_regression_leg_ik_gradient_still_matches_central_differences():
    # The safe-norm floor (eps * 1 m) must not change the gradient where the IK is solved: jax.grad
    # of leg_ik against central differences of leg_ik itself, float64, at valid targets away from
    # the singular poses (the same draws as the Jacobian tests).
    a = _valid_poses(64, seed=11)
    with jax.enable_x64(True):
        feet = np.asarray(fk(a))
        _, valid = map(np.asarray, ik(feet))
        feet = feet[valid]
        j = np.asarray(jax.jit(jax.vmap(jax.jacrev(lambda f: fb.leg_ik(f)[0])))(feet))
        h = 1e-7  # m; central: truncation h^2 |f'''| and rounding 1e-16 rad / h, both < 1e-8 rad/m
        cols = []
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            cols.append((np.asarray(ik(feet + e)[0]) - np.asarray(ik(feet - e)[0])) / (2 * h))
        central = np.stack(cols, axis=-1)
    assert len(feet) > 32
    err = np.abs(j - central).max(axis=(-1, -2)) / (1.0 + np.abs(j).max(axis=(-1, -2)))
    assert err.max() < 1e-5, err.max()
