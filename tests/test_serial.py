"""Serial roll-pitch-pitch leg: DH forward kinematics and closed-form IK against published vectors,
hand arithmetic, an independent numpy reading of seed 003 eq. 5-10 and seed 002's quadrant cases, and
finite differences. Production path: jit(vmap(...)), compiled once per module.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from quadson_mjx.serial import (
    CARAMEL,
    CARAMEL_LIMITS,
    CLIP_REACH,
    LEFT,
    RIGHT,
    WEEFEE_LARGE,
    WEEFEE_SMALL,
    SerialLeg,
    caramel_angles,
    caramel_commands,
    dh_transform,
    serial_fk,
    serial_fk_chain,
    serial_ik,
    serial_ik_checked,
)

PRESETS = {"caramel": CARAMEL, "weefee_small": WEEFEE_SMALL, "weefee_large": WEEFEE_LARGE}
SIDES = {"left": LEFT, "right": RIGHT}
CASES = [(p, s) for p in PRESETS for s in SIDES]
N = 4000


@pytest.fixture(scope="module")
def fk():
    return jax.jit(jax.vmap(serial_fk, in_axes=(0, None, None)))


@pytest.fixture(scope="module")
def chain():
    return jax.jit(jax.vmap(serial_fk_chain, in_axes=(0, None, None)))


@pytest.fixture(scope="module")
def ik():
    return jax.jit(jax.vmap(serial_ik, in_axes=(0, None, None, None)))


@pytest.fixture(scope="module")
def fk_jac():
    """d foot / d angles (..., 3, 3)."""
    return jax.jit(jax.vmap(jax.jacfwd(serial_fk), in_axes=(0, None, None)))


@pytest.fixture(scope="module")
def ik_jac():
    """d angles / d target (..., 3, 3), for finiteness checks at the boundaries."""
    return jax.jit(jax.vmap(jax.jacfwd(lambda t, leg, s: serial_ik(t, leg, s)[0]), in_axes=(0, None, None)))


def wrap(a):
    return np.angle(np.exp(1j * np.asarray(a, dtype=float)))


def fk_closed(q, leg, s):
    """Hand derivation, independent of the DH chain: leg-plane foot (x_p, z_p), then roll about x."""
    l1, l2, l3 = leg
    q1, q2, q3 = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    xp = -l2 * np.sin(q2) - l3 * np.sin(q2 + q3)  # +q2 about +y swings the femur backward
    zp = -l2 * np.cos(q2) - l3 * np.cos(q2 + q3)
    y = s * l1 * np.cos(q1) - zp * np.sin(q1)
    z = s * l1 * np.sin(q1) + zp * np.cos(q1)
    return np.stack([xp, y, z], axis=-1)


def seed003_thetas(p, leg, s):
    """Seed 003 eq. 5-10 as Caramel's code evaluates them (x forward, y left, z up; s = +1 left)."""
    l1, l2, l3 = leg
    x, y, z = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    a = np.sqrt(y**2 + z**2 - l1**2)
    big_a = (a**2 + x**2 + l2**2 - l3**2) / (2 * l2 * np.sqrt(a**2 + x**2))
    big_b = (a**2 + x**2 - l2**2 - l3**2) / (2 * l2 * l3)
    th1 = np.arctan2(y, -z) - np.arctan2(s * l1, a)
    th2 = np.pi / 2 - np.arctan2(a, x) - np.arctan2(np.sqrt(1 - big_a**2), big_a)
    th3 = np.arctan2(np.sqrt(1 - big_b**2), big_b)
    return np.stack([th1, th2, th3], axis=-1)


def random_branch_angles(rng, leg, n):
    """Random angles on the IK's branch: knee backward away from straight/folded, foot below the
    femur axis in the leg plane (depth > 5% of the leg) so the roll is well conditioned."""
    q = np.stack(
        [
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(-np.pi, np.pi, n),
            rng.uniform(-np.pi + 0.15, -0.15, n),
        ],
        axis=-1,
    )
    _, l2, l3 = leg
    zp = -l2 * np.cos(q[:, 1]) - l3 * np.cos(q[:, 1] + q[:, 2])
    return q[zp < -0.05 * (l2 + l3)]


