"""terrain.ground_height against MuJoCo C's own ray casting on the same compiled model."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import terrain
from quadson_mjx.robots.quadson import model as qmodel


@pytest.fixture(scope="module")
def rough():
    m = qmodel.load_model("rough")
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _ray_height(m, d, x, y, top=1.0):
    """Ground z under (x, y) by mujoco.mj_ray straight down, floor group only (the robot's geoms
    are in groups 2 and 3); None where the ray misses."""
    group = np.zeros(6, np.uint8)
    group[m.geom_group[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")]] = 1
    geom = np.zeros(1, np.int32)
    dist = mujoco.mj_ray(m, d, np.array([x, y, top]), np.array([0.0, 0.0, -1.0]), group, 1, -1, geom)
    return None if dist < 0 else top - dist


def test_ground_height_matches_mj_ray_on_the_stone_field(rough):
    m, d = rough
    field = terrain.heightfield(m)
    rng = np.random.default_rng(0)
    # 2000 random points, plus grid vertices and cell diagonals, where the triangulation shows
    xy = rng.uniform(-3.99, 3.99, (2000, 2))
    cell = 0.04  # constants.ROUGH_CELL
    grid = np.array([[-1.0 + i * cell, 0.5 + j * cell] for i in range(5) for j in range(5)])
    diag = grid[:-1] + np.array([0.3, 0.7]) * cell  # above the diagonal of a cell
    diag2 = grid[:-1] + np.array([0.7, 0.3]) * cell  # below it
    xy = np.concatenate([xy, grid, diag, diag2])
    ours = np.asarray(jax.jit(jax.vmap(lambda p: terrain.ground_height(field, p)))(jnp.asarray(xy)))
    ref = np.array([_ray_height(m, d, x, y) for x, y in xy])
    assert ours.shape == (len(xy),) and ours.dtype == np.float32
    # float32 heights of at most 4 cm: 1e-6 m is a few float32 ulps of 1 m (the ray's top)
    np.testing.assert_allclose(ours, ref, atol=1e-6)
    assert ref.max() > 0.03 and (ref < 1e-9).mean() > 0.3  # stones and bare ground both sampled


def test_off_the_field_clamps_to_the_border_and_is_flagged(rough):
    m, d = rough
    field = terrain.heightfield(m)
    assert _ray_height(m, d, 4.2, 1.0) is None  # MuJoCo: no ground beyond the field
    inside, outside = jnp.array([3.98, 1.0]), jnp.array([4.2, 1.0])
    # the border height, by a ray 10 um inside the edge (stone slopes stay under 1: < 1e-5 m apart)
    np.testing.assert_allclose(
        terrain.ground_height(field, outside), _ray_height(m, d, 3.99999, 1.0), atol=1e-5
    )
    assert bool(terrain.on_field(field, inside)) and not bool(terrain.on_field(field, outside))
    assert not bool(terrain.on_field(field, inside, margin_m=0.05))


def test_flat_scene_is_zero_everywhere():
    m = qmodel.load_model("flat")
    assert terrain.heightfield(m) is None
    xy = jnp.array([[0.0, 0.0], [100.0, -3.0]])
    np.testing.assert_array_equal(terrain.ground_height(None, xy), [0.0, 0.0])
    assert bool(jnp.all(terrain.on_field(None, xy)))


def test_scan_offsets_by_hand():
    got = terrain.scan_offsets(3, 0.1)
    want = [[-0.1, -0.1], [-0.1, 0.0], [-0.1, 0.1], [0.0, -0.1], [0.0, 0.0], [0.0, 0.1], [0.1, -0.1]]
    np.testing.assert_allclose(got[:7], want, atol=1e-12)
    assert got.shape == (9, 2) and terrain.scan_offsets(0, 0.1).shape == (0, 2)


def test_ground_scan_matches_mj_ray_around_a_turned_robot(rough):
    """A 5 x 5 scan 4 cm apart, turned by the heading, on the stone field: every point's height by
    MuJoCo's ray cast minus the ray's height under the robot; the rotation written out by hand."""
    m, d = rough
    field = terrain.heightfield(m)
    offsets = terrain.scan_offsets(5, 0.04)
    scan = jax.jit(lambda xy, yaw: terrain.ground_scan(field, xy, yaw, jnp.asarray(offsets, jnp.float32)))
    for (x, y), yaw in (((0.7, -1.1), 0.6), ((-2.3, 1.9), -2.4), ((1.5, 2.5), 3.0)):
        got = np.asarray(scan(jnp.array([x, y], jnp.float32), jnp.float32(yaw)))
        c, s = np.cos(yaw), np.sin(yaw)
        under = _ray_height(m, d, x, y)
        want = [_ray_height(m, d, x + c * dx - s * dy, y + s * dx + c * dy) - under for dx, dy in offsets]
        np.testing.assert_allclose(got, want, atol=2e-6)
        assert np.ptp(want) > 0.005  # the stones show in every scan
    np.testing.assert_array_equal(terrain.ground_scan(None, jnp.zeros(2), 1.0, jnp.asarray(offsets)), 0.0)
