"""Physics-only throughput of the Quadson model in MJX, and the five-bar closure error, per solver setting.

For each solver setting it reports
  * MuJoCo C (CPU, one world, 4 s): max closure residual under gait-like motion, base height;
  * MJX (the default JAX device, N worlds): control steps/s for a 0.02 s control step (5 physics
    steps at dt 0.004) with noisy gait-like position targets around `home`, the max closure
    residual over all worlds and steps, and the share of worlds that went NaN.
Gait-like motion: motors 1 and 5 swing +-0.15 rad at 2 Hz a quarter period apart (the foot traces a
loop), legs phased as the trot (FL+RR, FR+RL), motor 0 +-0.05 rad, plus N(0, 0.03 rad) target noise
drawn anew every control step.

    python benchmarks/mjx_physics_throughput.py --out results.json            # GPU: everything
    python benchmarks/mjx_physics_throughput.py --worlds 4 --steps 10 --out /tmp/b.json   # smoke test

Prints a markdown table and writes JSON (one record per setting and world count) to --out; the JSON
is rewritten after every measurement so a run cut short keeps what it measured.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import model as qmodel

CTRL_DT = 0.02
GAIT_HZ = 2.0
SWING = 0.15  # [rad] motors 1, 5
ABDUCT = 0.05  # [rad] motor 0
NOISE = 0.03  # [rad] target noise std

# name -> overrides of the committed model; "closure" False switches the equality constraints off.
SETTINGS: dict[str, dict] = {
    "it1_ls5": {"iterations": 1, "ls_iterations": 5},
    "it2_ls6": {"iterations": 2, "ls_iterations": 6},
    "it4_ls8": {"iterations": 4, "ls_iterations": 8},
    "it1_ls5_nolimit": {"iterations": 1, "ls_iterations": 5, "disable": ("LIMIT",)},
    "it2_ls6_softclosure": {
        "iterations": 2,
        "ls_iterations": 6,
        "closure_solimp": (0.9, 0.95, 0.001, 0.5, 2.0),
    },
    "it1_ls3_dt2ms": {"iterations": 1, "ls_iterations": 3, "dt": 0.002},
    "it2_ls6_implicitfast": {"iterations": 2, "ls_iterations": 6, "integrator": "IMPLICITFAST"},
    "it1_ls5_open": {"iterations": 1, "ls_iterations": 5, "closure": False},
    # no joint-limit rows, no base-ground contact, no sensors (the touch sensors make MJX compute
    # contact forces every step): what an env that reads qpos/qvel and terminates on height needs.
    "it1_ls5_lean": {"iterations": 1, "ls_iterations": 5, "disable": ("LIMIT", "SENSOR"), "feet_only": True},
}


# MJX measures these by default (each costs two compilations); MuJoCo C measures every setting.
# implicitfast is left out: it diverges in MuJoCo C with this closed chain (NaN within 2-3 s).
MJX_DEFAULT = ["it1_ls5", "it1_ls5_lean", "it2_ls6", "it1_ls5_open", "it4_ls8", "it1_ls5_nolimit"]


def configured_model(setting: dict) -> mujoco.MjModel:
    """The flat-scene model with a setting's overrides applied."""
    m = qmodel.load_model("flat")
    m.opt.timestep = setting.get("dt", m.opt.timestep)
    m.opt.iterations = setting.get("iterations", m.opt.iterations)
    m.opt.ls_iterations = setting.get("ls_iterations", m.opt.ls_iterations)
    if "integrator" in setting:
        m.opt.integrator = getattr(mujoco.mjtIntegrator, "mjINT_" + setting["integrator"])
    if "closure_solimp" in setting:
        m.eq_solimp[:] = setting["closure_solimp"]
    for flag in setting.get("disable", ()):
        m.opt.disableflags |= getattr(mujoco.mjtDisableBit, "mjDSBL_" + flag)
    if setting.get("feet_only", False):
        base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "base_collision")
        m.geom_contype[base] = m.geom_conaffinity[base] = 0
    if not setting.get("closure", True):
        m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_EQUALITY
    return m


def gait_offsets(t, xp=np):
    """(..., 12) target offsets [rad] from home at time t [s] (LEGS x MOTORS order)."""
    phase = xp.asarray([2 * np.pi * p for p in C.GAITS["trot"]["phase_offset"]])  # (4,)
    w = 2 * np.pi * GAIT_HZ * xp.asarray(t)[..., None] + phase
    off = xp.stack([ABDUCT * xp.sin(w), SWING * xp.sin(w), SWING * xp.cos(w)], axis=-1)  # (..., 4, 3)
    return off.reshape(off.shape[:-2] + (12,))