# --- published vectors -------------------------------------------------------------------------------


def test_caramel_published_ik_vectors(ik):
    # robots.md, Caramel (seed 003): hip frame [m] -> its joint commands (roll, pitch, knee) [rad], which
    # are pitch = -(theta2 + pi/4), knee = -(theta3 - pi/2) of seed 003's thetas; ours: theta = (q1, -q2, -q3).
    targets = {RIGHT: [0.0, -0.048, -0.17], LEFT: [0.0, 0.048, -0.12]}
    published = {RIGHT: [0.0, -0.00174, 0.00347], LEFT: [0.0, math.pi / 12, -math.pi / 6]}
    atol = {RIGHT: 6e-6, LEFT: 2e-6}  # right: printed to 3 significant figures
    for s in (RIGHT, LEFT):
        # The independent reading of seed 003 reproduces the published numbers through the mapping ...
        th = seed003_thetas(np.array(targets[s]), CARAMEL, s)
        ref_cmd = np.array([th[0], -(th[1] + np.pi / 4), -(th[2] - np.pi / 2)])
        np.testing.assert_allclose(ref_cmd, published[s], atol=atol[s])
        # ... and so does this module's IK.
        q, valid = ik(jnp.array([targets[s]], jnp.float32), CARAMEL, s, None)
        assert bool(valid[0])
        np.testing.assert_allclose(caramel_commands(q)[0], published[s], atol=atol[s])
        np.testing.assert_allclose(np.array([q[0, 0], -q[0, 1], -q[0, 2]]), th, atol=2e-6)
    # Hand check of the left vector: x = 0, D = 0.12 = L2 = L3 is an equilateral triangle, so
    # q3 = -(pi - pi/3) = -2 pi/3 and the femur leans back by pi/3 from straight down: q2 = pi/3.
    q, _ = ik(jnp.array([targets[LEFT]]), CARAMEL, LEFT, None)
    np.testing.assert_allclose(q[0], [0.0, math.pi / 3, -2 * math.pi / 3], atol=2e-6)


def test_angles_match_seed003_equations_over_the_workspace(fk, ik):
    rng = np.random.default_rng(3)
    for s in (LEFT, RIGHT):
        q = rng.uniform(CARAMEL_LIMITS[:, 0], CARAMEL_LIMITS[:, 1], size=(N, 3))
        p = np.asarray(fk(jnp.asarray(q, jnp.float32), CARAMEL, s), dtype=float)
        got, valid = ik(jnp.asarray(p, jnp.float32), CARAMEL, s, None)
        th = seed003_thetas(p, CARAMEL, s)
        assert np.all(valid)
        mine = np.stack([got[:, 0], -got[:, 1], -got[:, 2]], axis=-1)
        np.testing.assert_allclose(wrap(mine - th), 0.0, atol=2e-3)  # float32 IK near the knee's limits
        np.testing.assert_allclose(wrap(got - q), 0.0, atol=2e-3)


def test_caramel_limits_and_command_mapping():
    # Command limits roll +-pi/4, pitch +-pi/3, knee +-pi/5 (robots.md) with q2 = pitch + pi/4,
    # q3 = knee - pi/2: q2 in [-pi/12, 7 pi/12], q3 in [-7 pi/10, -3 pi/10].
    expected = [
        [-math.pi / 4, math.pi / 4],
        [-math.pi / 12, 7 * math.pi / 12],
        [-0.7 * math.pi, -0.3 * math.pi],
    ]
    np.testing.assert_allclose(CARAMEL_LIMITS, expected, atol=1e-12)
    q = jnp.array([0.1, 0.2, -1.0])
    np.testing.assert_allclose(caramel_commands(q), [0.1, 0.2 - math.pi / 4, -1.0 + math.pi / 2], atol=1e-6)
    np.testing.assert_allclose(caramel_angles(caramel_commands(q)), q, atol=1e-6)


# --- forward kinematics by hand ----------------------------------------------------------------------


