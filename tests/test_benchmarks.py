"""The study scripts' own arithmetic (``benchmarks/``), against closed forms and a Monte Carlo."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from crb_bound import as_few_chance, efficient_count_range


def test_an_efficient_estimators_count_range_is_the_coin_flips():
    """Two fair coins: 0, 1 or 2 heads with chances 1/4, 1/2, 1/4; sure episodes always count."""
    assert efficient_count_range([0.5, 0.5]) == (0, 2)
    assert efficient_count_range([1.0] * 5) == (5, 5)
    assert as_few_chance([0.5, 0.5], 0) == 0.25
    assert as_few_chance([0.5, 0.5], 1) == 0.75


def test_the_count_range_and_the_chance_of_as_few_match_a_monte_carlo():
    """A hundred episodes with unequal chances (as a study's are): the range holds about 90 % of simulated counts
    and the chance of as few is their share at or below the count."""
    rng = np.random.default_rng(5)
    chances = rng.uniform(0.8, 1.0, size=100)
    counts = np.sum(rng.random((40000, 100)) < chances, axis=1)
    low, high = efficient_count_range(list(chances))
    inside = np.mean((counts >= low) & (counts <= high))
    assert 0.9 <= inside < 0.97  # whole counts: the range holds at least 90 %
    assert np.mean(counts < low) <= 0.05 and np.mean(counts > high) <= 0.05
    for count in (low, int(np.median(counts)), high):
        assert abs(as_few_chance(list(chances), count) - np.mean(counts <= count)) < 0.01
