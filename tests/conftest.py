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


@pytest.fixture(scope="session")
def einsum_sums_even_odd() -> bool:
    """Whether this NumPy's ``einsum`` sums a contraction of six as two running sums, the even terms' and the odd
    terms' (NumPy's baseline x86-64 build; the order the committed rows were made in and the compiled R_eff term
    copies). Builds with wider vectors or fused multiply-adds (ARM, x86-64-v3) sum otherwise: there the compiled term
    agrees with ``einsum`` to rounding, not to the last bit."""
    terms = np.random.default_rng(0).normal(size=(1000, 6)) * 10.0 ** np.random.default_rng(1).uniform(-4, 4, (1000, 6))
    squares = terms * terms
    even_odd = ((squares[:, 0] + squares[:, 2]) + squares[:, 4]) + ((squares[:, 1] + squares[:, 3]) + squares[:, 5])
    return bool(np.array_equal(np.einsum("...i,...i->...", terms, terms), even_odd))