def test_dh_transform_by_hand():
    # theta = pi/2, d = 0.1, a = 0.2, alpha = -pi/2: columns x = (0, 1, 0), y = Rz x Rx(-90) y = (0, 0, -1)
    # rotated: (0, 0, -1) -> y column (0, 0, -1); z = (-1, 0, 0); origin (a cos, a sin, d) = (0, 0.2, 0.1).
    t = np.asarray(dh_transform(math.pi / 2, 0.1, 0.2, -math.pi / 2))
    np.testing.assert_allclose(t[:3, :3], [[0, 0, -1], [1, 0, 0], [0, -1, 0]], atol=1e-7)
    np.testing.assert_allclose(t[:3, 3], [0.0, 0.2, 0.1], atol=1e-7)


@pytest.mark.parametrize("side", [LEFT, RIGHT])
def test_fk_by_hand_caramel(chain, side):
    l1, l2, l3 = CARAMEL
    q = jnp.array(
        [
            [0.0, 0.0, 0.0],  # zero pose: straight down in the plane y = s L1
            [0.0, 0.0, -math.pi / 2],  # knee -90 deg about +y turns the tibia from down to forward
            [math.pi / 2, 0.0, 0.0],  # roll +90 deg about x: (y, z) = (s L1, -0.24) -> (0.24, s L1)
            [0.0, math.pi / 2, 0.0],  # pitch +90 deg about +y: straight leg points backward
        ]
    )
    pts = np.asarray(chain(q, CARAMEL, side))
    s = side
    np.testing.assert_allclose(
        pts[0], [[0, 0, 0], [0, s * l1, 0], [0, s * l1, -l2], [0, s * l1, -(l2 + l3)]], atol=1e-7
    )
    # 0.048 m offset, knee at 0.12 m below, foot 0.12 m ahead of the knee: (0.12, 0.048 s, -0.12).
    np.testing.assert_allclose(pts[1, -1], [0.12, 0.048 * s, -0.12], atol=1e-7)
    # y' = y cos 90 - z sin 90 = 0.24, z' = y sin 90 + z cos 90 = 0.048 s.
    np.testing.assert_allclose(pts[2, -1], [0.0, 0.24, 0.048 * s], atol=1e-7)
    np.testing.assert_allclose(pts[3, -1], [-0.24, 0.048 * s, 0.0], atol=1e-7)


@pytest.mark.parametrize("preset,side", CASES)
def test_fk_matches_closed_form_and_link_lengths(chain, preset, side):
    leg, s = PRESETS[preset], SIDES[side]
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, size=(N, 3))
    pts = np.asarray(chain(jnp.asarray(q, jnp.float32), leg, s), dtype=float)
    np.testing.assert_allclose(pts[:, -1], fk_closed(q, leg, s), atol=2e-7)
    # Links keep their lengths; the femur joint sits L1 from the roll axis, perpendicular to it.
    np.testing.assert_allclose(np.linalg.norm(pts[:, 1] - pts[:, 0], axis=-1), leg.hip_offset, atol=1e-7)
    np.testing.assert_allclose(pts[:, 1, 0], 0.0, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(pts[:, 2] - pts[:, 1], axis=-1), leg.femur, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(pts[:, 3] - pts[:, 2], axis=-1), leg.tibia, atol=1e-7)


# --- round trips -------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset,side", CASES)
def test_fk_ik_round_trip(fk, ik, preset, side):
    leg, s = PRESETS[preset], SIDES[side]
    q = random_branch_angles(np.random.default_rng(2), leg, N)
    assert len(q) > N // 4
    p = fk(jnp.asarray(q, jnp.float32), leg, s)
    got, valid = ik(p, leg, s, None)
    assert np.all(valid)
    np.testing.assert_allclose(wrap(got - q), 0.0, atol=1e-3)  # float32, knee kept >= 0.15 rad from the ends
    np.testing.assert_allclose(fk(got, leg, s), p, atol=1e-6)


