"""Statistics of the evaluations: a success rate with its 95 % interval."""

from __future__ import annotations

from scipy.stats import binomtest


def success_interval(successes: int, trials: int, confidence: float = 0.95) -> list[float]:
    """The Wilson score interval [low, high] of a success rate of `successes` in `trials` (scipy's
    binomtest): 16 of 32 is 50 % within [34, 66] %, 32 of 32 100 % within [89, 100] %."""
    if trials < 1 or not 0 <= successes <= trials:
        raise ValueError(f"success interval: {successes} successes in {trials} trials")
    ci = binomtest(int(successes), int(trials)).proportion_ci(confidence_level=confidence, method="wilson")
    return [float(ci.low), float(ci.high)]
