"""Synthesis of a frame: the source waveforms and the ambient noise level in the receiver band."""

import numpy as np
import pytest

from aasl_gym import synthesis
from aasl_gym.config import SignalConfig

FIXED = np.array([0.0, 0.0, -0.96])
ENVELOPE_RATE = SignalConfig().envelope_rate  # Hz, the shipped fast path's
C = 1500.0


@pytest.mark.parametrize("kind", ["tone", "sweep", "hop"])
def test_waveform_phase_is_continuous_and_its_rate_is_the_frequency(kind, rng):
    waveform = synthesis.Waveform.random(kind, rng)
    t = np.linspace(-1.0, 2.0, 300_001)  # spans several sweeps / hops, and negative emission times
    phase = waveform.phase_at(t)
    rate = np.diff(phase) / np.diff(t) / (2 * np.pi)
    midpoint = 0.5 * (t[1:] + t[:-1])
    # Continuous: no jump beyond one step's worth of the highest frequency.
    assert np.max(np.abs(np.diff(phase))) < 2 * np.pi * 1600 * (t[1] - t[0])
    away_from_switches = np.abs(np.diff(waveform.frequency_at(t))) == 0
    np.testing.assert_allclose(rate[away_from_switches], waveform.frequency_at(midpoint)[away_from_switches], atol=1e-3)


@pytest.mark.parametrize("kind", ["tone", "sweep", "hop"])
def test_the_noise_runs_are_the_noise_bins_in_order(kind, rng):
    """The envelope noise's bins placed as runs of slices: together, in order, exactly the bins the band-pass lets
    through, each run's draws the next ones in line (so the drawn spectrum is the one an index array places)."""
    waveform = synthesis.Waveform.random(kind, rng)
    for count in (960, 1000, 4001):
        bins = synthesis._noise_bins(count, ENVELOPE_RATE, waveform.carrier, waveform.band)
        runs = synthesis._noise_runs(count, ENVELOPE_RATE, waveform.carrier, waveform.band)
        placed = np.concatenate([np.arange(count)[into] for into, _ in runs])
        taken = np.concatenate([np.arange(len(bins))[draws] for _, draws in runs])
        np.testing.assert_array_equal(placed, bins)
        np.testing.assert_array_equal(taken, np.arange(len(bins)))
        assert all(into.stop - into.start == draws.stop - draws.start for into, draws in runs)


def test_noise_power_in_the_band_is_the_noise_level(rng):
    """White noise synthesized for a noise level of N dB has N dB of power inside the receiver band."""
    waveform = synthesis.Waveform.random("tone", rng)
    level = 80.0
    for baseband, rate in ((False, 200_000.0), (True, ENVELOPE_RATE)):
        silent = synthesis.synthesize(
            waveform, 0.0, 2.0, rate, baseband, [], FIXED + 10, np.zeros(3), FIXED, C, 140.0, level, rng
        )
        spectrum = np.abs(np.fft.fft(silent.mobile)) ** 2 / len(silent.times) ** 2
        frequencies = np.fft.fftfreq(len(silent.times), 1 / rate) + (waveform.carrier if baseband else 0.0)
        low, high = waveform.band
        magnitude = frequencies if baseband else np.abs(frequencies)  # a real signal's band shows on both sides
        in_band = spectrum[(magnitude >= low) & (magnitude <= high)].sum()
        power = in_band / 2 if baseband else in_band  # an envelope carries twice the real signal's power
        assert 10 * np.log10(power) == pytest.approx(level, abs=0.3)
