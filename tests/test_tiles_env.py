"""The environment on the tiled ground (env.terrain="tiles"): the height field MuJoCo steps is the
generator's, spawns start on their tile with nothing inside the ground (MuJoCo's own collision of
the feet and the base box against the field, on every tile type), the auto-reset moves a robot's
level as the curriculum rule says on hand-set episodes and respawns it on its new tile, and the
training log's per-type summary by hand."""

import copy
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from state_types import assert_evaluation_compiles_once

from quadson_mjx import terrain, terrain_tiles
from quadson_mjx.env import SPAWN_CLEARANCE_M, LocomotionEnv
from quadson_mjx.env_config import check_env_config
from quadson_mjx.env_model import BASE_GEOM
from quadson_mjx.randomize import randomization_fn
from quadson_mjx.tasks import config_from_flags
from quadson_mjx.wrappers import SUCCESS_SHARE, wrap_for_training

N_ENVS = 4
EPISODE = 6  # control steps


def _config(**tiles):
    """The robust preset on a small tiled ground (1 m tiles, 3 levels, every type)."""
    cfg = config_from_flags(env_preset="robust", terrain="tiles").unlock()
    cfg.tiles.update(
        {"tile_m": 1.0, "levels": 3, "max_init_level": 2, "border_m": 0.5, "spawn_margin_m": 0.15}
    )
    cfg.tiles.update(tiles)
    cfg.lock()
    return cfg


@pytest.fixture(scope="module")
def env():
    return LocomotionEnv(_config())


@pytest.fixture(scope="module")
def spawn(env):
    return jax.jit(jax.vmap(env.reset_on_tile))


@pytest.fixture(scope="module")
def wrapped(env):
    rand = functools.partial(
        randomization_fn(env.config.randomization, env.base_body),
        rng=jax.random.split(jax.random.PRNGKey(1), N_ENVS),
    )
    w = wrap_for_training(env, EPISODE, randomization_fn=rand)
    return w, jax.jit(w.reset_on_tiles), jax.jit(w.step)


def test_the_field_is_the_generators(env):
    spec = env.tiles
    assert spec.types == terrain_tiles.TILE_TYPES and spec.levels == 3 and spec.tile_m == 1.0
    field = terrain.heightfield(env.mj_model)
    want = terrain_tiles.tile_grid(spec)
    assert field.heights.shape == want.shape == (3 * 50 + 1 + 50, 8 * 50 + 1 + 50)  # 0.5 m border
    z = np.asarray(field.heights) + float(field.origin[2])
    np.testing.assert_allclose(z, want, atol=2e-6)  # float32 samples of a 0.36 m relief
    np.testing.assert_allclose(field.half_size, spec.half_size)


def test_config_errors_name_the_key():
    for tiles, words in (
        ({"types": "flat,lava"}, "env.tiles"),
        ({"max_init_level": 3}, "env.tiles.max_init_level"),
        ({"min_init_level": 2, "max_init_level": 1}, "env.tiles.min_init_level"),
        ({"spawn_margin_m": 0.5}, "env.tiles.spawn_margin_m"),
        ({"curriculum_down": 0.9}, "env.tiles.curriculum_down"),
        ({"border_m": 0.015}, "border_m"),
        ({"cell_m": 0.03}, "cell_m"),  # 1 m is no whole number of 3 cm cells
        ({"type_weights": "slope_up:2,lava:1"}, "env.tiles.type_weights"),
    ):
        with pytest.raises(ValueError, match=words.replace(".", r"\.")):
            check_env_config(_config(**tiles))


def _contact_model(env) -> mujoco.MjModel:
    """The env's model with the base box colliding again and a 5 cm margin on the feet and the box,
    so MuJoCo reports their distance to the field before they touch it."""
    m = copy.copy(env.mj_model)
    base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, BASE_GEOM)
    m.geom_contype[base] = m.geom_conaffinity[base] = 1
    for name in (*env.robot.foot_geoms(), BASE_GEOM):
        m.geom_margin[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)] = 0.05
    return m


