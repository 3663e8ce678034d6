import math

import numpy as np

from aasl_gym import metrics


def test_convergence_time_requires_staying_below():
    times = np.arange(1, 11) * 1.0
    errors = np.array([np.nan, np.nan, 5, 0.5, 2, 0.9, 0.8, 0.7, 0.6, 0.5])
    assert metrics.convergence_time(times, errors, 1.0) == 6.0
    assert math.isnan(metrics.convergence_time(times, np.r_[errors[:-1], 1.5], 1.0))
    assert metrics.convergence_time(times, np.full(10, 0.1), 1.0) == 1.0


def test_success_rmse_and_first_estimate():
    times = np.arange(1, 6) * 1.0
    errors = np.array([np.nan, 3.0, 4.0, 0.4, 0.15])
    assert metrics.success(times, errors) == {
        "0.1": False,
        "0.2": True,
        "0.5": True,
        "1.0": True,
        "2.0": True,
        "3.0": True,
    }
    assert metrics.rmse(errors) == np.sqrt(np.mean(np.array([3.0, 4.0, 0.4, 0.15]) ** 2))
    assert metrics.time_to_first_estimate(times, errors) == 2.0
