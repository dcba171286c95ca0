"""The light five-bar model (env.fivebar_model=light) against the full one, in MuJoCo C.

    python benchmarks/fivebar_light_vs_full.py [--gait trot] [--duration-s 5] [--json PATH]

Prints each model's DoFs and constraint rows at the home keyframe on flat ground; then, under the
same motor targets (the gait's open-loop targets through the five-bar IK, 50 Hz, from home, as
`quadson-gait` plays them), walking on the flat floor and hanging (base welded 0.15 m up, no
contact): the feet's difference light - full (max, RMS, world and base frame, when they first part
by 1 mm), the feet's normal-force difference, each model's largest closure gap, and the same numbers
for the full model against itself with every target moved by 1 µrad (the floor two nearly equal
runs reach) and without its knee4 hinges' damping (a change as small as the light model's); and the
light model's error over one control step started from each state of the full model's run (with
the model's 1 solver iteration and with 50); each of the five gaits' open-loop trial (`quadson-gait`:
mean speed, stayed up, roll and pitch ranges) on both models. Last, mjx.step against mj_step on the light model
(float64, a converged solver).
"""

from __future__ import annotations

import argparse
import json

from quadson_mjx.cli.gait import FIVE, open_loop_targets, run_trial
from quadson_mjx.robots.quadson import gait as G
from quadson_mjx.robots.quadson import light_check as L
from quadson_mjx.robots.quadson import model as M

CTRL_DT = 0.02
SOLVER_CONVERGED = 50  # iterations of the converged-solver rows


def _up(trial):
    return "yes" if trial["stayed_up"] else f"NO {trial['fell_at_s']:.1f} s"


def _mm(x):
    return "never" if x is None else f"{x:.2f} s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gait", default="trot", choices=G.GAIT_NAMES)
    ap.add_argument("--duration-s", type=float, default=5.0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    out = {"sizes": {v: L.model_sizes(v) for v in M.FIVEBAR_MODELS}}
    print("model  nq  nv  nbody  nefc  equality rows  contacts  mass [kg]")
    for v, s in out["sizes"].items():
        print(f"{v:6s} {s['nq']:3d} {s['nv']:3d} {s['nbody']:6d} {s['nefc']:5d} {s['equality_rows']:14d} "
              f"{s['contacts']:9d} {s['mass_kg']:10.4f}")  # fmt: skip

    targets = open_loop_targets(args.gait, args.duration_s, CTRL_DT)
    n_sub = round(CTRL_DT / M.load_model().opt.timestep)
    for case, hang in (("walking", False), ("hanging", True)):
        r = L.compare(targets, n_sub, CTRL_DT, hang)
        out[case] = r
        print(f"\n{case}: {args.gait}, {args.duration_s} s, closure gap max full {1e3 * r['closure_max_full_m']:.3f} mm, "
              f"light {1e3 * r['closure_max_light_m']:.3f} mm; full's mean foot normal force {r['force_mean_full_n']:.2f} N; "
              f"MuJoCo warnings {r['warnings']}")  # fmt: skip
        print(
            "               foot max  foot RMS  base-frame max  base-frame RMS  feet 1 mm apart  base max  force max  force RMS"
        )
        for name in ("light", "floor", "undamped_knee4"):
            d = r[name]
            print(f"  {name:14s} {1e3 * d['foot_max_m']:8.3f}  {1e3 * d['foot_rms_m']:8.3f}  "
                  f"{1e3 * d['foot_base_frame_max_m']:14.3f}  {1e3 * d['foot_base_frame_rms_m']:14.3f}  "
                  f"{_mm(d['feet_1mm_apart_at_s']):>15s}  {1e3 * d['base_max_m']:8.3f}  "
                  f"{d['force_max_n']:9.3f}  {d['force_rms_n']:9.3f}")  # fmt: skip
        print(
            "  (lengths in mm, forces in N; light: light vs full; floor: full vs full with targets + 1 µrad;"
        )
        print("   undamped_knee4: full vs full without the knee4 hinges' 0.001 N m s/rad damping)")
        for it in (None, SOLVER_CONVERGED):
            e = L.one_step_errors(targets, n_sub, hang, it)
            out[case][f"one_step_iterations_{it or 1}"] = e
            print(f"  one control step from the full model's state, {it or 1} solver iteration(s): feet max "
                  f"{1e3 * e['foot_max_m']:.3f} mm, RMS {1e3 * e['foot_rms_m']:.3f} mm; normal force max "
                  f"{e['force_max_n']:.3f} N, RMS {e['force_rms_n']:.3f} N")  # fmt: skip

    print(
        "\nopen-loop gaits, 10 s at the seed speed (quadson-gait): mean vx [m/s], stayed up, roll and pitch range [deg]"
    )
    print("gait     full: vx    stayed up   Δroll  Δpitch   light: vx    stayed up   Δroll  Δpitch")
    out["gaits"] = {}
    for gait in FIVE:
        r = {v: run_trial(gait, fivebar_model=v) for v in M.FIVEBAR_MODELS}
        out["gaits"][gait] = r
        cells = "   ".join(
            f"{r[v]['mean_vx']:9.3f} {_up(r[v]):>9s} {r[v]['roll_range_deg']:7.2f} "
            f"{r[v]['pitch_range_deg']:7.2f}"
            for v in M.FIVEBAR_MODELS
        )
        print(f"{gait:8s} {cells}")

    out["mjx_vs_c"] = L.mjx_vs_c("light")
    r = out["mjx_vs_c"]
    print(f"\nmjx.step vs mj_step, light model, 5 steps, float64, 50 solver iterations: qpos max {r['qpos_max']:.2e}, "
          f"qvel max {r['qvel_max']:.2e}, feet max {r['foot_max_m']:.2e} m, closure gap C {r['closure_max_c_m']:.2e} m, "
          f"MJX {r['closure_max_mjx_m']:.2e} m")  # fmt: skip
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
