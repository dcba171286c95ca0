"""The evaluations' success interval against published Wilson score intervals."""

import pytest

from quadson_mjx.stats import success_interval


@pytest.mark.parametrize(
    "successes, trials, low, high",
    [
        # Wilson (1927) score intervals at 95 %, as tabulated by Newcombe, Statistics in Medicine 17
        # (1998) 857-872, table II: 81/263 -> 0.2553-0.3662, 15/148 -> 0.0624-0.1605,
        # 0/20 -> 0-0.1611, 1/29 -> 0.0061-0.1718
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
        (0, 20, 0.0, 0.1611),
        (1, 29, 0.0061, 0.1718),
    ],
)
def test_wilson_interval_matches_published_values(successes, trials, low, high):
    lo, hi = success_interval(successes, trials)
    assert lo == pytest.approx(low, abs=6e-5) and hi == pytest.approx(high, abs=6e-5)


def test_all_or_nothing_reach_the_bounds_and_bad_counts_are_refused():
    assert success_interval(32, 32)[1] == 1.0 and success_interval(0, 32)[0] == 0.0
    lo, hi = success_interval(16, 32)
    assert lo < 0.5 < hi and lo + hi == pytest.approx(1.0)  # symmetric about one half
    for bad in ((1, 0), (-1, 10), (11, 10)):
        with pytest.raises(ValueError, match="success interval"):
            success_interval(*bad)
