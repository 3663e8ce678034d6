import os

import numpy as np
import pytest
from hypothesis import settings

# Property-based tests (Hypothesis) draw the same cases on every run: a failure reproduces, CI stays green
# or red for a reason. ``HYPOTHESIS_PROFILE=explore`` searches afresh.
settings.register_profile("ci", derandomize=True, max_examples=100, deadline=None, print_blob=True)
settings.register_profile("explore", max_examples=2000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