def c_reference(setting: dict, seconds: float = 4.0, seed: int = 0) -> dict:
    """MuJoCo C, one world: max closure residual [m] and final base height under gait-like motion."""
    m = configured_model(setting)
    d = mujoco.MjData(m)
    ids = qmodel.model_ids(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, C.HOME_KEYFRAME))
    home = qmodel.home_ctrl(m)
    rng = np.random.default_rng(seed)
    n_sub = int(round(CTRL_DT / m.opt.timestep))
    res = 0.0
    t0 = time.perf_counter()
    for k in range(int(round(seconds / CTRL_DT))):
        ctrl = home.copy()
        ctrl[ids.motor_actuator] += gait_offsets(k * CTRL_DT) + NOISE * rng.standard_normal(12)
        d.ctrl[:] = ctrl
        for _ in range(n_sub):
            mujoco.mj_step(m, d)
            res = max(res, float(qmodel.closure_residual(m, d).max()))
    wall = time.perf_counter() - t0
    return {
        "c_residual_max_m": res,
        "c_base_z_final_m": float(d.qpos[ids.root_qposadr + 2]),
        "c_warnings": int(sum(w.number for w in d.warning)),
        "c_ctrl_steps_per_s": round(seconds / CTRL_DT / wall, 1),
    }


def mjx_rollout(m: mujoco.MjModel, n_worlds: int, n_ctrl: int, seed: int = 0):
    """Jitted batched rollout: returns (fn, args); fn(*args) -> (final data, per-world max residual)."""
    mx = mjx.put_model(m, impl="jax")
    ids = qmodel.model_ids(m)
    n_sub = int(round(CTRL_DT / m.opt.timestep))
    home_ctrl = jnp.asarray(qmodel.home_ctrl(m))
    act = jnp.asarray(ids.motor_actuator)
    d0 = mjx.make_data(mx, impl="jax").replace(qpos=jnp.asarray(qmodel.home_qpos(m)), ctrl=home_ctrl)
    d0 = mjx.forward(mx, d0)

    def world(d, key):
        def ctrl_step(carry, k):
            d, key, res = carry
            key, kn = jax.random.split(key)
            target = gait_offsets(k * CTRL_DT, jnp) + NOISE * jax.random.normal(kn, (12,))
            d = d.replace(ctrl=home_ctrl.at[act].add(target))

            def phys(d, _):
                d = mjx.step(mx, d)
                return d, jnp.max(qmodel.closure_residual_mjx(d.site_xpos, ids))

            d, r = jax.lax.scan(phys, d, None, length=n_sub)
            return (d, key, jnp.maximum(res, jnp.max(r))), None

        (d, _, res), _ = jax.lax.scan(ctrl_step, (d, key, jnp.zeros(())), jnp.arange(n_ctrl))
        return d, res

    batch = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n_worlds,) + x.shape), d0)
    keys = jax.random.split(jax.random.PRNGKey(seed), n_worlds)
    return jax.jit(jax.vmap(world)), (batch, keys)


def mjx_measure(setting: dict, n_worlds: int, n_ctrl: int) -> dict:
    m = configured_model(setting)
    fn, args = mjx_rollout(m, n_worlds, n_ctrl)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))  # compile + first run
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    d, res = jax.block_until_ready(fn(*args))
    wall = time.perf_counter() - t0
    nan = np.asarray(jnp.any(~jnp.isfinite(d.qpos), axis=-1))
    res = np.asarray(res)
    return {
        "ctrl_steps_per_s": round(n_worlds * n_ctrl / wall, 1),
        "mjx_residual_max_m": float(np.nanmax(res)) if np.isfinite(res).any() else float("nan"),
        "mjx_residual_p99_m": float(np.nanpercentile(res, 99)) if np.isfinite(res).any() else float("nan"),
        "nan_worlds_frac": float(nan.mean()),
        "compile_plus_first_s": round(compile_s, 1),
        "rollout_s": round(wall, 3),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, nargs="+", default=[8192, 32768])
    ap.add_argument("--steps", type=int, default=100, help="control steps per timed rollout")
    ap.add_argument("--settings", nargs="+", default=MJX_DEFAULT, choices=list(SETTINGS), help="MJX settings")
    ap.add_argument("--no-c", action="store_true", help="skip the MuJoCo C reference")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)

    info = {
        "device": str(jax.devices()[0].device_kind),
        "platform": jax.default_backend(),
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
        "ctrl_dt": CTRL_DT,
    }
    records = []
    c_ref: dict = {}

    def dump():
        with open(a.out, "w") as f:
            json.dump({"info": info, "c_reference": c_ref, "records": records}, f, indent=1)

    print(f"# {info}")
    for name in [] if a.no_c else SETTINGS:
        c_ref[name] = c_reference(SETTINGS[name])
        print(f"C reference {name}: {c_ref[name]}", flush=True)
    dump()
    for name in a.settings:  # setting-major: a run cut short keeps complete settings
        for n in a.worlds:
            rec = {"setting": name, **SETTINGS[name], "worlds": n, **c_ref.get(name, {})}
            try:
                rec.update(mjx_measure(SETTINGS[name], n, a.steps))
            except Exception as e:  # noqa: BLE001 - keep measuring the other settings
                rec["error"] = f"{type(e).__name__}: {e}"[:300]
            records.append(rec)
            dump()
            print(json.dumps(rec), flush=True)

    cols = [
        "setting",
        "worlds",
        "ctrl_steps_per_s",
        "mjx_residual_max_m",
        "nan_worlds_frac",
        "c_residual_max_m",
        "c_base_z_final_m",
    ]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in records:
        cells = []
        for c in cols:
            v = r.get(c, r.get("error", "") if c == "ctrl_steps_per_s" else "")
            cells.append(
                f"{v * 1e3:.3f} mm"
                if c.endswith("_m") and isinstance(v, float) and "residual" in c
                else str(v)
            )
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