def test_spawns_on_their_tile_and_never_inside_the_ground(env, spawn):
    """On every type and level: the base over the tile at least spawn_margin_m inside it, a random
    heading, and MuJoCo's collision of the feet and the base box with the field finds no
    penetration while the lowest of them is within a few mm of the ground (a drop of millimetres)."""
    spec = env.tiles
    types, levels = np.meshgrid(np.arange(len(spec.types)), np.arange(spec.levels), indexing="ij")
    types, levels = np.repeat(types.ravel(), 4), np.repeat(levels.ravel(), 4)  # 4 spawns per tile
    states = spawn(jax.random.split(jax.random.PRNGKey(3), types.size), types, levels)
    qpos = np.asarray(states.pipeline_state.qpos)
    np.testing.assert_array_equal(states.info["tile_type"], types)
    np.testing.assert_array_equal(states.info["tile_level"], levels)
    centre = np.asarray(terrain_tiles.tile_center(spec, types, levels))
    assert np.all(np.abs(qpos[:, :2] - centre) <= spec.tile_m / 2 - env.config.tiles.spawn_margin_m + 1e-6)
    yaw = 2 * np.arctan2(qpos[:, 6], qpos[:, 3])
    assert np.ptp(np.mod(yaw, 2 * np.pi)) > 3.0  # headings spread over the circle

    m = _contact_model(env)
    d = mujoco.MjData(m)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, terrain.FLOOR_GEOM)
    closest = []
    for i, q in enumerate(qpos):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        dist = [c.dist for c in d.contact[: d.ncon] if floor in (c.geom1, c.geom2)]
        kind = spec.types[types[i]]
        assert dist, f"{kind} level {levels[i]}: nothing within 5 cm of the ground"
        assert min(dist) >= -1e-6, f"{kind} level {levels[i]}: starts {-min(dist) * 1e3:.2f} mm in the ground"
        closest.append(min(dist))
    # the lift is tight: a foot's sphere within clearance + its radius x tan(20 deg) + a cell's slope
    assert max(closest) < SPAWN_CLEARANCE_M + 0.01
    assert np.median(closest) < SPAWN_CLEARANCE_M + 0.002


def test_first_resets_follow_the_type_weights():
    """env.tiles.type_weights reaches the environment's reset: with every weight 0 but waves' and
    obstacles', each robot starts on one of those two columns, at a level in [0, max_init_level]
    (tiles.min_init_level: [min_init_level, max_init_level])."""
    weights = ",".join(f"{t}:{int(t in ('waves', 'obstacles'))}" for t in terrain_tiles.TILE_TYPES)
    env = LocomotionEnv(_config(type_weights=weights))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(4), 16))
    kinds = {terrain_tiles.TILE_TYPES[i] for i in np.asarray(states.info["tile_type"])}
    assert kinds == {"waves", "obstacles"}
    assert np.all(np.asarray(states.info["tile_level"]) <= env.config.tiles.max_init_level)
    # a fine-tune's start where its source's robots ended: every level of [min, max] and no other
    env = LocomotionEnv(_config(type_weights=weights, min_init_level=1, max_init_level=2))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(4), 16))
    assert set(np.asarray(states.info["tile_level"]).tolist()) == {1, 2}


