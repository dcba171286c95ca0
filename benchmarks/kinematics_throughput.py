"""Throughput of batched, jitted leg FK and IK against a per-point Python loop of the seed algorithm.

The loop is seed 000 Algorithms 1-2 written as the robot's own code does it: one point at a time
with the math module, float64. It is timed on a subsample (--loop-points) and its per-point rate
is assumed constant for larger batches (Python loop cost is linear in the points); the table
says which rows are extrapolated. Jitted rows are measured at every size: compiled first, inputs
already on the device, best of --repeats, block_until_ready.

    python benchmarks/kinematics_throughput.py            # CPU, float64 (and float32 for jax)
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import numpy as np

from quadson_mjx.robots.quadson import constants as C

L0, L1, L2, L3, L4, L5 = C.LINK_LENGTHS


# --- the seed's algorithms, one point at a time (reference and baseline) -----------------------


def fk_point(t0: float, t1: float, t5: float) -> tuple[float, float, float]:
    """Algorithm 1 with the rotation sign of robots.md."""
    p2x, p2y = L1 * math.cos(t1), -L1 * math.sin(t1)
    p4x, p4y = L0 + L5 * math.cos(t5), -L5 * math.sin(t5)
    l14 = math.hypot(p4x, p4y)
    l24 = math.hypot(p4x - p2x, p4y - p2y)
    theta2 = (
        math.acos((L2**2 + l24**2 - L4**2) / (2 * L2 * l24))
        + math.acos((L1**2 + l24**2 - l14**2) / (2 * L1 * l24))
        - (math.pi - t1)
    )
    x = p2x + (L2 + L3) * math.cos(theta2)
    y = p2y - (L2 + L3) * math.sin(theta2)
    return x, y * math.cos(t0), y * math.sin(t0)


def ik_point(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Algorithm 2 (atan2 for the seed's atan of a quotient)."""
    t0 = -math.atan2(z, -y)
    yp = y * math.cos(t0) + z * math.sin(t0)
    l1e = math.hypot(x, yp)
    t1 = math.atan2(-yp, x) + math.acos((L1**2 + l1e**2 - (L2 + L3) ** 2) / (2 * L1 * l1e))
    p2x, p2y = L1 * math.cos(t1), -L1 * math.sin(t1)
    p3x = (x * L2 + p2x * L3) / (L2 + L3)
    p3y = (yp * L2 + p2y * L3) / (L2 + L3)
    l35 = math.hypot(L0 - p3x, p3y)
    t350 = math.atan2(-p3y, L0 - p3x)
    t354 = math.acos((l35**2 + L5**2 - L4**2) / (2 * l35 * L5))
    return t0, t1, math.pi - (t350 + t354)


def _rot_x(a: float) -> np.ndarray:
    return np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]])


def fk_point_numpy(t0: float, t1: float, t5: float) -> np.ndarray:
    """Algorithm 1 in the style of the robot's own code: small numpy arrays per point, np.clip'ed
    acos, the planar points turned 3D by a row vector times R(-t0)."""
    p2 = np.array([L1 * math.cos(t1), -L1 * math.sin(t1)])
    p5 = np.array([L0, 0.0])
    p4 = np.array([L5 * math.cos(t5), -L5 * math.sin(t5)]) + p5
    l14, l24 = np.linalg.norm(p4), np.linalg.norm(p4 - p2)
    a324 = math.acos(np.clip((L2**2 + l24**2 - L4**2) / (2 * L2 * l24), -1.0, 1.0))
    a421 = math.acos(np.clip((L1**2 + l24**2 - l14**2) / (2 * L1 * l24), -1.0, 1.0))
    theta2 = a324 + a421 - (math.pi - t1)
    pe = p2 + (L2 + L3) * np.array([math.cos(theta2), -math.sin(theta2)])
    return np.array([pe[0], pe[1], 0.0]) @ _rot_x(-t0)


def ik_point_numpy(x: float, y: float, z: float) -> np.ndarray:
    """Algorithm 2 in the style of the robot's own code (numpy arrays per point)."""
    t0 = -math.atan2(z, -y)
    xp, yp, _ = _rot_x(-t0) @ np.array([x, y, z])
    pe = np.array([xp, yp])
    l1e = np.linalg.norm(pe)
    c12 = (L1**2 + l1e**2 - (L2 + L3) ** 2) / (2 * L1 * l1e)
    t1 = math.atan2(-yp, xp) + math.acos(np.clip(c12, -1.0, 1.0))
    p2 = np.array([L1 * math.cos(t1), -L1 * math.sin(t1)])
    p3 = (pe * L2 + p2 * L3) / (L2 + L3)
    p5 = np.array([L0, 0.0])
    l35 = np.linalg.norm(p3 - p5)
    t350 = math.atan2(-p3[1], L0 - p3[0])
    t354 = math.acos(np.clip((l35**2 + L5**2 - L4**2) / (2 * l35 * L5), -1.0, 1.0))
    return np.array([t0, t1, math.pi - (t350 + t354)])


# --- data: valid poses of the robot's branch and their feet -----------------------------------


