"""The tiled ground (terrain_tiles): tile heights by hand, the height query against MuJoCo's ray casts
on every tile type, the height-field file MuJoCo loads, spawns and the curriculum's update rule."""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from quadson_mjx import terrain
from quadson_mjx import terrain_tiles as T

# small enough for the CPU: 1 m tiles, 3 levels, every type (401 x 151 samples)
SPEC = T.TerrainSpec(tile_m=1.0, levels=3, seed=5)
# the same on 4 cm cells (env.tiles.cell_m), 201 x 76 samples
COARSE = T.TerrainSpec(tile_m=1.0, levels=3, seed=5, cell_m=0.04)


@pytest.fixture(scope="module")
def grid():
    return T.tile_grid(SPEC)


def _tile(grid, spec, kind, level):
    """The n x n samples tile (kind, level) owns (its left and lower borders, not the right and upper
    ones, which are the next tiles' first samples)."""
    n, t = spec.cells_per_tile, spec.types.index(kind)
    return grid[level * n : level * n + n, t * n : t * n + n]


def test_layout_and_reproducibility(grid):
    n = SPEC.cells_per_tile
    assert n == 50 and grid.shape == (3 * n + 1, 8 * n + 1)
    assert np.all(np.isfinite(grid))
    np.testing.assert_array_equal(T.tile_grid(SPEC), grid)  # the same spec, the same ground
    other = T.tile_grid(T.TerrainSpec(tile_m=1.0, levels=3, seed=6))
    assert not np.array_equal(_tile(other, SPEC, "stones", 1), _tile(grid, SPEC, "stones", 1))
    np.testing.assert_array_equal(_tile(other, SPEC, "slope_up", 1), _tile(grid, SPEC, "slope_up", 1))
    # the edges of these tiles are at 0, so they meet their neighbours without a cliff
    for kind in ("slope_up", "slope_down", "stairs_up", "stairs_down", "waves", "flat"):
        for level in range(SPEC.levels):
            tile = _tile(grid, SPEC, kind, level)
            edge = np.concatenate([tile[0], tile[:, 0]])  # the others are the next tiles' first
            np.testing.assert_allclose(edge, 0.0, atol=1e-12, err_msg=f"{kind} {level}")


def test_tile_heights_by_hand(grid):
    n, half = SPEC.cells_per_tile, SPEC.tile_m / 2
    for level in range(SPEC.levels):
        d = (level + 1) / 3
        centre = n // 2
        # a pyramid of 20 d degrees over 0.5 m: the centre tan(20 d) * 0.5 below (up) or above (down)
        want = math.tan(math.radians(20 * d)) * half
        assert _tile(grid, SPEC, "slope_up", level)[centre, centre] == pytest.approx(-want, abs=1e-12)
        assert _tile(grid, SPEC, "slope_down", level)[centre, centre] == pytest.approx(want, abs=1e-12)
        # halfway out (0.25 m from the centre along x) the slope has risen half of it
        assert _tile(grid, SPEC, "slope_down", level)[centre, centre + 12] == pytest.approx(
            math.tan(math.radians(20 * d)) * (half - 0.24), abs=1e-12
        )
        # stairs of 0.15 m treads over 0.5 m: 3 whole treads from the edge to the centre, 4 d cm each
        stairs = _tile(grid, SPEC, "stairs_down", level)
        assert stairs[centre, centre] == pytest.approx(3 * 0.04 * d, abs=1e-12)
        assert stairs[centre, 0 + 7] == pytest.approx(0.0, abs=1e-12)  # 0.14 m in: outer ring
        assert stairs[centre, 0 + 8] == pytest.approx(0.04 * d, abs=1e-12)  # 0.16 m in: one step up
        assert _tile(grid, SPEC, "stairs_up", level)[centre, 8] == pytest.approx(-0.04 * d, abs=1e-12)
        # waves: sin(2 pi x / 0.5) sin(2 pi y / 0.5) from the tile's corner; a crest at (0.125, 0.125)
        waves = _tile(grid, SPEC, "waves", level)
        assert waves[6, 6] == pytest.approx(0.03 * d * math.sin(math.pi / 2 * 0.12 / 0.125) ** 2, rel=1e-9)
        assert np.max(np.abs(waves)) <= 0.03 * d + 1e-12
        stones, boxes = _tile(grid, SPEC, "stones", level), _tile(grid, SPEC, "obstacles", level)
        assert 0 < stones.max() <= 0.03 * d + 1e-12 and stones.min() == 0.0
        np.testing.assert_allclose(np.unique(boxes), [0.0, 0.03 * d], atol=1e-12)  # ground and box tops
        assert np.all(_tile(grid, SPEC, "flat", level) == 0.0)


