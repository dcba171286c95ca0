"""The foot-contact pattern against the gait's phase table, in numpy: shared by the MJX evaluation
(gait_eval) and the MuJoCo C closed loop (sim2sim), which must count a touchdown alike.

A foot is "down" when its normal contact force exceeds FORCE_THRESHOLD_N; the table says "stance"
where the leg's phase is below the gait's duty. A control step matches when all four feet agree
with the table; within one step (`tolerance=1`) each foot's touchdown and lift-off may fall one
control step early or late, so that a touchdown between two 50 Hz samples is not a mismatch.
"""

from __future__ import annotations

import numpy as np

FORCE_THRESHOLD_N = 1.0  # a foot carrying less than ~3 % of its share of the ~3 kg robot is "up"


def tolerant_agreement(contact: np.ndarray, stance: np.ndarray, tolerance: int) -> np.ndarray:
    """contact, stance: (T, ...) bool -> (T, ...) bool: contact[t] equals stance[t'] for some
    |t' - t| <= tolerance (t' inside the array): each transition may be early or late by up to
    `tolerance` steps."""
    contact = np.asarray(contact, bool)
    stance = np.asarray(stance, bool)
    ok = contact == stance
    n = contact.shape[0]
    for d in range(1, tolerance + 1):
        ok[d:] |= contact[d:] == stance[:-d]
        ok[: n - d] |= contact[: n - d] == stance[d:]
    return ok


def pattern_counts(foot_force: np.ndarray, stance: np.ndarray) -> dict:
    """foot_force (T, 4) [N], stance (T, 4) bool of one walk's consecutive control steps -> the
    number of steps T, those where all four feet match the table exactly ("pattern_hits") and
    within one step ("pattern_1step_hits"), and the (step, foot) pairs that agree."""
    contact = np.asarray(foot_force, np.float64).reshape(-1, 4) > FORCE_THRESHOLD_N
    stance = np.asarray(stance, bool).reshape(-1, 4)
    if contact.shape != stance.shape:
        raise ValueError(f"foot forces {contact.shape} and stance {stance.shape} differ in shape")
    return {
        "pattern_steps": int(contact.shape[0]),
        "pattern_hits": int(np.sum(np.all(contact == stance, axis=-1))),
        "pattern_1step_hits": int(np.sum(np.all(tolerant_agreement(contact, stance, 1), axis=-1))),
        "foot_agree": int(np.sum(contact == stance)),
    }