def test_critic_ground_scan_is_mujocos_ground_around_the_robot(env):
    """env.critic_scan_points: the critic's grid of ground heights on spawns over every tile type at
    the top level, against MuJoCo's ray casts at the grid's points turned by the spawn's heading by
    hand; the actor's observation is unchanged, the critic's 9 values longer."""
    cfg = _config().unlock()
    cfg.critic_scan_points, cfg.critic_scan_spacing_m = 3, 0.1
    cfg.lock()
    scanning = LocomotionEnv(cfg)
    assert scanning.obs_spec == env.obs_spec and scanning.critic_spec.size == env.critic_spec.size + 9
    assert scanning.critic_spec.entries[-1].name == "ground_scan"
    types = np.repeat(np.arange(len(env.tiles.types)), 2)
    levels = np.full(types.size, env.tiles.levels - 1)
    states = jax.jit(jax.vmap(scanning.reset_on_tile))(
        jax.random.split(jax.random.PRNGKey(5), types.size), types, levels
    )
    m, d = scanning.mj_model, mujoco.MjData(scanning.mj_model)
    mujoco.mj_forward(m, d)  # the field's pose, which the rays need
    group = np.zeros(6, np.uint8)
    group[m.geom_group[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, terrain.FLOOR_GEOM)]] = 1
    top, geom = 2.0, np.zeros(1, np.int32)

    def ray(x, y):
        dist = mujoco.mj_ray(m, d, np.array([x, y, top]), np.array([0.0, 0, -1]), group, 1, -1, geom)
        assert dist >= 0, (x, y)  # a miss is -1
        return top - dist

    offsets = [(dx, dy) for dx in (-0.1, 0.0, 0.1) for dy in (-0.1, 0.0, 0.1)]
    spans = []
    for q, critic in zip(
        np.asarray(states.pipeline_state.qpos), np.asarray(states.obs["privileged_state"]), strict=True
    ):
        yaw = 2 * np.arctan2(q[6], q[3])  # a spawn turns about z only
        c, s = np.cos(yaw), np.sin(yaw)
        want = [ray(q[0] + c * dx - s * dy, q[1] + s * dx + c * dy) - ray(q[0], q[1]) for dx, dy in offsets]
        np.testing.assert_allclose(scanning.critic_spec.split(critic)["ground_scan"], want, atol=1e-5)
        spans.append(np.ptp(want))
    assert max(spans) > 0.02  # slopes and stairs show
    cfg.unlock()
    cfg.asymmetric_critic = False
    with pytest.raises(ValueError, match="env.critic_scan_points > 0 needs env.asymmetric_critic=true"):
        check_env_config(cfg)