@pytest.mark.parametrize("preset,side", CASES)
def test_ik_fk_round_trip_and_reach_flags(fk, ik, preset, side):
    leg, s = PRESETS[preset], SIDES[side]
    l1, l2, l3 = leg
    rng = np.random.default_rng(4)
    p = rng.uniform(-1.1, 1.1, size=(N, 3)) * (l1 + l2 + l3)
    got, valid = ik(jnp.asarray(p, jnp.float32), leg, s, None)
    got, valid = np.asarray(got), np.asarray(valid)
    assert np.all(np.isfinite(got))
    # Independent reach criterion in float64: outside the offset cylinder, |L2 - L3| <= R <= L2 + L3.
    depth_sq = p[:, 1] ** 2 + p[:, 2] ** 2 - l1**2
    reach = np.sqrt(np.maximum(depth_sq, 0.0) + p[:, 0] ** 2)
    reachable = (depth_sq >= 0) & (reach <= l2 + l3) & (reach >= abs(l2 - l3))
    margin = (
        (np.abs(depth_sq) > 1e-6) & (np.abs(reach - (l2 + l3)) > 1e-6) & (np.abs(reach - abs(l2 - l3)) > 1e-6)
    )
    np.testing.assert_array_equal(valid[margin], reachable[margin])
    assert 0.1 < valid.mean() < 0.9
    np.testing.assert_allclose(np.asarray(fk(jnp.asarray(got), leg, s))[valid], p[valid], atol=5e-6)


@pytest.mark.parametrize("side", [LEFT, RIGHT])
def test_quadrant_sweep(fk, ik, side):
    """Seed 002's four (y, z) cases, each ahead of and behind the hip, come out of one atan2."""
    l1 = CARAMEL.hip_offset
    signs = np.array([(sx, sy, sz) for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], dtype=float)
    p = signs * np.array([0.05, 0.10, 0.10])  # r = 0.141 > L1; R = sqrt(0.05^2 + 0.133^2) = 0.142 < 0.24
    got, valid = ik(jnp.asarray(p, jnp.float32), CARAMEL, side, None)
    assert np.all(valid)
    np.testing.assert_allclose(fk(got, CARAMEL, side), p, atol=1e-6)
    assert np.all(np.asarray(got)[:, 2] < 0)  # knee backward everywhere
    # Seed 002 case by case (its ratio y/z read as z/y; see serial.py): alpha1 in [0, 2 pi), then
    # theta1 = alpha1 + 90 deg - asin(La / A); equal to q1 mod 2 pi for left legs, whose offset is +L1.
    y, z = p[:, 1], p[:, 2]
    t = np.abs(np.arctan(z / y))
    alpha1 = np.select(
        [(y > 0) & (z > 0), (y < 0) & (z > 0), (y < 0) & (z < 0), (y > 0) & (z < 0)],
        [t, np.pi - t, np.pi + t, 2 * np.pi - t],
    )
    theta1 = alpha1 + np.pi / 2 - side * np.arcsin(l1 / np.hypot(y, z))
    np.testing.assert_allclose(wrap(np.asarray(got)[:, 0] - theta1), 0.0, atol=1e-6)


# --- derivatives -------------------------------------------------------------------------------------


def test_fk_jacobian_matches_central_differences(fk, fk_jac, ik_jac):
    with jax.enable_x64(True):
        rng = np.random.default_rng(5)
        q = jnp.asarray(rng.uniform(-np.pi, np.pi, size=(64, 3)), jnp.float64)
        h = 1e-6
        for leg, s in ((CARAMEL, LEFT), (WEEFEE_LARGE, RIGHT)):
            jac = fk_jac(q, leg, s)
            assert jac.dtype == jnp.float64 and jac.shape == (64, 3, 3)
            # Central differences: O(h^2 |p'''|) ~ 1e-13 truncation, ~1e-10 rounding.
            fd = jnp.stack(
                [(fk(q + h * e, leg, s) - fk(q - h * e, leg, s)) / (2 * h) for e in jnp.eye(3)], axis=-1
            )
            np.testing.assert_allclose(jac, fd, atol=1e-8)
            # IK is the inverse on its branch: J_ik(FK(q)) J_fk(q) = I.
            qb = jnp.asarray(random_branch_angles(rng, leg, 256))
            j_fk = fk_jac(qb, leg, s)
            j_ik = ik_jac(fk(qb, leg, s), leg, s)
            np.testing.assert_allclose(j_ik @ j_fk, np.broadcast_to(np.eye(3), j_fk.shape), atol=1e-8)


