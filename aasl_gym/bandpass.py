"""The receivers' band-pass filter (SPEC section 3, step 2): a 4th-order Butterworth about the source
band (SciPy's analog design), run forward and backward (zero phase), so each frequency's amplitude is
scaled by the design's power gain |H(f)|^2.

Both the front end (:mod:`aasl_gym.frontend`, which filters the channels) and the synthesis
(:mod:`aasl_gym.synthesis`, which draws the fast path's noise only where the filter lets it through)
use it.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import integrate, signal


@functools.lru_cache(maxsize=16)
def _butterworth(band: tuple[float, float], order: int) -> tuple[np.ndarray, np.ndarray]:
    return signal.butter(order, 2 * np.pi * np.asarray(band), btype="bandpass", analog=True)


def band_gain(frequencies: np.ndarray, band: tuple[float, float], order: int = 4) -> np.ndarray:
    """Power gain |H(f)|^2 of the ``order``-th order Butterworth band-pass (SciPy's analog design) at
    ``frequencies`` (Hz): what the filter run forward and backward (zero phase) does to each frequency."""
    numerator, denominator = _butterworth(tuple(band), order)
    _, response = signal.freqs(numerator, denominator, worN=2 * np.pi * np.abs(frequencies))
    return np.abs(response) ** 2


@functools.lru_cache(maxsize=16)
def noise_bandwidth(band: tuple[float, float], order: int = 4) -> float:
    """Hz, how much white noise the zero-phase band-pass lets through: the integral of the square of
    :func:`band_gain` (the forward-backward filter's amplitude response is |H|^2, its power response |H|^4)."""
    width = band[1] - band[0]
    frequencies = np.linspace(max(band[0] - 2 * width, 0.0), band[1] + 2 * width, 4001)
    return float(integrate.trapezoid(band_gain(frequencies, band, order) ** 2, frequencies))
