"""Motor targets that the five-bar can reach: the get-up task's guard, in numpy and in JAX alike.

A walking target comes from the IK, so its two hip angles always assemble the chain. A get-up
policy commands the 12 motors directly over their whole ranges, and two hip angles (t1, t5) whose
links p2 and p4 are further apart than L2 + L4 (or closer than |L4 - L2|) cannot be reached: the two
servos would push against each other through the closed chain. `guard_targets` makes any target
reachable, the same way on the robot (numpy, quadson_mjx.deploy_supervisor) and in training (JAX,
quadson_mjx.getup_env), `getup_targets`:

  1. each motor clipped into its real range (constants.MOTOR_RANGES), t5 to at most t1 + TOE_IN_MAX
     (the robot's toe-in guard, as the walking loop's clamp);
  2. a leg whose hip pair then misses the chain by less than margin_m [m] (|p4 - p2| outside
     [|L4 - L2| + margin, L2 + L4 - margin], the lock-up poses) is moved back along the straight
     line to the home angles, to the farthest point of that line that still assembles, found by
     BISECTIONS halvings (home assembles, and the range and the toe-in guard are convex, so every
     point of the line keeps them). It is clamped and counted, never NaN.

The get-up action (`getup_targets`) is centred on the home stance, with the whole real range of each
motor on either side: an untrained policy (a = 0) holds the stance stiffly, and every pose inside
the limits is one action away (full authority). A target relative to the encoders (MuJoCo
Playground's Go1 getup) was tried first: a = 0 then commands the pose the servos already have, so
they exert no torque and the robot sags (measured: from the home stance, zero actions let the base
fall from 0.215 m to 0.09 m within 1.6 s).

Functions take `xp` (numpy or jax.numpy); shapes (..., 4, 3) motor angles (t0, t1, t5) [rad].
"""

from __future__ import annotations

import numpy as np

from quadson_mjx.robots.quadson import constants as C

CHAIN_MARGIN_M = 0.005  # the five-bar this far from its folded or stretched lock-up [m] (getup_start's)
BISECTIONS = 12  # halvings of the line to home: 2^-12 of the way, < 1 mrad on every motor


def chain_slack(angles, xp=np, margin_m: float = CHAIN_MARGIN_M):
    """angles (..., 3) (t0, t1, t5) [rad] -> (...) [m]: how far |p4 - p2| lies inside the band in
    which the chain assembles with margin_m to spare (negative: outside; seed 000's p2 = p1 + L1
    (cos t1, -sin t1), p4 = p5 + L5 (cos t5, -sin t5), p5 = (L0, 0))."""
    t1, t5 = angles[..., 1], angles[..., 2]
    dx = C.L0 + C.L5 * xp.cos(t5) - C.L1 * xp.cos(t1)
    dy = -C.L5 * xp.sin(t5) + C.L1 * xp.sin(t1)
    l24 = xp.sqrt(dx * dx + dy * dy)
    return xp.minimum(l24 - (abs(C.L4 - C.L2) + margin_m), (C.L2 + C.L4 - margin_m) - l24)


def range_and_toe_in(angles, xp=np):
    """(..., 4, 3) [rad] -> the same clipped into MOTOR_RANGES with t5 <= t1 + TOE_IN_MAX."""
    lo, hi = C.MOTOR_RANGES[:, 0], C.MOTOR_RANGES[:, 1]
    a = xp.clip(angles, lo, hi)
    t5 = xp.clip(xp.minimum(a[..., 2], a[..., 1] + C.TOE_IN_MAX), lo[2], hi[2])
    return xp.concatenate([a[..., :2], t5[..., None]], axis=-1)


def guard_targets(angles, anchor, xp=np, margin_m: float = CHAIN_MARGIN_M):
    """angles (..., 4, 3) motor targets [rad]; anchor (..., 4, 3) angles that assemble, to fall
    back toward (the get-up task: home) ->
    (targets (..., 4, 3) inside the ranges, the toe-in guard and the chain band; moved (..., 4) bool:
    the legs that step 2 of the module docstring moved toward the anchor)."""
    target = range_and_toe_in(angles, xp)
    ok = chain_slack(target, xp, margin_m) >= 0.0
    lo = xp.zeros(ok.shape, target.dtype)  # fraction of the way to the target that assembles
    hi = xp.ones(ok.shape, target.dtype)
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        fits = chain_slack(anchor + mid[..., None] * (target - anchor), xp, margin_m) >= 0.0
        lo, hi = xp.where(fits, mid, lo), xp.where(fits, hi, mid)
    s = xp.where(ok, 1.0, lo)[..., None]
    return xp.where(ok[..., None], target, anchor + s * (target - anchor)), ~ok


def getup_targets(action, home, xp=np):
    """The get-up task's action -> motor targets, on the robot and in training alike: action
    (..., 12) in [-1, 1] (clipped), home (12,) the home stance's angles [rad] -> (targets (..., 12)
    [rad]: a = 0 the home stance, a = -1 each motor's lower limit, +1 its upper limit, linear in
    between on either side; then guard_targets toward home; moved (..., 4) bool)."""
    a = xp.clip(action, -1.0, 1.0)
    lo = xp.asarray(np.tile(C.MOTOR_RANGES[:, 0], 4))
    hi = xp.asarray(np.tile(C.MOTOR_RANGES[:, 1], 4))
    raw = home + xp.where(a < 0.0, a * (home - lo), a * (hi - home))
    shape = raw.shape[:-1] + (4, 3)
    targets, moved = guard_targets(xp.reshape(raw, shape), xp.reshape(home, (4, 3)), xp)
    return xp.reshape(targets, raw.shape), moved
