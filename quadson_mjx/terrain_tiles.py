"""Tiled training ground: one MuJoCo height field of square tiles, columns by type, rows by difficulty.

The layout of legged_gym's and Isaac Lab's terrain generators: a robot's tile column is its terrain
type and its row its level, which a curriculum moves up and down (`curriculum_levels`). The edges of
flat, slope, stair and wave tiles are at height 0, so tiles meet without a cliff (a stone or box
may straddle an edge); the robot may start anywhere on a tile (`spawn_xy`), with no flat patch
unless the tile is flat.

Tile types (d = (level + 1) / levels, the difficulty in (0, 1]):

* `flat`: height 0.
* `stones`: loose half-ellipsoid stones of 3-8 cm diameter, up to `max_stone_m * d` high.
* `slope_up`, `slope_down`: a pyramid of slope `max_slope_deg * d`; `up`: the tile's centre is its
  lowest point, so a robot walking out from the centre climbs; `down`: the centre is its highest.
* `stairs_up`, `stairs_down`: the same pyramids in steps of rise `max_step_m * d` and tread
  `tread_m` (square rings); the centre square is the bottom (`up`) or top (`down`) landing.
* `waves`: sin(2 pi x / L) sin(2 pi y / L) of amplitude `max_wave_m * d`, L dividing the tile.
* `obstacles`: scattered boxes of 5-20 cm sides, `max_obstacle_m * d` high.

Heights are sampled on the height field's grid (`cell_m`); MuJoCo joins the samples into triangles
(terrain.py), so a step's riser is one cell wide (2 cm by default): the nearest to vertical a height
field can be. Everything here is numpy, built once; the queries in JAX are terrain.ground_height and
the functions at the end of this module.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from quadson_mjx import terrain

TILE_TYPES = (
    "flat",
    "stones",
    "slope_up",
    "slope_down",
    "stairs_up",
    "stairs_down",
    "waves",
    "obstacles",
)


@dataclasses.dataclass(frozen=True)
class TerrainSpec:
    """The tiled ground. Lengths in m, angles in degrees. Defaults: 2 m tiles for a 0.3 m robot,
    slopes to 20 degrees and steps to 4 cm (the issue's ranges), treads of 0.15 m (half a body)."""

    types: tuple[str, ...] = TILE_TYPES
    levels: int = 10
    tile_m: float = 2.0
    cell_m: float = 0.02
    max_slope_deg: float = 20.0
    max_step_m: float = 0.04
    tread_m: float = 0.15
    max_wave_m: float = 0.03
    wave_length_m: float = 0.5
    max_stone_m: float = 0.03
    max_obstacle_m: float = 0.03
    seed: int = 0
    border_m: float = 0.0  # flat ground around the tiles, so a robot on an outer tile can walk off it

    def __post_init__(self):
        unknown = [t for t in self.types if t not in TILE_TYPES]
        if unknown or not self.types or len(set(self.types)) != len(self.types):
            raise ValueError(f"terrain types {list(self.types)}: each once, from {list(TILE_TYPES)}")
        if not (isinstance(self.levels, int) and self.levels >= 1):
            raise ValueError(f"terrain levels {self.levels!r}: an integer >= 1")
        for name in ("tile_m", "cell_m", "tread_m", "wave_length_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"terrain {name} {getattr(self, name)!r}: a finite length > 0")
        for name in ("max_step_m", "max_wave_m", "max_stone_m", "max_obstacle_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"terrain {name} {getattr(self, name)!r}: a finite length >= 0")
        if not 0 <= self.max_slope_deg < 60:
            raise ValueError(f"terrain max_slope_deg {self.max_slope_deg!r}: in [0, 60)")
        cells = self.tile_m / self.cell_m
        if abs(cells - round(cells)) > 1e-6 or round(cells) < 4:
            raise ValueError(
                f"terrain tile_m {self.tile_m} must be a whole number (>= 4) of cell_m {self.cell_m}"
            )
        border = self.border_m / self.cell_m
        if not (math.isfinite(self.border_m) and self.border_m >= 0 and abs(border - round(border)) < 1e-6):
            raise ValueError(
                f"terrain border_m {self.border_m!r}: a whole number (>= 0) of cell_m {self.cell_m}"
            )
        waves = self.tile_m / self.wave_length_m
        if abs(waves - round(waves)) > 1e-6:
            raise ValueError(
                f"terrain wave_length_m {self.wave_length_m} must divide tile_m {self.tile_m} (edges at 0)"
            )

    @property
    def cells_per_tile(self) -> int:
        return int(round(self.tile_m / self.cell_m))

    @property
    def tiles_half_size(self) -> tuple[float, float]:
        """The tiles' x (types) and y (levels) half extents [m], centred on the world origin."""
        return len(self.types) * self.tile_m / 2, self.levels * self.tile_m / 2

    @property
    def half_size(self) -> tuple[float, float]:
        """The field's x and y half extents [m]: the tiles and the flat border around them."""
        hx, hy = self.tiles_half_size
        return hx + self.border_m, hy + self.border_m

    def difficulty(self, level: int) -> float:
        return (level + 1) / self.levels


def tile_center(spec: TerrainSpec, type_index, level):
    """World x, y [m] of the centre of tile (type_index, level); numpy or JAX, broadcasting -> (..., 2)."""
    hx, hy = spec.tiles_half_size
    x = -hx + (type_index + 0.5) * spec.tile_m
    y = -hy + (level + 0.5) * spec.tile_m
    xp = jnp if isinstance(x, jax.Array) or isinstance(y, jax.Array) else np
    return xp.stack(xp.broadcast_arrays(xp.asarray(x, float), xp.asarray(y, float)), axis=-1)


def _pyramid_r(x, y, half):
    """Chebyshev distance from the tile's centre, clipped to the tile: 0 at the centre, half at the edge."""
    return np.minimum(np.maximum(np.abs(x), np.abs(y)), half)


def _tile_heights(spec: TerrainSpec, kind: str, level: int, x: np.ndarray, y: np.ndarray, rng) -> np.ndarray:
    """Heights [m] of one tile at local coordinates x, y (its centre at 0, 0)."""
    d = spec.difficulty(level)
    half = spec.tile_m / 2
    if kind == "flat":
        return np.zeros_like(x)
    if kind in ("slope_up", "slope_down"):
        rise = math.tan(math.radians(spec.max_slope_deg * d)) * (half - _pyramid_r(x, y, half))
        return -rise if kind == "slope_up" else rise
    if kind in ("stairs_up", "stairs_down"):
        # steps counted inwards from the edge: the outer ring (one tread wide) is at 0
        steps = np.floor((half - _pyramid_r(x, y, half)) / spec.tread_m + 1e-9)
        rise = spec.max_step_m * d * steps
        return -rise if kind == "stairs_up" else rise
    if kind == "waves":
        k = 2 * math.pi / spec.wave_length_m
        return spec.max_wave_m * d * np.sin(k * (x + half)) * np.sin(k * (y + half))
    h = np.zeros_like(x)
    area = spec.tile_m**2
    if kind == "stones":
        n = int(0.6 * area / 0.06**2)  # 0.6 stones per 6 x 6 cm, as the stone field
        cx, cy = rng.uniform(-half, half, n), rng.uniform(-half, half, n)
        rad, top = rng.uniform(0.015, 0.04, n), spec.max_stone_m * d * rng.uniform(0.2, 1.0, n)
        for i in range(n):
            near = (np.abs(x - cx[i]) <= rad[i]) & (np.abs(y - cy[i]) <= rad[i])
            d2 = ((x[near] - cx[i]) ** 2 + (y[near] - cy[i]) ** 2) / rad[i] ** 2
            h[near] = np.maximum(h[near], top[i] * np.sqrt(np.clip(1.0 - d2, 0.0, 1.0)))
        return h
    if kind == "obstacles":
        n = int(area / 0.3**2)  # one box per 30 x 30 cm
        cx, cy = rng.uniform(-half, half, n), rng.uniform(-half, half, n)
        sx, sy = rng.uniform(0.025, 0.1, n), rng.uniform(0.025, 0.1, n)  # half sides
        for i in range(n):
            inside = (np.abs(x - cx[i]) <= sx[i]) & (np.abs(y - cy[i]) <= sy[i])
            h[inside] = spec.max_obstacle_m * d
        return h
    raise AssertionError(kind)


def tile_grid(spec: TerrainSpec) -> np.ndarray:
    """(nrow, ncol) float64 heights [m] of the whole field on its height-field grid: rows along y
    (levels), columns along x (types), spaced cell_m, the field centred on the world origin, then
    border_m of flat ground (height 0) on every side. A
    sample on the border of two tiles belongs to the tile after it (x or y larger); the field's last
    row and column belong to the last tile. Reproducible: the same spec gives the same array."""
    n = spec.cells_per_tile
    ncol, nrow = len(spec.types) * n + 1, spec.levels * n + 1
    out = np.zeros((nrow, ncol))
    local = np.arange(n + 1) * spec.cell_m - spec.tile_m / 2  # a tile's samples, both borders
    x, y = np.meshgrid(local, local)  # (n + 1, n + 1): rows y, columns x
    for t, kind in enumerate(spec.types):
        for level in range(spec.levels):
            rng = np.random.default_rng([spec.seed, t, level])
            h = _tile_heights(spec, kind, level, x, y, rng)
            # the tile owns its first n samples in each direction, the last tile its closing border too
            r1 = n + 1 if level == spec.levels - 1 else n
            c1 = n + 1 if t == len(spec.types) - 1 else n
            out[level * n : level * n + r1, t * n : t * n + c1] = h[:r1, :c1]
    return np.pad(out, int(round(spec.border_m / spec.cell_m)))  # the flat border, at 0


def hfield_size(heights: np.ndarray, spec: TerrainSpec, base_m: float = 0.1) -> tuple[np.ndarray, float]:
    """-> (MuJoCo hfield size (x half, y half, relief, base depth) [m], z of the height field geom [m]):
    MuJoCo scales its normalised data [0, 1] by the relief and raises it from the geom's z, so the
    geom sits at the lowest height and the relief spans to the highest (a flat field gets 1 mm)."""
    lo, hi = float(heights.min()), float(heights.max())
    relief = max(hi - lo, 1e-3)
    hx, hy = spec.half_size
    return np.array([hx, hy, relief, base_m]), lo


def hfield_data(heights: np.ndarray) -> np.ndarray:
    """Heights -> MuJoCo's normalised hfield_data, float32 in [0, 1], row-major (rows along y)."""
    lo, hi = float(heights.min()), float(heights.max())
    return ((heights - lo) / max(hi - lo, 1e-3)).astype(np.float32).ravel()


def write_hfield_bin(path, heights: np.ndarray) -> None:
    """MuJoCo's custom height-field file: int32 nrow, int32 ncol, then nrow * ncol float32 heights,
    row-major (MuJoCo normalises them to [0, 1] when it loads the file)."""
    nrow, ncol = heights.shape
    with open(path, "wb") as f:
        f.write(np.array([nrow, ncol], np.int32).tobytes())
        f.write(heights.astype(np.float32).tobytes())


# The env config's `tiles` keys (env_config: terrain="tiles"; no other terrain reads them).
# types: comma-separated tile types, one column each (TILE_TYPES); levels: rows of rising
# difficulty; border_m: flat ground around them (a robot on an outer tile can walk off it before
# the field's edge ends its episode, termination.off_field_margin_m). A robot keeps its column and
# starts at a level drawn in [min_init_level, max_init_level] (legged_gym starts at 5 of 10 rows; 0-4
# here: the rows before the 15-degree slopes and 2.4 cm steps; a fine-tune of a trained policy
# starts its robots where the source's ended, e.g. 6-9), with a random heading, anywhere on its tile
# at least spawn_margin_m inside the edges. With curriculum, at every episode end its level goes up
# one when it covered curriculum_up of the distance its commands asked for and did not fall, down
# one when it fell or covered less than curriculum_down (curriculum_levels).
TILES = {
    "types": ",".join(TILE_TYPES),
    "levels": 10,
    "tile_m": 2.0,
    "border_m": 1.0,
    # the height field's grid: a step's riser is one cell wide, and MJX tests each foot sphere
    # against every prism under its bounding box (18 on 2 cm cells, 8 on 4 cm)
    "cell_m": 0.02,
    "seed": 0,
    "min_init_level": 0,
    "max_init_level": 4,
    "spawn_margin_m": 0.25,
    "curriculum": True,
    "curriculum_up": 0.8,
    "curriculum_down": 0.5,
    # how often each type's column is drawn at a robot's first reset, "type:weight,..." (types not
    # named weigh 1; "" draws every type alike): "slope_up:3,stairs_up:3" puts 3 / 12 of the robots
    # on each of those two and 1 / 12 on each other type
    "type_weights": "",
}


def relaid(tiles, levels: int) -> dict:
    """The `tiles` keys that change when a field is laid out in `levels` rows of difficulty (an
    evaluation's, levels >= 1): `levels`, and the curriculum's start levels (training's only)
    brought within them."""
    top = levels - 1
    starts = {k: min(tiles[k], top) for k in ("min_init_level", "max_init_level") if k in tiles}
    return {"levels": levels, **starts}


def tile_spec(cfg) -> TerrainSpec:
    """The TerrainSpec of an env config's `tiles` keys (terrain="tiles"); ValueError
    naming the key for a value the generator refuses."""
    t = cfg.tiles
    types = tuple(x.strip() for x in t.types.split(","))
    try:
        spec = TerrainSpec(
            types=types,
            levels=t.levels,
            tile_m=t.tile_m,
            cell_m=t.get("cell_m", TILES["cell_m"]),  # a config saved before the key: its grid
            seed=t.seed,
            border_m=t.border_m,
        )
    except ValueError as e:
        raise ValueError(f"env.tiles: {e}") from None
    if t.max_init_level >= t.levels:
        raise ValueError(
            f"env.tiles.max_init_level must be < env.tiles.levels ({t.levels}), got {t.max_init_level}"
        )
    if t.get("min_init_level", 0) > t.max_init_level:
        raise ValueError(
            f"env.tiles.min_init_level ({t.min_init_level}) must be <= env.tiles.max_init_level ({t.max_init_level})"
        )
    if t.spawn_margin_m >= t.tile_m / 2:
        raise ValueError(
            f"env.tiles.spawn_margin_m must be < tile_m / 2 ({t.tile_m / 2} m), got {t.spawn_margin_m}"
        )
    if t.curriculum_down > t.curriculum_up:
        raise ValueError(
            f"env.tiles.curriculum_down ({t.curriculum_down}) must be <= env.tiles.curriculum_up ({t.curriculum_up})"
        )
    type_weights(t.get("type_weights", TILES["type_weights"]), spec.types)
    return spec


def type_weights(text: str, types) -> np.ndarray | None:
    """env.tiles.type_weights ("type:weight,...", each type once, weights finite and >= 0, types
    not named weigh 1) -> the normalised share of each of `types`, or None for "" (every type
    alike). ValueError naming the key for anything else."""
    if not text.strip():
        return None
    weights = dict.fromkeys(types, 1.0)
    seen = set()
    for item in text.split(","):
        name, sep, value = item.partition(":")
        name = name.strip()
        try:
            w = float(value) if sep else math.nan
        except ValueError:
            w = math.nan
        if name not in weights or name in seen or not (math.isfinite(w) and w >= 0):
            raise ValueError(
                f"env.tiles.type_weights {text!r}: 'type:weight,...' with each type once from "
                f"{list(types)} and weights >= 0, got {item.strip()!r}"
            )
        seen.add(name)
        weights[name] = w
    total = sum(weights.values())
    if total <= 0:
        raise ValueError(f"env.tiles.type_weights {text!r}: at least one type needs a weight > 0")
    return np.array([weights[t] / total for t in types])


def draw_type(key, shares) -> jax.Array:
    """A tile column index drawn with the probabilities `shares` (type_weights' array) -> () int32.
    jit/vmap."""
    shares = jnp.asarray(shares)
    return jax.random.choice(key, shares.shape[0], p=shares).astype(jnp.int32)


# --- in JAX, per robot: where it starts and how its level moves ---


def spawn_xy(spec: TerrainSpec, key, type_index, level, margin_m: float = 0.25):
    """A uniform start position on tile (type_index, level), at least margin_m inside its edges ->
    (..., 2) world x, y [m] (the caller puts the robot on terrain.ground_height there). jit/vmap."""
    if not 0 <= margin_m < spec.tile_m / 2:
        raise ValueError(f"spawn margin_m {margin_m!r}: in [0, tile_m / 2)")
    shape = jnp.broadcast_shapes(jnp.shape(type_index), jnp.shape(level))
    offset = jax.random.uniform(key, (*shape, 2), minval=-1.0, maxval=1.0) * (spec.tile_m / 2 - margin_m)
    return tile_center(spec, jnp.asarray(type_index), jnp.asarray(level)) + offset


def curriculum_levels(
    level, distance, commanded, key, levels: int, up: float = 0.8, down: float = 0.5, fell=None
):
    """legged_gym's game-inspired curriculum, per robot at the end of its episode. level (...,) int;
    distance: how far it went [m]; commanded: how far its command asked [m]; fell (...,) bool or
    None -> (...,) new level.
    Up one when distance >= up * commanded; down one when distance < down * commanded or it fell;
    kept otherwise. A robot that goes up from the top level is sent to a uniformly random level (so
    the top rows keep being trained without the rest being forgotten); nothing goes below 0. A
    command asking for no distance (standing) counts as covered (commanded <= 0: up) unless it fell."""
    if not 0 <= down <= up:
        raise ValueError(f"curriculum thresholds down {down!r} <= up {up!r}, both >= 0")
    level = jnp.asarray(level)
    fell = jnp.zeros(level.shape, bool) if fell is None else jnp.asarray(fell, bool)
    covered = ((distance >= up * commanded) | (commanded <= 0)) & ~fell
    short = ((distance < down * commanded) & ~covered) | fell
    new = level + covered.astype(level.dtype) - short.astype(level.dtype)
    random_level = jax.random.randint(key, level.shape, 0, levels, dtype=level.dtype)
    return jnp.where(new >= levels, random_level, jnp.maximum(new, 0))


def spawn_lift(field, xy, z, radius, disc: int = 13):
    """How far to raise a trial pose so that its lowest sphere or point just clears the ground [m]
    (negative: lower it; a pose above a pit comes down onto its floor).

    xy (..., P, 2), z (..., P): world positions of P sphere centres of the robot at the trial pose
    (a foot) or points (radius 0: a corner of the base box); radius (P,) [m]. The ground is sampled
    on a disc x disc grid over each sphere's footprint, against the sphere's lower surface there
    (z - sqrt(r^2 - rho^2) at rho from its centre): a stone narrower than the sphere or a step's
    edge beside its lowest point is met where it touches. With the default 13 x 13 grid the samples
    are r / 6 apart; the field's surface between them (the piecewise-linear terrain.ground_height,
    MuJoCo's surface) can sit above them by at most its slope times that spacing: 5 mm on a 4 cm
    riser of one 2 cm cell under Quadson's 1.5 cm foot, which the environment's SPAWN_CLEARANCE_M covers
    (tested against MuJoCo's collision on every tile type). jit/vmap."""
    radius = jnp.asarray(radius)
    u = jnp.linspace(-1.0, 1.0, disc) if disc > 1 else jnp.zeros(1)
    ux, uy = jnp.meshgrid(u, u)
    ux, uy = ux.ravel(), uy.ravel()
    inside = ux**2 + uy**2 <= 1.0 + 1e-9  # (S,) on the unit disc
    offsets = jnp.stack([ux, uy], axis=-1)  # (S, 2)
    samples = xy[..., None, :] + radius[:, None, None] * offsets  # (..., P, S, 2)
    drop = radius[:, None] * jnp.sqrt(jnp.clip(1.0 - ux**2 - uy**2, 0.0, 1.0))  # (P, S)
    clearance = z[..., None] - drop - terrain.ground_height(field, samples)  # (..., P, S)
    clearance = jnp.where(inside, clearance, jnp.inf)
    return -jnp.min(clearance, axis=(-2, -1))


def curriculum_summary(spec: TerrainSpec, tile_type, level, result) -> dict[str, float]:
    """The curriculum's state over a batch of robots, per tile type, for the training log.

    tile_type, level (N,) int; result (N,): each robot's last finished episode (-1 none yet, 0
    failed, 1 success) -> {"<type>/robots": how many train on it, "<type>/level_mean": their mean
    level, "<type>/level_max_share": the share at the top level, "<type>/success": the share of
    their last episodes that succeeded, "<type>/episodes": how many of them have finished one}; a
    share or mean of nobody is left out (no NaN in the log)."""
    tile_type, level, result = (np.asarray(a).reshape(-1) for a in (tile_type, level, result))
    out: dict[str, float] = {}
    for t, kind in enumerate(spec.types):
        mine = tile_type == t
        done = mine & (result >= 0)
        out[f"{kind}/robots"] = float(mine.sum())
        out[f"{kind}/episodes"] = float(done.sum())
        if mine.any():
            out[f"{kind}/level_mean"] = float(level[mine].mean())
            out[f"{kind}/level_max_share"] = float((level[mine] == spec.levels - 1).mean())
        if done.any():
            out[f"{kind}/success"] = float((result[done] > 0.5).mean())
    return out


def curriculum_line(spec: TerrainSpec, summary: dict[str, float]) -> str:
    """One console line of curriculum_summary: each type's mean level and last-episode success."""
    parts = []
    for kind in spec.types:
        level = summary.get(f"{kind}/level_mean")
        success = summary.get(f"{kind}/success")
        parts.append(
            f"{kind} "
            + ("-" if level is None else f"L{level:.1f}")
            + ("" if success is None else f" {100 * success:.0f}%")
        )
    return "curriculum (mean level, success): " + ", ".join(parts)