def test_finite_gradients_at_the_reach_boundaries(ik, ik_jac, fk):
    l1, l2, l3 = CARAMEL
    for s in (LEFT, RIGHT):
        boundary = jnp.array(
            [
                [0.0, s * l1, -(l2 + l3)],  # straight leg: full reach
                [0.1, s * l1, 0.0],  # on the hip-offset cylinder: depth 0, leg horizontal, reachable
                [0.0, s * l1, -1e-9],  # folded flat: L2 = L3, the foot on the femur joint
            ],
            jnp.float32,
        )
        got, valid = ik(boundary, CARAMEL, s, None)
        assert np.all(valid)
        np.testing.assert_allclose(fk(got, CARAMEL, s)[:2], boundary[:2], atol=1e-6)
        # Folded flat the knee clip leaves the foot L sqrt(2 eps) = 0.12 * 4.9e-4 m = 59 um out.
        np.testing.assert_allclose(fk(got, CARAMEL, s)[2], boundary[2], atol=1e-4)
        jac = ik_jac(boundary, CARAMEL, s)
        assert np.all(np.isfinite(jac))


# --- unreachable targets ---------------------------------------------------------------------------


def test_unreachable_flagged_finite_and_eager_helper_raises(ik, ik_jac):
    leg, s = WEEFEE_SMALL, RIGHT  # reach 0.11 m, dead zone |50 - 60| mm = 0.01 m, offset 0.03 m
    bad = {
        "inside the hip-offset cylinder": [0.0, 0.0, 0.0],  # on the roll axis: atan2(0, 0) regression
        "out of reach": [0.5, 0.0, -0.1],
        "too close": [0.0, -0.03, -0.005],  # 5 mm below the femur joint
    }
    p = jnp.array(list(bad.values()), jnp.float32)
    got, valid = ik(p, leg, s, None)
    assert not np.any(valid)
    assert np.all(np.isfinite(got))
    assert np.all(np.isfinite(ik_jac(p, leg, s)))
    for reason, target in bad.items():
        with pytest.raises(ValueError, match=reason) as err:
            serial_ik_checked(target, leg, s)
        assert f"({target[0]:.6g}, {target[1]:.6g}, {target[2]:.6g}) m" in str(err.value)
    # A reachable target passes and agrees with the jitted IK.
    ok = [0.02, -0.04, -0.08]
    np.testing.assert_allclose(serial_ik_checked(ok, leg, s), serial_ik(jnp.array(ok), leg, s)[0], atol=1e-6)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_regression_serial_ik_non_finite_target_is_invalid_with_finite_angles_and_gradients(dtype):
    # Regression: under jit a NaN or inf coordinate gave NaN angles and gradients (against the
    # docstring). Now: valid False, the home angles (foot at (0, s L1, -max(L2, L3)): by hand for
    # Caramel, L2 = L3 = 0.12 m, depth 0.12 m = L2: an equilateral femur-tibia-line triangle, so
    # q3 = -(pi - pi/3) = -2 pi/3, q2 = pi/3, q1 = 0), zero gradients; a 1e30 m target (its squares
    # overflow float32) is solved as its clip at CLIP_REACH leg lengths, out of reach either way.
    with jax.enable_x64(dtype == "float64"):
        dt = jnp.dtype(dtype)
        targets = jnp.array(
            [
                [np.nan, 0.05, -0.2],
                [np.inf, 0.05, -0.2],
                [0.0, -np.inf, -0.2],
                [0.0, 0.05, np.nan],
                [0.0, 0.0, -1e30],
                [0.0, 0.0, -CLIP_REACH * sum(CARAMEL)],
            ],
            dt,
        )
        ik_lim = jax.jit(jax.vmap(serial_ik, in_axes=(0, None, None, None)))
        angles, valid = map(np.asarray, ik_lim(targets, CARAMEL, LEFT, CARAMEL_LIMITS))
        assert angles.dtype == dt and np.all(np.isfinite(angles)) and not valid.any()
        np.testing.assert_allclose(angles[:4], [[0.0, math.pi / 3, -2 * math.pi / 3]] * 4, atol=1e-6)
        np.testing.assert_allclose(angles[4], angles[5], atol=1e-6)
        jac = jax.jit(jax.vmap(jax.jacrev(lambda t: serial_ik(t, CARAMEL, LEFT)[0])))(targets)
        grad = jax.jit(jax.vmap(jax.grad(lambda t: jnp.sum(serial_ik(t, CARAMEL, LEFT)[0]))))(targets)
        assert np.all(np.isfinite(np.asarray(jac))) and np.all(np.isfinite(np.asarray(grad)))
        np.testing.assert_array_equal(np.asarray(jac)[:4], 0.0)


