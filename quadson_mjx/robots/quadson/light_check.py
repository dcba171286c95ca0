"""The light five-bar model against the full one in MuJoCo C, under the same motor commands.

`run_variant` steps one model variant (model.FIVEBAR_MODELS) from the home keyframe through a table
of motor targets, standing on the flat floor or hanging (the base welded in the air, no contact),
and records the feet, their normal contact forces and the closure gap; `compare` runs both variants
and reduces the differences; `model_sizes` counts DoFs and constraint rows at home.
benchmarks/fivebar_light_vs_full.py prints them.
"""

from __future__ import annotations

import mujoco
import numpy as np

from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import model as M

HANG_HEIGHT_M = 0.15  # the hanging base is this much above its home height: feet clear the floor


def undamped_knee4(spec: mujoco.MjSpec) -> None:
    """The full model's knee4 hinges without their damping (C.PASSIVE_DAMPING): a change as small as
    the light model's, to show how much a walk's path moves under one."""
    for leg in C.LEGS:
        spec.joint(C.joint_name(leg, "knee4")).damping = np.zeros(3)


def scene_model(variant: str, hang: bool = False, iterations: int | None = None, edit=None) -> mujoco.MjModel:
    """The flat scene of `variant`; hang: its free joint removed, so the base is welded to the world
    HANG_HEIGHT_M above the home height (the legs swing in the air); iterations: the solver's and
    its line search's (None: the model's 1 and 5); edit: a function that changes the MjSpec."""
    if hang or edit is not None:
        spec = mujoco.MjSpec.from_file(str(M.scene_path("flat", variant)))
        if hang:
            base = spec.body(C.ROOT_BODY)
            spec.delete(base.first_joint())
            base.pos = [0.0, 0.0, M.HOME_BASE_HEIGHT + HANG_HEIGHT_M]
            spec.delete(spec.keys[0])  # its qpos has the free joint's 7 numbers
        if edit is not None:
            edit(spec)
        m = spec.compile()
    else:
        m = M.load_model("flat", variant)
    if iterations is not None:
        m.opt.iterations = m.opt.ls_iterations = iterations
    return m


def home_qpos(model: mujoco.MjModel, variant: str) -> np.ndarray:
    """(nq,) the home keyframe's joint angles, without the free joint for a hanging model."""
    qpos = M.home_qpos(M.load_model("flat", variant))
    return qpos if model.nq == qpos.size else qpos[7:]


def model_sizes(variant: str) -> dict:
    """DoFs and constraint rows of `variant` at the home keyframe on the flat floor (mj_forward)."""
    m = M.load_model("flat", variant)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, C.HOME_KEYFRAME))
    mujoco.mj_forward(m, d)
    return {
        "nq": m.nq,
        "nv": m.nv,
        "nbody": m.nbody,
        "nefc": int(d.nefc),
        "equality_rows": int(d.ne),
        "limit_rows": int(d.nl),
        "contacts": int(d.ncon),
        "mass_kg": float(mujoco.mj_getTotalmass(m)),
        "com_m": d.subtree_com[m.body(C.ROOT_BODY).id].tolist(),
    }


def foot_normal_forces(model: mujoco.MjModel, data: mujoco.MjData, foot_geoms: np.ndarray) -> np.ndarray:
    """(4,) normal contact force on each foot geom [N]."""
    out, f = np.zeros(len(foot_geoms)), np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        for k, g in enumerate(foot_geoms):
            if g in (c.geom1, c.geom2):
                mujoco.mj_contactForce(model, data, i, f)
                out[k] += f[0]
    return out


