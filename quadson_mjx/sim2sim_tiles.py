"""Sim-to-sim on the tiled ground: the terrains "tiles:TYPE:LEVEL" of quadson_mjx.sim2sim, one tile
of a tiles policy's own training field (its env config's `tiles` keys), where a run starts, and the
trial the MJX tiles evaluation (quadson_mjx.tiles_eval) runs. JAX (terrain_tiles) is imported only
when a tile is asked for: the flat and stone runs stay numpy and MuJoCo.

    spec, kind, level = tile_terrain("tiles:stairs_up:6", env_config)
"""

from __future__ import annotations

from quadson_mjx.sim2sim_model import TERRAINS

TILE = "tile"  # the command set of a tile trial: TILE_COMMAND held
TILE_COMMAND = (0.3, 0.0, 0.0)  # quadson_mjx.tiles_eval's default trial command
TILE_PREFIX = "tiles:"
TILE_START_M = 0.02  # a tile run starts this close to its tile's centre (as quadson_mjx.tiles_eval)
SUCCESS_SHARE = 0.8  # of the commanded distance (quadson_mjx.wrappers.SUCCESS_SHARE; a test holds them equal)


def tile_field(env_config: dict):
    """The terrain_tiles.TerrainSpec of a policy's env config; ValueError for a policy not trained
    on the tiled ground."""
    if env_config.get("terrain") != "tiles" or "tiles" not in env_config:
        raise ValueError("the policy was not trained on the tiled ground (no env.tiles)")
    import ml_collections

    from quadson_mjx import terrain_tiles  # JAX: imported for the tiles only

    return terrain_tiles.tile_spec(ml_collections.ConfigDict({"tiles": env_config["tiles"]}))


def tile_terrain(terrain: str, env_config: dict):
    """A terrain "tiles:TYPE:LEVEL" -> (tile_field(env_config), type, level); None for "flat" and
    "stones"; ValueError for any other terrain, a policy not trained on the tiles, or a type or
    level its field does not have."""
    if terrain in TERRAINS:
        return None
    kind, sep, level = terrain.removeprefix(TILE_PREFIX).partition(":")
    if not terrain.startswith(TILE_PREFIX) or not sep:
        raise ValueError(f"terrain {terrain!r}: flat, stones or {TILE_PREFIX}TYPE:LEVEL")
    try:
        spec = tile_field(env_config)
    except ValueError as e:
        raise ValueError(f"terrain {terrain!r}: {e}") from None
    if kind not in spec.types or not level.isdigit() or not 0 <= int(level) < spec.levels:
        raise ValueError(
            f"terrain {terrain!r}: the policy's field has types {', '.join(spec.types)} and levels "
            f"0..{spec.levels - 1}"
        )
    return spec, kind, int(level)


def start_xy(terrain: str, env_config: dict, rng) -> tuple[float, float]:
    """Where a run starts: the origin, or on a tile within TILE_START_M of its centre (drawn from rng)."""
    tile = tile_terrain(terrain, env_config)
    if tile is None:
        return (0.0, 0.0)
    from quadson_mjx.terrain_tiles import tile_center

    spec, kind, level = tile
    x, y = tile_center(spec, spec.types.index(kind), level) + rng.uniform(-TILE_START_M, TILE_START_M, 2)
    return (float(x), float(y))


def tile_seed_shift(terrain: str) -> int:
    """A tile's offset of the plant's random streams (sim2sim.plant_seed_of): one per type and level,
    the same on every machine, none equal to flat's (0) or the stones' (17)."""
    from quadson_mjx.terrain_tiles import TILE_TYPES

    kind, _, level = terrain.removeprefix(TILE_PREFIX).partition(":")
    return 100 + len(TILE_TYPES) * int(level) + TILE_TYPES.index(kind)