def test_regression_serial_ik_checked_blames_a_nan_target_on_being_non_finite():
    # Regression: a NaN y was "inside the hip-offset cylinder", a NaN x "out of reach".
    for target in ([0.0, np.nan, -0.2], [np.nan, 0.05, -0.2], [0.0, 0.05, np.inf]):
        with pytest.raises(ValueError, match="not a finite number") as err:
            serial_ik_checked(target, CARAMEL, LEFT)
        assert "cylinder" not in str(err.value) and "out of reach" not in str(err.value)


def test_joint_limits():
    # Standing foot of a left leg rolled 60 deg about x: roll 60 deg > pi/4, other joints in range.
    c, sn = math.cos(math.pi / 3), math.sin(math.pi / 3)
    l1, h = CARAMEL.hip_offset, 0.17
    target = jnp.array([0.0, l1 * c + h * sn, l1 * sn - h * c])
    q, valid = serial_ik(target, CARAMEL, LEFT)
    np.testing.assert_allclose(q[0], math.pi / 3, atol=1e-6)
    assert bool(valid)
    _, valid = jax.jit(serial_ik)(target, CARAMEL, LEFT, CARAMEL_LIMITS)
    assert not bool(valid)
    with pytest.raises(ValueError, match="beyond joint limits: hip_roll"):
        serial_ik_checked(np.asarray(target), CARAMEL, LEFT, CARAMEL_LIMITS)
    # The published stance vectors lie inside Caramel's limits.
    stance = jnp.array([[0.0, 0.048, -0.12], [0.0, -0.048, -0.17]])
    _, valid = serial_ik(stance, CARAMEL, jnp.array([LEFT, RIGHT]), CARAMEL_LIMITS)
    assert np.all(valid)


# --- shapes and dtypes -------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(), (7,), (3, 5)])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_batch_shapes_and_dtypes(shape, dtype):
    with jax.enable_x64(dtype == "float64"):
        dt = jnp.dtype(dtype)
        rng = np.random.default_rng(6)
        # q2 + q3 in [-1.4, 0.6] keeps the foot below the femur axis: the IK's branch.
        q = jnp.asarray(rng.uniform(-0.5, 0.5, size=shape + (3,)) + [0.0, 0.8, -1.2], dt)
        leg = SerialLeg(*(jnp.asarray(v, dt) for v in WEEFEE_LARGE))
        p = jax.jit(serial_fk)(q, leg, RIGHT)
        pts = jax.jit(serial_fk_chain)(q, leg, RIGHT)
        got, valid = jax.jit(serial_ik)(p, leg, RIGHT)
        assert p.shape == shape + (3,) and pts.shape == shape + (4, 3)
        assert got.shape == shape + (3,) and valid.shape == shape
        assert p.dtype == dt and pts.dtype == dt and got.dtype == dt and valid.dtype == jnp.bool_
        assert bool(jnp.all(valid))
        np.testing.assert_allclose(got, q, atol=1e-3 if dtype == "float32" else 1e-9)
        # A per-leg side broadcasts with the batch.
        sides = jnp.where(jnp.arange(shape[-1] if shape else 1) % 2 == 0, LEFT, RIGHT).astype(dt)
        sides = sides.reshape(shape[-1:]) if shape else sides[0]
        p2 = jax.jit(serial_fk)(q, leg, sides)
        got2, valid2 = jax.jit(serial_ik)(p2, leg, sides)
        assert bool(jnp.all(valid2))
        np.testing.assert_allclose(got2, q, atol=1e-3 if dtype == "float32" else 1e-9)
