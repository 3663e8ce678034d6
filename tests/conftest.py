import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


# Property-based tests (Hypothesis) draw the same cases on every run: a failure reproduces, CI stays green
# or red for a reason. ``HYPOTHESIS_PROFILE=explore`` searches afresh.
import os  # noqa: E402

from hypothesis import settings  # noqa: E402

settings.register_profile("ci", derandomize=True, max_examples=100, deadline=None, print_blob=True)
settings.register_profile("explore", max_examples=2000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
