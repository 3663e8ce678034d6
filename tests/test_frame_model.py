"""The filter's frame-averaged measurement model against independent truths: a track that is linear in
time, and the noise-free tone front end with surface and bed reflections."""

from functools import partial

import numpy as np

from aasl_gym import frontend, geometry, synthesis
from aasl_gym.config import SignalConfig
from aasl_gym.measurement_models import (
    Propagation,
    frame_averaged,
    frame_offsets,
    multipath_measurement,
    phasor_range_difference,
)

FIXED = np.array([0.0, 0.0, -0.96])
ENVELOPE_RATE = SignalConfig().envelope_rate  # Hz, the shipped fast path's
C = 1500.0


def test_a_track_linear_in_time_averages_to_its_centre_and_its_rate(rng):
    """RD = the source's x coordinate moves linearly over the frame: its mean is the centre's value and its
    least-squares slope the x velocity, exactly, for any number of samples."""

    def x_coordinate(position, mobile, fixed):
        return position[..., 0] + 0 * mobile[..., 0]

    position, velocity = rng.normal(0, 10, (4, 3)), rng.normal(0, 1, (4, 3))
    for samples in (2, 3, 7):
        z = frame_averaged(
            x_coordinate, frame_offsets(0.2, samples), 4.2, position, velocity, np.zeros(3), np.ones(3), FIXED
        )
        np.testing.assert_allclose(z[:, 0], position[:, 0], atol=1e-12)
        np.testing.assert_allclose(z[:, 1], velocity[:, 0], atol=1e-12)


def test_frame_offsets_are_the_centres_of_equal_parts():
    np.testing.assert_allclose(frame_offsets(0.2, 4), [-0.075, -0.025, 0.025, 0.075])


def test_the_frame_model_is_what_the_tone_front_end_measures_with_reflections(rng):
    """Noise-free frames with surface and bed paths (D = 60 m, a = -0.9 / 0.3) at random scenes: the
    5-sample frame model follows the front end's RD within 5 mm and its RRD within a quarter of the
    phasor model's own worst miss at the frame's centre, which near an interference null is many sd."""
    centre_misses, frame_misses = [], []
    for _ in range(30):
        source = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-30, -3)])
        mobile = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-15, -2)])
        source_velocity, mobile_velocity = rng.normal(0, 0.7, 3), rng.normal(0, 0.8, 3)
        waveform = synthesis.Waveform.random("tone", rng)
        paths = synthesis.path_sources(source, source_velocity, True, 60.0, -0.9, 0.3)
        channel = synthesis.synthesize(
            waveform, 3.0, 0.24, ENVELOPE_RATE, True, paths, mobile, mobile_velocity, FIXED, C, 140.0, None, None
        )
        result = frontend.estimate(frontend.envelopes(channel, waveform, ENVELOPE_RATE, 0.02), waveform, C, 45.0 / C)
        measured = np.array([result.range_difference, result.range_rate_difference])
        wavenumber = 2 * np.pi * waveform.frequency / C
        propagation = Propagation(60.0, -0.9, 0.3, wavenumber)
        state = (source, source_velocity, mobile, mobile_velocity, FIXED)
        rd = partial(phasor_range_difference, propagation)
        for model, misses in (
            (multipath_measurement("phasor", propagation, *state), centre_misses),
            (frame_averaged(rd, frame_offsets(0.2, 5), wavenumber, *state), frame_misses),
        ):
            miss = measured - model
            miss[0] = geometry.wrap_to_period(miss[0], C / waveform.frequency)
            misses.append(np.abs(miss))
    centre_worst, frame_worst = np.max(centre_misses, axis=0), np.max(frame_misses, axis=0)
    assert frame_worst[0] < 5e-3
    assert frame_worst[1] < 0.25 * centre_worst[1]
    assert centre_worst[1] > 0.1  # the scenes come near a null: a centre model misses by many sd there