def _model(heights, spec):
    size, z = T.hfield_size(heights, spec)
    nrow, ncol = heights.shape
    xml = f"""<mujoco><asset><hfield name="ground" nrow="{nrow}" ncol="{ncol}"
      size="{" ".join(map(str, size))}"/></asset><worldbody>
      <geom name="floor" type="hfield" hfield="ground" pos="0 0 {z}"/></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    m.hfield_data[:] = T.hfield_data(heights)
    return m


@pytest.mark.parametrize("spec", [SPEC, COARSE], ids=["2cm", "4cm"])
def test_height_query_equals_mujoco_ray_casts_on_every_tile(spec, grid):
    if spec is not SPEC:
        grid = T.tile_grid(spec)
        assert grid.shape == (3 * 25 + 1, 8 * 25 + 1)
    m = _model(grid, spec)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    field = terrain.heightfield(m)
    np.testing.assert_allclose(np.asarray(field.heights) + float(field.origin[2]), grid, atol=2e-6)
    query = jax.jit(jax.vmap(lambda xy: terrain.ground_height(field, xy)))
    rng = np.random.default_rng(0)
    geomid = np.zeros(1, np.int32)
    for t, kind in enumerate(spec.types):
        for level in range(spec.levels):
            c = T.tile_center(spec, t, level)
            xy = c + rng.uniform(-0.5, 0.5, (64, 2)) * spec.tile_m
            got = np.asarray(query(jnp.asarray(xy, jnp.float32)))
            top = grid.max() + 1.0
            want = [
                top - mujoco.mj_ray(m, d, np.array([*p, top]), np.array([0.0, 0, -1]), None, 1, -1, geomid)
                for p in xy
            ]
            np.testing.assert_allclose(got, want, atol=1e-5, err_msg=f"{kind} level {level}")


def test_hfield_file_loads_as_the_grid(grid, tmp_path):
    T.write_hfield_bin(tmp_path / "ground.bin", grid)
    size, z = T.hfield_size(grid, SPEC)
    xml = f"""<mujoco><asset><hfield name="ground" file="ground.bin" size="{" ".join(map(str, size))}"/>
      </asset><worldbody><geom name="floor" type="hfield" hfield="ground" pos="0 0 {z}"/></worldbody></mujoco>"""
    (tmp_path / "scene.xml").write_text(xml)
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "scene.xml"))
    assert (m.hfield_nrow[0], m.hfield_ncol[0]) == grid.shape
    np.testing.assert_allclose(m.hfield_data, T.hfield_data(grid), atol=1e-6)


def test_spawns_lie_on_their_tile():
    types = jnp.array([0, 3, 7, 5])
    levels = jnp.array([0, 2, 1, 2])
    keys = jax.random.split(jax.random.PRNGKey(0), 500)
    xy = jax.jit(jax.vmap(lambda k: T.spawn_xy(SPEC, k, types, levels, margin_m=0.2)))(keys)
    assert xy.shape == (500, 4, 2)
    centre = np.asarray(T.tile_center(SPEC, np.asarray(types), np.asarray(levels)))
    off = np.asarray(xy) - centre
    assert np.all(np.abs(off) <= 0.5 - 0.2 + 1e-6)
    assert np.abs(off).max() > 0.29  # the whole allowed square is used
    # tile (3, 2) of a 8 x 3 field of 1 m tiles centred on the origin: x -4 + 3.5, y -1.5 + 2.5
    np.testing.assert_allclose(centre[1], [-0.5, 1.0])
    with pytest.raises(ValueError, match="margin_m"):
        T.spawn_xy(SPEC, keys[0], 0, 0, margin_m=0.5)


def test_curriculum_update_by_hand():
    update = jax.jit(T.curriculum_levels, static_argnames=("levels",))
    key = jax.random.PRNGKey(1)
    level = jnp.array([0, 0, 3, 3, 3, 5, 2, 9])
    commanded = jnp.array([4.0, 4.0, 4.0, 4.0, 4.0, 2.0, 0.0, 4.0])
    distance = jnp.array([3.2, 1.0, 3.1, 2.0, 1.99, 1.6, 0.0, 3.9])
    # 3.2 >= 0.8 * 4: up; 1.0 < 2 at level 0: stays 0; 3.1 in [2, 3.2): kept; 2.0 kept (not < 2);
    # 1.99 < 2: down; 1.6 >= 1.6: up; standing (commanded 0): up; top level 9 going up: random
    new = np.asarray(update(level, distance, commanded, key, levels=10))
    np.testing.assert_array_equal(new[:7], [1, 0, 3, 3, 2, 6, 3])
    assert 0 <= new[7] < 10
    # many robots over the top land uniformly on all levels
    top = np.asarray(update(jnp.full(5000, 9), jnp.ones(5000), jnp.ones(5000), key, levels=10))
    counts = np.bincount(top, minlength=10)
    assert counts.min() > 400 and counts.max() < 600
    with pytest.raises(ValueError, match="thresholds"):
        T.curriculum_levels(level, distance, commanded, key, 10, up=0.4, down=0.5)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"types": ("flat", "lava")}, "terrain types"),
        ({"types": ("flat", "flat")}, "terrain types"),
        ({"levels": 0}, "levels"),
        ({"cell_m": 0.03}, "whole number"),
        ({"wave_length_m": 0.3}, "divide"),
        ({"max_slope_deg": 75.0}, "max_slope_deg"),
        ({"max_step_m": math.nan}, "max_step_m"),
        ({"tread_m": 0.0}, "tread_m"),
    ],
)
def test_bad_spec_names_the_field(kwargs, words):
    with pytest.raises(ValueError, match=words):
        T.TerrainSpec(**kwargs)


def test_type_weights_parse_and_draw():
    """env.tiles.type_weights: the shares worked by hand, the empty string for the uniform draw, bad
    text refused naming the key; draw_type's frequencies over 20000 keys within 4 standard errors
    of the shares, and a type of weight 0 never drawn."""
    types = T.TILE_TYPES
    assert T.type_weights("", types) is None and T.type_weights("  ", types) is None
    shares = T.type_weights("slope_up:3, stairs_up:3,flat:0", types)
    want = np.array([0, 1, 3, 1, 3, 1, 1, 1]) / 11  # flat 0, the two uphill types 3, the rest 1
    np.testing.assert_allclose(shares, want)
    for bad in ("lava:2", "slope_up", "slope_up:x", "slope_up:-1", "slope_up:inf", "flat:1,flat:2"):
        with pytest.raises(ValueError, match=r"env\.tiles\.type_weights"):
            T.type_weights(bad, types)
    with pytest.raises(ValueError, match="at least one type"):
        T.type_weights(",".join(f"{t}:0" for t in types), types)
    n = 20000
    drawn = np.asarray(
        jax.jit(jax.vmap(lambda k: T.draw_type(k, shares)))(jax.random.split(jax.random.PRNGKey(0), n))
    )
    freq = np.bincount(drawn, minlength=len(types)) / n
    assert freq[0] == 0.0
    np.testing.assert_array_less(np.abs(freq - want), 4 * np.sqrt(want * (1 - want) / n) + 1e-12)