def valid_poses(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n motor angles (within limits, toe-in guard, on the IK branch) and their feet, float64."""
    from quadson_mjx.robots.quadson import fivebar

    rng = np.random.default_rng(seed)
    fk_j, ik_j = jax.jit(fivebar.leg_fk), jax.jit(fivebar.leg_ik)
    chunks, have = [], 0
    while have < n:
        a = rng.uniform(C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1], size=(2 * n, 3))
        foot = np.asarray(fk_j(a))
        back, valid = map(np.asarray, ik_j(foot))
        keep = valid & np.all(np.abs(back - a) < 1e-9, axis=-1)  # on the branch IK returns
        # Algorithm 1's acos sum holds only while p4 is clockwise of p2 -> p1 (see fivebar).
        p2 = L1 * np.stack([np.cos(a[:, 1]), -np.sin(a[:, 1])], -1)
        p4 = np.stack([L0 + L5 * np.cos(a[:, 2]), -L5 * np.sin(a[:, 2])], -1)
        u, v = -p2, p4 - p2
        keep &= u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] <= 0
        chunks.append(a[keep])
        have += int(keep.sum())
    a = np.concatenate(chunks)[:n]
    return a, np.asarray(fk_j(a))


# --- timing --------------------------------------------------------------------------------------


def best_of(fn, repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def time_jitted(fn, x, repeats: int) -> float:
    xd = jax.device_put(x)
    jax.block_until_ready(fn(xd))  # compile and warm up
    return best_of(lambda: jax.block_until_ready(fn(xd)), repeats)


def time_loop(point_fn, rows: np.ndarray, repeats: int) -> float:
    pts = rows.tolist()
    return best_of(lambda: [point_fn(*p) for p in pts], repeats)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", default="1,10,100,1000,10000,100000,1000000")
    parser.add_argument(
        "--loop-points", type=int, default=20_000, help="largest batch the Python loops really run"
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--platform", default="cpu")
    args = parser.parse_args()
    jax.config.update("jax_platforms", args.platform)
    jax.config.update("jax_enable_x64", True)  # a script: the reference comparison is float64

    from quadson_mjx.robots.quadson import fivebar

    sizes = [int(float(s)) for s in args.sizes.split(",")]
    angles, feet = valid_poses(max(max(sizes), args.loop_points))
    jitted = {"fk": (jax.jit(fivebar.leg_fk), angles), "ik": (jax.jit(lambda f: fivebar.leg_ik(f)[0]), feet)}
    loops = {
        ("fk", "numpy"): fk_point_numpy,
        ("fk", "math"): fk_point,
        ("ik", "numpy"): ik_point_numpy,
        ("ik", "math"): ik_point,
    }

    # Agreement with the per-point seed algorithm, float64, on the loops' subsample.
    m = args.loop_points
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), jax {jax.__version__}")
    for (name, style), fn in loops.items():
        jf, rows = jitted[name]
        ref = np.array([fn(*p) for p in rows[:m].tolist()])
        err = np.abs(np.asarray(jf(rows[:m])) - ref).max()
        unit = "m" if name == "fk" else "rad"
        print(
            f"max |jitted - per-point {style} loop| {name.upper()}, float64, {m} valid poses: {err:.2e} {unit}"
        )
        assert err <= 1e-9, "jitted kinematics disagree with the seed algorithm"

    # Per-point loop rates: measured for batches up to --loop-points, beyond that the rate of the
    # --loop-points run (a Python loop's cost is linear in the points).
    rate = {}
    for (name, style), fn in loops.items():
        rows = jitted[name][1]
        for n in [n for n in sizes if n < m] + [m]:
            rate[name, style, n] = n / time_loop(fn, rows[:n], max(2, min(args.repeats, 10_000 // n)))
        for n in sizes:
            rate.setdefault((name, style, n), rate[name, style, m])
    for name, (jf, rows) in jitted.items():
        for n in sizes:
            reps = args.repeats if n < 1_000_000 else max(3, args.repeats // 2)
            rate[name, "jit64", n] = n / time_jitted(jf, rows[:n], reps)
            rate[name, "jit32", n] = n / time_jitted(jf, rows[:n].astype(np.float32), reps)

    cols = [(k, s) for k in ("fk", "ik") for s in ("jit64", "jit32", "numpy", "math")]
    head = {"jit64": "jit f64", "jit32": "jit f32", "numpy": "numpy loop", "math": "math loop"}
    print()
    print("Throughput [points/s]; loops are float64 per-point Python, * = extrapolated rate.")
    print()
    print(
        "| batch | "
        + " | ".join(f"{k.upper()} {head[s]}" for k, s in cols)
        + " | IK jit f64 / numpy loop | IK jit f64 / math loop |"
    )
    print("|---:" * (len(cols) + 3) + "|")
    for n in sizes:
        star = " *" if n > m else ""
        cells = [f"{rate[k, s, n]:.3g}" + (star if s in ("numpy", "math") else "") for k, s in cols]
        up = [f"{rate['ik', 'jit64', n] / rate['ik', s, n]:.3g}x" for s in ("numpy", "math")]
        print(f"| {n:,} | " + " | ".join(cells + up) + " |")
    print()
    big = max(sizes)
    print(f"* extrapolated from the loops' {m:,}-point run at a constant per-point cost.")
    for s in ("numpy", "math"):
        print(
            f"IK of {big:,} points, float64: jitted batch {big / rate['ik', 'jit64', big]:.3f} s vs per-point "
            f"{s} loop {big / rate['ik', s, big]:.1f} s: {rate['ik', 'jit64', big] / rate['ik', s, big]:.0f}x."
        )


if __name__ == "__main__":
    main()
