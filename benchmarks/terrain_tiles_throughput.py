"""Environment steps/s on the tiled ground, per tile type, against flat ground, the stone field and
MuJoCo Playground's feet-only Go1, in one run.

    python benchmarks/terrain_tiles_throughput.py --envs 8192 --steps 100 \
        --go1-scene PATH/scene_mjx_feetonly_flat_terrain.xml --out benchmarks/results/terrain_tiles_h100.json

Every row is the robust preset (the sensor-only joystick recipe: randomization, pushes, the
privileged critic's observation, feet-only contact) as PPO runs it: the training wrappers with domain
randomization and the auto-reset, whose tiled-ground respawn (curriculum and a fresh start on the
tile) runs every step. Actions are uniform in [-0.2, 0.2] (foot offsets of at most 1 cm) around the
gait, so the robots walk and sometimes fall and respawn, as early in training.

The tiled ground is compiled once: its rows differ only in where the robots start (all tile types
mixed, as training draws them, then every robot on one type), each at levels drawn uniformly over
all rows (curriculum off, so the mix stays as drawn). "flat" and "stones" are the plane and the
stone-field scenes. One jitted lax.scan over --steps control steps per row, best of --repeats. The
Go1 row (--go1-scene, see physics_vs_go1.py) is bare physics, the anchor of the other benchmarks;
Playground's feet-only Go1 on its rough height field (the scene beside it) is the field's own
measure of what a height field costs.

--hfield-foot-contacts 4 1 repeats the stone field's and the tiles' rows with one contact a foot
(env.hfield_foot_contacts=1, quadson_mjx/hfield_contact.py) beside MJX's own collider.

--breakdown adds what the tiled ground's cost is made of, in the same run: bare physics (no
environment, noisy position targets around the home pose, every world at the field's centre) on the
plane, the stone field and the tiles on 2 cm and 4 cm cells; the environment on 4 cm cells
(`env.tiles.cell_m=0.04`); and on 2 cm cells with the respawn replaced by a restart at each robot's
first state (as on the stone field), which leaves out the per-step fresh start on the tile.
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
from physics_vs_go1 import load_go1, physics_only, recorder, run_meta

from quadson_mjx.env import LocomotionEnv
from quadson_mjx.randomize import randomization_fn
from quadson_mjx.tasks import config_from_flags
from quadson_mjx.wrappers import ResamplingAutoReset, wrap_for_training

ACTION_RANGE = 0.2


class RestartAtFirstState(ResamplingAutoReset):
    """The auto-reset with the tiled ground's respawn left out: a robot whose episode ends restarts
    at its first state (as on the stone field), so the difference to the respawn's row is the
    per-step fresh start (spawn place, lift, kinematics, observation) and the curriculum."""

    def _respawn_on_tiles(self, state, done, where_done):
        pipeline_state = jax.tree.map(where_done, state.info["first_pipeline_state"], state.pipeline_state)
        obs = jax.tree.map(where_done, state.info["first_obs"], state.obs)
        return state.replace(pipeline_state=pipeline_state, obs=obs)


def wrapped(terrain: str, n_envs: int, cell_m: float | None = None, respawn: bool = True, contacts: int = 4):
    cfg = config_from_flags(env_preset="robust", terrain=terrain).unlock()
    cfg.hfield_foot_contacts = contacts
    if terrain == "tiles":
        cfg.tiles.curriculum = False  # keep each row's mix of levels as drawn
        if cell_m is not None:
            cfg.tiles.cell_m = cell_m
    cfg.lock()
    env = LocomotionEnv(cfg)
    rand = functools.partial(
        randomization_fn(env.config.randomization, env.base_body),
        rng=jax.random.split(jax.random.PRNGKey(1), n_envs),
    )
    w = wrap_for_training(env, env.episode_length, randomization_fn=rand)
    if not respawn:
        w = RestartAtFirstState(w.env, env.episode_length)
    return env, w


def bare_physics(env, n_envs: int, steps: int, repeats: int) -> dict:
    """physics_only on the env's model (its ground) from the home keyframe at the world's origin."""
    m = env.mj_model
    home = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, env.robot.home_keyframe)
    return physics_only(m, m.key_qpos[home], m.key_ctrl[home], n_envs, steps, repeats)


def rollout_fn(env, w, n_envs: int, steps: int):
    """The jitted rollout: (state, key) -> (falls, episode ends) over `steps` control steps."""

    @jax.jit
    def run(state, key):
        def one(carry, k):
            s, falls, resets = carry
            a = jax.random.uniform(k, (n_envs, env.action_size), minval=-ACTION_RANGE, maxval=ACTION_RANGE)
            s = w.step(s, a)
            return (s, falls + jnp.sum(s.metrics["fall"]), resets + jnp.sum(s.done)), None

        init = (state, jnp.zeros(()), jnp.zeros(()))
        (_, falls, resets), _ = jax.lax.scan(one, init, jax.random.split(key, steps))
        return falls, resets

    return run


def timed_rollout(run, state, n_envs: int, steps: int, repeats: int) -> dict:
    t0 = time.perf_counter()
    jax.block_until_ready(run(state, jax.random.PRNGKey(2)))
    first = time.perf_counter() - t0
    best = float("inf")
    for r in range(repeats):
        t0 = time.perf_counter()
        falls, resets = jax.block_until_ready(run(state, jax.random.PRNGKey(3 + r)))
        best = min(best, time.perf_counter() - t0)
    return {
        "env_steps_per_s": n_envs * steps / best,
        "compile_and_first_s": first,
        "falls_per_env_step": float(falls) / (n_envs * steps),
        "episode_ends_per_env_step": float(resets) / (n_envs * steps),
    }


def _contacts_label(contacts: int) -> str:
    return "" if contacts == 4 else f", {contacts} contact{'s' if contacts > 1 else ''} a foot"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[8192])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--go1-scene", default=None)
    p.add_argument("--breakdown", action="store_true", help="add the rows that split the tiles' cost")
    p.add_argument(
        "--hfield-foot-contacts",
        type=int,
        nargs="+",
        default=[4],
        help="the stones' and tiles' rows under each env.hfield_foot_contacts (4: MJX's collider, 1: one contact a foot)",
    )
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    meta = run_meta(args)
    rows, record = recorder(meta, args.out)

    print(f"# {meta}", flush=True)
    for n in args.envs:
        if args.go1_scene:
            go1 = load_go1(args.go1_scene)
            key = mujoco.mj_name2id(go1, mujoco.mjtObj.mjOBJ_KEY, "home")
            record({"robot": "go1_feetonly", "ground": "flat (physics only)", "envs": n,
                    **physics_only(go1, go1.key_qpos[key], go1.key_ctrl[key], n, args.steps, args.repeats)})  # fmt: skip
            rough = load_go1(str(Path(args.go1_scene).with_name("scene_mjx_feetonly_rough_terrain.xml")))
            record({"robot": "go1_feetonly", "ground": "rough height field (physics only)", "envs": n,
                    **physics_only(rough, go1.key_qpos[key], go1.key_ctrl[key], n, args.steps, args.repeats)})  # fmt: skip
        for terrain, ground, contacts in (
            ("flat", "flat", 4),
            *(("rough", "stones field" + _contacts_label(c), c) for c in args.hfield_foot_contacts),
        ):
            env, w = wrapped(terrain, n, contacts=contacts)
            state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), n))
            run = rollout_fn(env, w, n, args.steps)
            record({"robot": "quadson", "ground": ground, "envs": n, "hfield_foot_contacts": contacts,
                    **timed_rollout(run, state, n, args.steps, args.repeats)})  # fmt: skip
        for contacts in args.hfield_foot_contacts:
            env, w = wrapped("tiles", n, contacts=contacts)
            run = rollout_fn(env, w, n, args.steps)  # compiled once for every row of the tiled ground
            spec = env.tiles
            reset_on = jax.jit(w.reset_on_tiles)
            keys = jax.random.split(jax.random.PRNGKey(0), n)
            levels = jax.random.randint(jax.random.PRNGKey(5), (n,), 0, spec.levels)
            mixed = jax.random.randint(jax.random.PRNGKey(6), (n,), 0, len(spec.types))
            for ground, types in (
                ("tiles: all types", mixed),
                *((f"tiles: {t}", i) for i, t in enumerate(spec.types)),
            ):
                state = reset_on(keys, types, levels)
                record({"robot": "quadson", "ground": ground + _contacts_label(contacts), "envs": n,
                        "hfield_foot_contacts": contacts, **timed_rollout(run, state, n, args.steps, args.repeats)})  # fmt: skip
        if args.breakdown:
            for name, kw in (
                ("tiles: all types, 4 cm cells", {"cell_m": 0.04}),
                ("tiles: all types, no respawn", {"respawn": False}),
            ):
                env, w = wrapped("tiles", n, **kw)
                state = jax.jit(w.reset_on_tiles)(keys, mixed, levels)
                record({"robot": "quadson", "ground": name, "envs": n,
                        **timed_rollout(rollout_fn(env, w, n, args.steps), state, n, args.steps, args.repeats)})  # fmt: skip
            for name, terrain, cell in (
                ("plane", "flat", None),
                ("stone field (4 cm cells)", "rough", None),
                ("tiles (2 cm cells)", "tiles", None),
                ("tiles (4 cm cells)", "tiles", 0.04),
            ):
                env, _ = wrapped(terrain, n, cell_m=cell)
                record({"robot": "quadson", "ground": f"{name} (physics only)", "envs": n,
                        **bare_physics(env, n, args.steps, args.repeats)})  # fmt: skip
    flat = {r["envs"]: r["env_steps_per_s"] for r in rows if r["ground"] == "flat"}
    go1 = {r["envs"]: r["physics_steps_per_s"] for r in rows if r["ground"] == "flat (physics only)"}
    plane = {r["envs"]: r["physics_steps_per_s"] for r in rows if r["ground"] == "plane (physics only)"}
    print("\n| ground | envs | env steps/s | x flat | x Go1 physics | falls per 1000 steps |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        if "env_steps_per_s" not in r:
            continue
        sps, n = r["env_steps_per_s"], r["envs"]
        vs_go1 = f"{sps / go1[n]:.2f}" if n in go1 else "-"
        print(f"| {r['ground']} | {n} | {sps:,.0f} | {sps / flat[n]:.2f} | {vs_go1} | {1000 * r['falls_per_env_step']:.1f} |")  # fmt: skip
    physics = [r for r in rows if "physics_steps_per_s" in r]
    if physics:
        print("\n| bare physics | envs | control steps/s | x Go1 flat | x Quadson plane |")
        print("|---|---|---:|---:|---:|")
        for r in physics:
            sps, n = r["physics_steps_per_s"], r["envs"]
            vs_go1 = f"{sps / go1[n]:.2f}" if n in go1 else "-"
            vs_plane = f"{sps / plane[n]:.2f}" if n in plane else "-"
            print(f"| {r['robot']}: {r['ground']} | {n} | {sps:,.0f} | {vs_go1} | {vs_plane} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
