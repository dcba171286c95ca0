"""Sim-to-sim on the tiled ground: the terrains "tiles:TYPE:LEVEL" of quadson_mjx.sim2sim, one tile
of a tiles policy's own training field (its env config's `tiles` keys), where a run starts, and the
trial the MJX tiles evaluation (quadson_mjx.tiles_eval) runs. JAX (terrain_tiles) is imported only
when a tile is asked for: the flat and stone runs stay numpy and MuJoCo.

    spec, kind, level = tile_terrain("tiles:stairs_up:6", env_config)
    spec, kind, level = tile_terrain("tiles:stairs_up:5/8", env_config)  # level 5 of 8: 15 deg, 3 cm
"""

from __future__ import annotations

from quadson_mjx.sim2sim_model import TERRAINS

TILE = "tile"  # the command set of a tile trial: TILE_COMMAND held
TILE_COMMAND = (0.3, 0.0, 0.0)  # quadson_mjx.tiles_eval's default trial command
TILE_PREFIX = "tiles:"
TILE_START_M = 0.02  # a tile run starts this close to its tile's centre (as quadson_mjx.tiles_eval)
SUCCESS_SHARE = 0.8  # of the commanded distance (quadson_mjx.wrappers.SUCCESS_SHARE; a test holds them equal)


def tile_field(env_config: dict, levels: int | None = None):
    """The terrain_tiles.TerrainSpec of a policy's env config, with `levels` rows of difficulty
    instead of its own where given (level L of N is (L + 1) / N of each type's largest size; the
    curriculum's start levels, training's only, brought within them); ValueError for a policy not
    trained on the tiled ground."""
    if env_config.get("terrain") != "tiles" or "tiles" not in env_config:
        raise ValueError("the policy was not trained on the tiled ground (no env.tiles)")
    import ml_collections

    from quadson_mjx import terrain_tiles  # JAX: imported for the tiles only

    tiles = dict(env_config["tiles"])
    if levels is not None:  # tile_spec refuses fewer than one level, naming the key
        tiles.update(terrain_tiles.relaid(tiles, levels))
    return terrain_tiles.tile_spec(ml_collections.ConfigDict({"tiles": tiles}))


def _level_of(text: str) -> tuple[int, int | None] | None:
    """A terrain name's level, "L" or "L/N" (level L of a field of N levels) -> (L, N or None);
    None if it is neither."""
    level, sep, levels = text.partition("/")
    if not level.isdigit() or (sep and not levels.isdigit()):
        return None
    return int(level), (int(levels) if sep else None)


def tile_terrain(terrain: str, env_config: dict):
    """A terrain "tiles:TYPE:LEVEL", or "tiles:TYPE:LEVEL/N" on the policy's field laid out in N
    levels (tile_field) -> (that field's TerrainSpec, type, level); None for "flat" and "stones";
    ValueError for any other terrain, a policy not trained on the tiles, or a type or level the
    field does not have."""
    if terrain in TERRAINS:
        return None
    kind, sep, text = terrain.removeprefix(TILE_PREFIX).partition(":")
    parsed = _level_of(text)
    if not terrain.startswith(TILE_PREFIX) or not sep or parsed is None:
        raise ValueError(f"terrain {terrain!r}: flat, stones or {TILE_PREFIX}TYPE:LEVEL[/LEVELS]")
    level, levels = parsed
    try:
        spec = tile_field(env_config, levels)
    except ValueError as e:
        raise ValueError(f"terrain {terrain!r}: {e}") from None
    if kind not in spec.types or not 0 <= level < spec.levels:
        raise ValueError(
            f"terrain {terrain!r}: the field has types {', '.join(spec.types)} and levels "
            f"0..{spec.levels - 1}"
        )
    return spec, kind, level


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
    """A tile's offset of the plant's random streams (sim2sim.plant_seed_of): one per type, level
    and field (its own levels, or N of "LEVEL/N"), the same on every machine, none equal to flat's
    (0) or the stones' (17)."""
    from quadson_mjx.terrain_tiles import TILE_TYPES

    kind, _, text = terrain.removeprefix(TILE_PREFIX).partition(":")
    level, levels = _level_of(text)
    field = 0 if levels is None else 10_000 * levels
    return 100 + field + len(TILE_TYPES) * level + TILE_TYPES.index(kind)