def test_curriculum_and_respawn_on_hand_set_episodes(env, wrapped):
    """Four robots one step before their episode's end, with the distance covered and asked for set
    by hand: covered (up), short (down), in between (kept), fell (down); each restarts on its
    column at its new level, its episode and buffers fresh, its result recorded."""
    w, reset_on_tiles, step = wrapped
    spec = env.tiles
    types = jnp.array([0, 3, 4, 6])
    state = reset_on_tiles(jax.random.split(jax.random.PRNGKey(0), N_ENVS), types, jnp.array([1, 1, 1, 1]))
    info = dict(state.info)
    info["steps"] = jnp.full(N_ENVS, EPISODE - 1.0)  # the next step ends every episode (time limit)
    info["tile_progress_m"] = jnp.array([2.0, 0.1, 0.7, 2.0])
    info["tile_commanded_m"] = jnp.array([1.0, 1.0, 1.0, 1.0])
    info["command"] = jnp.zeros((N_ENVS, 3))  # nothing added in the last step
    state = state.replace(info=info)
    # robot 3 falls: turned upside down
    qpos = state.pipeline_state.qpos.at[3, 3:7].set(jnp.array([0.0, 1.0, 0.0, 0.0]))
    state = state.replace(pipeline_state=state.pipeline_state.replace(qpos=qpos))
    out = step(state, jnp.zeros((N_ENVS, env.action_size)))
    assert np.all(np.asarray(out.done) == 1.0)
    np.testing.assert_array_equal(out.metrics["fall"], [0, 0, 0, 1])
    np.testing.assert_array_equal(out.info["tile_level"], [2, 0, 1, 0])
    np.testing.assert_array_equal(out.info["tile_type"], types)
    # success: no fall and SUCCESS_SHARE of the commanded distance
    assert SUCCESS_SHARE == 0.8
    np.testing.assert_array_equal(out.info["tile_result"], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(out.info["tile_progress_m"], 0.0)
    np.testing.assert_array_equal(out.info["episode_time"], 0.0)
    centre = np.asarray(terrain_tiles.tile_center(spec, types, out.info["tile_level"]))
    xy = np.asarray(out.pipeline_state.qpos[:, :2])
    assert np.all(np.abs(xy - centre) <= spec.tile_m / 2)  # respawned on the new tile
    assert np.all(np.isfinite(np.asarray(out.obs["state"]))) and np.all(
        np.isfinite(np.asarray(out.obs["privileged_state"]))
    )


def test_a_step_keeps_the_state_types_so_the_evaluation_compiles_once(env, wrapped):
    """Regression: the reset's tile_result was weakly typed and the step's not, so brax's
    evaluation of the tiled ground compiled twice (two ~40 s compilations a run on one H200)."""
    assert_evaluation_compiles_once(wrapped[0], env.action_size, N_ENVS)


def test_curriculum_summary_by_hand():
    spec = terrain_tiles.TerrainSpec(types=("flat", "stairs_up"), levels=4)
    s = terrain_tiles.curriculum_summary(spec, [0, 0, 0, 1], [1, 3, 2, 0], [1, 0, -1, -1])
    assert (
        s["flat/robots"] == 3
        and s["flat/level_mean"] == 2.0
        and s["flat/level_max_share"] == pytest.approx(1 / 3)
    )
    assert s["flat/episodes"] == 2 and s["flat/success"] == 0.5
    assert s["stairs_up/robots"] == 1 and s["stairs_up/episodes"] == 0 and "stairs_up/success" not in s
    line = terrain_tiles.curriculum_line(spec, s)
    assert line == "curriculum (mean level, success): flat L2.0 50%, stairs_up L0.0"


def test_tiles_evaluation_of_the_gait_alone():
    """evaluate_tiles with a zero policy (the gait alone) standing on two tile types x two levels:
    one row per tile with its robots; standing asks for no distance, so every robot that did not
    fall succeeds; the gait stepping in place tracks vx = 0 within 0.12 m/s. Bad requests refused."""
    from quadson_mjx import tiles_eval
    from quadson_mjx.stats import success_interval

    env_cfg = _config()
    act = LocomotionEnv(env_cfg).action_size

    def policy(obs, key):
        return jnp.zeros(obs["state"].shape[:-1] + (act,)), {}

    rows = tiles_eval.evaluate_tiles(
        env_cfg, policy, [0, 2], 2, 1.5, (0.0, 0.0, 0.0), 0, ["flat", "slope_up"]
    )
    assert [(r["type"], r["level"], r["robots"]) for r in rows] == [
        ("flat", 0, 2), ("flat", 2, 2), ("slope_up", 0, 2), ("slope_up", 2, 2)
    ]  # fmt: skip
    assert rows[3]["slope_deg"] == pytest.approx(20.0) and "slope_deg" not in rows[0]
    for r in rows:
        assert r["success"] == 1.0 - r["falls"] / r["robots"]
        assert r["distance_share"] == 1.0
        lo, hi = r["success_95"]  # its 95 % interval, of the same counts (tests/test_stats.py)
        assert lo <= r["success"] <= hi and r["success_95"] == success_interval(
            r["robots"] - r["falls"], r["robots"]
        )
    # 0.092, 0.108 and 0.104 m/s with XLA's CPU code for SSE4.2, AVX2 and AVX-512
    # (XLA_FLAGS=--xla_cpu_max_isa=...): two robots for 1.5 s amplify the rounding's differences
    assert rows[0]["falls"] == 0 and rows[0]["rms_vx"] < 0.12
    with pytest.raises(ValueError, match="lava"):
        tiles_eval.evaluate_tiles(env_cfg, policy, [0], 1, 1.5, types=["lava"])
    with pytest.raises(ValueError, match="levels"):
        tiles_eval.evaluate_tiles(env_cfg, policy, [3], 1, 1.5)
    # --nominal: the same trials on the nominal model without pushes; by default the run's own
    ran = tiles_eval.tiles_env_config(env_cfg)
    assert ran.randomize and ran.pushes  # the robust preset's
    nominal = tiles_eval.tiles_env_config(env_cfg, nominal=True)
    assert not nominal.randomize and not nominal.pushes
    assert nominal.tiles.curriculum is False and nominal.terrain == "tiles"
    spec = terrain_tiles.TerrainSpec()
    assert tiles_eval.difficulty(spec, "slope_down", 6) == {"slope_deg": pytest.approx(14.0)}
    assert tiles_eval.difficulty(spec, "stairs_up", 7) == {"step_m": pytest.approx(0.032)}
    # eight levels (--env.tiles.levels=8): level 5 is the 15 degrees and 3 cm
    eight = terrain_tiles.TerrainSpec(levels=8)
    assert tiles_eval.difficulty(eight, "slope_up", 5) == {"slope_deg": pytest.approx(15.0)}
    assert tiles_eval.difficulty(eight, "stairs_down", 5) == {"step_m": pytest.approx(0.03)}


@pytest.mark.parametrize(
    "argv",
    [
        ["--run", "no/such/run"],
        ["--run", "results/policy_h100_sensors", "--seconds", "nan"],
        ["--run", "results/policy_h100_sensors", "--envs", "0"],
        ["--run", "results/policy_h100_sensors", "--vx", "5"],
        ["--run", "results/policy_h100_sensors", "--json", "/proc/version/x.json"],
        # --env: only the evaluation's conditions, and the env config's own checks
        ["--run", "results/policy_h100_sensors", "--env.obs_history=1"],
        ["--run", "results/policy_h100_sensors", "--env.sensor.imu_tilt=0.01"],
        ["--run", "results/policy_h100_sensors", "--env.sensor.imu_tilt_rad=-1"],
        ["--run", "results/policy_h100_sensors", "--sensor.imu_tilt_rad=0.01"],
        # the tiled ground's levels are a condition, its other keys are the run's
        ["--run", "results/tiles_h100", "--env.tiles.levels=0"],
        ["--run", "results/tiles_h100", "--env.tiles.levels=8", "--levels", "8"],
        ["--run", "results/tiles_h100", "--env.tiles.tile_m=3"],
    ],
)
def test_tiles_eval_cli_bad_inputs_one_line_exit_2(argv, capsys, monkeypatch):
    from pathlib import Path

    from quadson_mjx.cli import tiles_eval as cli

    monkeypatch.chdir(Path(__file__).resolve().parents[1])
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1, err


def test_tiles_eval_cli_env_overrides_reach_the_trials(capsys, monkeypatch, tmp_path):
    """--env.sensor.imu_tilt_rad=0.01 (a calibrated IMU) and --env.tiles.levels=8 (the tiles at
    eighths of their largest size) reach evaluate_tiles's env config, the rest of the run's config
    unchanged, and the JSON keeps the command line."""
    import json
    from pathlib import Path

    from quadson_mjx import tiles_eval
    from quadson_mjx.cli import tiles_eval as cli
    from quadson_mjx.training import load_run_config

    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    seen = {}

    def fake(env_cfg, policy, levels, *args, **kwargs):
        seen["cfg"], seen["levels"] = env_cfg, levels
        return []

    monkeypatch.setattr(tiles_eval, "evaluate_tiles", fake)
    argv = [
        "--run",
        "results/policy_h100_sensors",
        "--env.sensor.imu_tilt_rad=0.01",
        "--json",
        str(tmp_path / "e.json"),
    ]
    assert cli.main(argv) == 0
    run_cfg, _ = load_run_config(root / "results/policy_h100_sensors")
    assert run_cfg.sensor.imu_tilt_rad == pytest.approx(0.035) and seen["cfg"].sensor.imu_tilt_rad == 0.01
    changed = {k for k in seen["cfg"].to_dict() if seen["cfg"][k] != run_cfg[k]}
    assert changed == {"sensor"}
    assert json.loads((tmp_path / "e.json").read_text())["argv"] == argv
    # the tiled ground's levels: only tiles.levels changes, and the trials get the asked level
    argv = ["--run", "results/tiles_h100", "--env.tiles.levels=8", "--levels", "5"]
    assert cli.main(argv) == 0
    run_cfg, _ = load_run_config(root / "results/tiles_h100")
    assert run_cfg.tiles.levels == 10 and seen["cfg"].tiles.levels == 8 and seen["levels"] == [5]
    changed = {k for k in seen["cfg"].to_dict() if seen["cfg"][k] != run_cfg[k]}
    assert changed == {"tiles"}
    assert {k for k in run_cfg.tiles if seen["cfg"].tiles[k] != run_cfg.tiles[k]} == {"levels"}
    # fewer levels than the run's robots started at (0-4): the start levels, training's only, come down
    assert cli.main(["--run", "results/tiles_h100", "--env.tiles.levels=4", "--levels", "2"]) == 0
    assert seen["cfg"].tiles.levels == 4 and seen["levels"] == [2]
    assert (seen["cfg"].tiles.min_init_level, seen["cfg"].tiles.max_init_level) == (0, 3)


def test_foxglove_draws_the_default_tiled_ground_decimated():
    """The default field (1101 x 901 samples) is drawn from every 2nd sample, corners kept: the
    drawn vertices are MuJoCo's samples at their grid positions, and the scene stays small."""
    from quadson_mjx import foxglove_scene
    from quadson_mjx.env_config import env_config
    from quadson_mjx.env_model import training_model
    from quadson_mjx.robots import get_robot

    m = training_model(get_robot("quadson"), env_config(terrain="tiles"))
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, terrain.FLOOR_GEOM)
    xs, ys, z = foxglove_scene.hfield_grid(m, g)
    nrow, ncol = int(m.hfield_nrow[0]), int(m.hfield_ncol[0])
    assert (nrow, ncol) == (1101, 901)
    rows, cols = len(range(0, nrow, 2)), len(range(0, ncol, 2))  # every 2nd: rows 0..1100, columns 0..900
    assert z.shape == (rows, cols) and z.size <= foxglove_scene.HFIELD_MAX_VERTICES
    data = m.hfield_data.reshape(nrow, ncol) * m.hfield_size[0, 2]
    rx, ry = m.hfield_size[0, :2]
    assert (xs[0], ys[0], z[0, 0]) == pytest.approx((-rx, -ry, data[0, 0]))
    assert (xs[-1], ys[-1], z[-1, -1]) == pytest.approx((rx, ry, data[-1, -1]))
    assert (xs[11], ys[7], z[7, 11]) == pytest.approx((-rx + 0.44, -ry + 0.28, data[14, 22]), abs=1e-6)
    assert foxglove_scene._hfield_triangles(m, g) is not None  # the message builds from them