def run_variant(
    variant: str,
    targets: np.ndarray,
    n_sub: int,
    hang: bool = False,
    iterations: int | None = None,
    edit=None,
) -> dict:
    """targets: (n, 12) motor angles [rad] in C.ACTUATORS order, one row per control step of n_sub
    physics steps -> arrays over the n + 1 states (the first is home): "foot" (n+1, 4, 3) world [m],
    "foot_base" (n+1, 4, 3) in the base frame [m], "force" (n+1, 4) foot normal forces [N], "closure"
    (n+1, 4) closure gap [m], "base" (n+1, 3) base position [m], the state "qpos", "qvel",
    "qacc_warmstart"; "warnings": MuJoCo warnings."""
    m = scene_model(variant, hang, iterations, edit)
    d = mujoco.MjData(m)
    ids = M.model_ids(m)
    d.qpos[:] = home_qpos(m, variant)
    d.ctrl[ids.motor_actuator] = targets[0]
    mujoco.mj_forward(m, d)
    feet = np.array(
        [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{leg}_foot_collision") for leg in C.LEGS]
    )
    base = ids.base_body
    rec = {k: [] for k in ("foot", "foot_base", "force", "closure", "base", "qpos", "qvel", "qacc_warmstart")}

    def record():
        foot = d.site_xpos[ids.foot_site]
        rec["foot"].append(foot.copy())
        rec["foot_base"].append((foot - d.xpos[base]) @ d.xmat[base].reshape(3, 3))
        rec["force"].append(foot_normal_forces(m, d, feet))
        rec["closure"].append(M.closure_residual(m, d))
        rec["base"].append(d.xpos[base].copy())
        for k in ("qpos", "qvel", "qacc_warmstart"):
            rec[k].append(getattr(d, k).copy())

    record()
    for row in targets:
        d.ctrl[ids.motor_actuator] = row
        mujoco.mj_step(m, d, nstep=n_sub)
        # positions and contact forces of the new state (mj_step leaves the last substep's); mj_forward
        # changes no state (qacc_warmstart included), so the run is the one `quadson-gait` plays
        mujoco.mj_forward(m, d)
        record()
    out = {k: np.asarray(v) for k, v in rec.items()}
    out["warnings"] = int(np.sum(d.warning.number))
    return out


PERTURB_RAD = 1e-6  # the chaos floor: the full model again, every motor target moved by this much


def _diff(a: dict, b: dict, ctrl_dt: float) -> dict:
    """Differences b - a of two runs (run_variant): foot paths (world and base frame) max and RMS
    [m], the first time the world feet part by more than 1 mm [s] (None: never), base position max
    [m], foot normal forces max and RMS [N]."""

    def dist(key):
        return np.linalg.norm(b[key] - a[key], axis=-1)

    foot, foot_base, df = dist("foot"), dist("foot_base"), b["force"] - a["force"]
    apart = np.nonzero(foot.max(axis=-1) > 1e-3)[0]
    return {
        "foot_max_m": float(foot.max()),
        "foot_rms_m": float(np.sqrt(np.mean(foot**2))),
        "foot_base_frame_max_m": float(foot_base.max()),
        "foot_base_frame_rms_m": float(np.sqrt(np.mean(foot_base**2))),
        "feet_1mm_apart_at_s": float(apart[0] * ctrl_dt) if apart.size else None,
        "base_max_m": float(dist("base").max()),
        "force_max_n": float(np.abs(df).max()),
        "force_rms_n": float(np.sqrt(np.mean(df * df))),
    }


def compare(targets: np.ndarray, n_sub: int, ctrl_dt: float, hang: bool = False) -> dict:
    """Both variants under the same targets (n, 12) [rad], n_sub physics steps per control step of
    ctrl_dt [s] -> "light": the light model's differences from the full one (_diff); "floor": the
    full model's own differences under targets + PERTURB_RAD (how fast contact makes two nearly equal
    runs part); "undamped_knee4": the full model's differences when its knee4 hinges lose their
    damping (undamped_knee4); the full model's mean foot normal force [N]; each run's largest
    closure gap [m] and MuJoCo warnings."""
    full, light = (run_variant(v, targets, n_sub, hang) for v in M.FIVEBAR_MODELS)
    nudged = run_variant("full", targets + PERTURB_RAD, n_sub, hang)
    undamped = run_variant("full", targets, n_sub, hang, edit=undamped_knee4)
    return {
        "light": _diff(full, light, ctrl_dt),
        "floor": _diff(full, nudged, ctrl_dt),
        "undamped_knee4": _diff(full, undamped, ctrl_dt),
        "force_mean_full_n": float(full["force"].mean()),
        "closure_max_full_m": float(full["closure"].max()),
        "closure_max_light_m": float(light["closure"].max()),
        "warnings": full["warnings"] + light["warnings"] + nudged["warnings"] + undamped["warnings"],
    }


def mjx_vs_c(
    variant: str = "light", n_steps: int = 10, offset_rad: float = 0.05, iterations: int = 50
) -> dict:
    """`variant` on the flat floor from home, motor targets home + offset_rad, stepped n_steps
    physics steps by mjx.step (jit, the default float32) and by mj_step -> largest differences of
    qpos [m or rad], qvel [m/s or rad/s] and the feet [m], and the closure gaps [m] of both.
    iterations: the solver's (the model's 1 Newton iteration leaves each step's answer to how the
    two implementations start and search; a converged solve compares the constraints themselves)."""
    import jax
    from mujoco import mjx

    m = M.load_model("flat", variant)
    m.opt.iterations, m.opt.ls_iterations = iterations, iterations
    ids = M.model_ids(m)
    d = mujoco.MjData(m)
    d.qpos[:] = M.home_qpos(m)
    d.ctrl[:] = M.home_ctrl(m)
    d.ctrl[ids.motor_actuator] += offset_rad
    mujoco.mj_forward(m, d)
    with jax.enable_x64(True):  # float32 parts from C by ~1 mm in 10 steps on either variant
        dx = mjx.put_data(m, d)
        step = jax.jit(mjx.step)
        mx = mjx.put_model(m)
        for _ in range(n_steps):
            dx = step(mx, dx)
            mujoco.mj_step(m, d)
        return {
            "qpos_max": float(np.abs(np.asarray(dx.qpos) - d.qpos).max()),
            "qvel_max": float(np.abs(np.asarray(dx.qvel) - d.qvel).max()),
            "foot_max_m": float(
                np.abs(np.asarray(dx.site_xpos)[ids.foot_site] - d.site_xpos[ids.foot_site]).max()
            ),
            "closure_max_c_m": float(M.closure_residual(m, d).max()),
            "closure_max_mjx_m": float(np.asarray(M.closure_residual_mjx(dx.site_xpos, ids)).max()),
        }


def _shared_coordinates(full: mujoco.MjModel, light: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """qpos and dof indices of `full` (in light's order) of the joints both models have: every joint
    of the light model, under the same name and with the same meaning (model._knee2_ref keeps it)."""
    qpos, dof = [], []
    for j in range(light.njnt):
        jf = full.joint(light.joint(j).name).id
        nq = {0: 7, 1: 4}.get(int(light.jnt_type[j]), 1)
        qpos += range(full.jnt_qposadr[jf], full.jnt_qposadr[jf] + nq)
        dof += range(full.jnt_dofadr[jf], full.jnt_dofadr[jf] + (nq - 1 if nq > 1 else 1))
    return np.asarray(qpos), np.asarray(dof)


def one_step_errors(
    targets: np.ndarray, n_sub: int, hang: bool = False, iterations: int | None = None
) -> dict:
    """The light model started from every state of the full model's run (run_variant) and stepped
    one control step (n_sub physics steps) under the same target: its feet [m] and foot normal forces
    [N] against the full model's next state, max and RMS over steps and feet. This measures the
    models' difference per step, apart from how a walk amplifies it (iterations: scene_model)."""
    full = run_variant("full", targets, n_sub, hang, iterations)
    mf, m = scene_model("full", hang), scene_model("light", hang, iterations)
    qi, vi = _shared_coordinates(mf, m)
    d = mujoco.MjData(m)
    ids = M.model_ids(m)
    feet = np.array(
        [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{leg}_foot_collision") for leg in C.LEGS]
    )
    foot_err, force_err = [], []
    for k, row in enumerate(targets):
        d.qpos[:], d.qvel[:] = full["qpos"][k][qi], full["qvel"][k][vi]
        d.qacc_warmstart[:] = full["qacc_warmstart"][k][vi]
        d.ctrl[ids.motor_actuator] = row
        mujoco.mj_step(m, d, nstep=n_sub)
        mujoco.mj_forward(m, d)  # contacts and forces of the new state, as run_variant records them
        foot_err.append(np.linalg.norm(d.site_xpos[ids.foot_site] - full["foot"][k + 1], axis=-1))
        force_err.append(foot_normal_forces(m, d, feet) - full["force"][k + 1])
    foot_err, force_err = np.asarray(foot_err), np.asarray(force_err)
    return {
        "foot_max_m": float(foot_err.max()),
        "foot_rms_m": float(np.sqrt(np.mean(foot_err**2))),
        "force_max_n": float(np.abs(force_err).max()),
        "force_rms_n": float(np.sqrt(np.mean(force_err**2))),
    }