def test_init_from_names_where_the_source_curriculum_ended(tmp_path):
    """A fine-tune of a tiles run prints the mean level per type of the source's robots at its last
    logged evaluation beside the levels the new run starts at; nothing for a run without them."""
    from quadson_mjx.mcap_log import McapLog
    from quadson_mjx.training.runs import source_curriculum_line

    tiles = _config(min_init_level=1, max_init_level=2).tiles
    with McapLog(tmp_path / "train.mcap") as log:
        log.log("/train/metrics", {"progress": {"step": 0.0}}, 1)
        log.log("/train/metrics", {"curriculum": {"slope_up_level_mean": 3.0, "slope_up_success": 0.5}}, 2)
        log.log("/train/metrics", {"curriculum": {"slope_up_level_mean": 7.25, "flat_level_mean": 6.0}}, 3)
    line = source_curriculum_line(tmp_path, tiles)
    assert line == (
        "curriculum: the source's robots ended at mean levels slope_up 7.2, flat 6.0; this run starts "
        "its robots at levels 1-2 (env.tiles.min_init_level, max_init_level)"
    )
    assert source_curriculum_line(tmp_path / "none", tiles) is None
    (tmp_path / "flat").mkdir()
    with McapLog(tmp_path / "flat" / "train.mcap") as log:
        log.log("/train/metrics", {"progress": {"step": 0.0}}, 1)
    assert source_curriculum_line(tmp_path / "flat", tiles) is None
