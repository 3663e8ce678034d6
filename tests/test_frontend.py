"""The acoustic front end against the geometry: [RD, RRD] from two synthesized channels, the SNR it measures,
its detector, the Cramer-Rao sd and the unwrapping of a whole episode."""

import numpy as np
import pytest

from aasl_gym import bandpass, frontend, geometry, kernels, synthesis
from aasl_gym.config import SignalConfig

FIXED = np.array([0.0, 0.0, -0.96])
C = 1500.0
ENVELOPE_RATE = SignalConfig().envelope_rate  # Hz, the shipped fast path's
MAX_DELAY = 45.0 / C


def scene(rng):
    """A random source and robot state near the pod (positions m, velocities m/s)."""
    source = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-30, -3)])
    mobile = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-15, -2)])
    return source, rng.normal(0, 0.7, 3), mobile, rng.normal(0, 0.8, 3)


def measure(
    waveform, source, source_velocity, mobile, mobile_velocity, baseband=True, noise_level_db=None, rng=None, guard=0.02
):
    """One 0.2 s frame (plus ``guard`` s each side, dropped after filtering) through the front end."""
    rate = ENVELOPE_RATE if baseband else 200_000.0
    paths = synthesis.path_sources(source, source_velocity, False, 60.0, -0.9, 0.3)
    channel = synthesis.synthesize(
        waveform,
        3.0,
        0.2 + 2 * guard,
        rate,
        baseband,
        paths,
        mobile,
        mobile_velocity,
        FIXED,
        C,
        140.0,
        noise_level_db,
        rng,
    )
    envelope = frontend.envelopes(channel, waveform, ENVELOPE_RATE, guard)
    return frontend.estimate(envelope, waveform, C, MAX_DELAY, noise_level_db=noise_level_db)


@pytest.mark.parametrize("kind", ["tone", "sweep", "hop"])
def test_noise_free_front_end_matches_the_geometry(kind, rng):
    """Fast path, no noise, no reflections, source and robot moving: [RD, RRD] against the geometry at
    the frame's centre.

    Tone: RD (modulo one wavelength) within 1 mm, RRD within 2 mm/s - its phase difference *is* the
    range difference. Sweep and hop: their delay is where two Doppler-scaled copies line up, which
    differs from RD / c by RD * rdot_f / c (about 1e-3 of RD here), so RD within 2e-3 |RD| + 2 mm; RRD
    within 1.5 cm/s for a sweep and 3 cm/s for a hop (over 300 random scenes the largest errors were
    1.0 and 2.5 cm/s, RMS 0.17 and 0.47 cm/s: a window that holds two hops dates its delay toward the
    higher-frequency one, so a hop's delay track is jittered in time by up to a quarter dwell)."""
    for _ in range(5):
        source, source_velocity, mobile, mobile_velocity = scene(rng)
        waveform = synthesis.Waveform.random(kind, rng)
        result = measure(waveform, source, source_velocity, mobile, mobile_velocity)
        rd = geometry.range_difference(source, mobile, FIXED)
        rrd = geometry.range_rate_difference(source, source_velocity, mobile, mobile_velocity, FIXED)
        if kind == "tone":
            assert abs(geometry.wrap_to_period(result.range_difference - rd, C / waveform.frequency)) < 1e-3
            assert result.range_rate_difference == pytest.approx(rrd, abs=2e-3)
        else:
            assert result.range_difference == pytest.approx(rd, abs=2e-3 * abs(rd) + 2e-3)
            assert result.range_rate_difference == pytest.approx(rrd, abs=1.5e-2 if kind == "sweep" else 3e-2)
        assert result.coherence > 0.99


def test_fdoa_sign_follows_the_spec(rng):
    """A robot running away from the source hears a lower tone: FDOA = f_fixed - f_mobile = (f0/c) RRD > 0.

    The two received frequencies are read off the synthesized channels themselves (mean phase
    increment), independently of the estimator, and the estimator's RRD has the same sign and size."""
    source, source_velocity = np.array([5.0, 0.0, -10.0]), np.zeros(3)
    mobile = np.array([20.0, 0.0, -10.0])
    mobile_velocity = np.array([1.5, 0.0, 0.0])  # straight away from the source
    waveform = synthesis.Waveform.random("tone", rng)
    paths = synthesis.path_sources(source, source_velocity, False, 60.0, -0.9, 0.3)
    channel = synthesis.synthesize(
        waveform, 3.0, 0.2, ENVELOPE_RATE, True, paths, mobile, mobile_velocity, FIXED, C, 140.0, None, None
    )

    def frequency(envelope):
        return waveform.frequency + np.angle(np.vdot(envelope[:-1], envelope[1:])) * channel.rate / (2 * np.pi)

    fdoa = frequency(channel.fixed) - frequency(channel.mobile)
    rrd = geometry.range_rate_difference(source, source_velocity, mobile, mobile_velocity, FIXED)
    assert rrd > 0
    assert fdoa == pytest.approx(geometry.fdoa_from_rrd(rrd, waveform.frequency, C), rel=1e-3)
    assert measure(waveform, source, source_velocity, mobile, mobile_velocity).range_rate_difference == pytest.approx(
        rrd, abs=2e-3
    )


@pytest.mark.parametrize("kind,rd_tolerance,rrd_tolerance", [("tone", 2e-3, 5e-3), ("sweep", 2e-2, 2e-2)])
def test_hardware_rate_and_baseband_paths_agree(kind, rd_tolerance, rrd_tolerance, rng):
    """The 200 kHz real path (band-pass, Hilbert, mix down) and the baseband path give one answer, noise
    free: a tone within 2 mm in RD and 5 mm/s in RRD, a sweep within 2 cm and 2 cm/s."""
    for _ in range(3):
        source, source_velocity, mobile, mobile_velocity = scene(rng)
        waveform = synthesis.Waveform.random(kind, rng)
        fast = measure(waveform, source, source_velocity, mobile, mobile_velocity, baseband=True)
        hardware = measure(waveform, source, source_velocity, mobile, mobile_velocity, baseband=False)
        assert hardware.range_difference == pytest.approx(fast.range_difference, abs=rd_tolerance)
        assert hardware.range_rate_difference == pytest.approx(fast.range_rate_difference, abs=rrd_tolerance)


@pytest.mark.parametrize("kind", ["tone", "hop"])
def test_filtered_noise_matches_its_closed_form_on_both_paths(kind, rng):
    """Noise alone through either path's band-pass: the envelope's power is 2 N B_n / B (B_n the
    integral of |H|^4, :func:`~aasl_gym.bandpass.noise_bandwidth`) and its one-sample correlation is
    :func:`~aasl_gym.frontend.noise_lag_product`, within 4 % over 4 s of samples. The envelope's
    mirror band (negative frequencies) must not let noise through."""
    waveform = synthesis.Waveform.random(kind, rng)
    level, band = 80.0, waveform.band
    for baseband, rate in ((True, ENVELOPE_RATE), (False, 200_000.0)):
        channel = synthesis.synthesize(
            waveform, 0.0, 4.0, rate, baseband, [], FIXED + 10, np.zeros(3), FIXED, C, 140.0, level, rng
        )
        noise = frontend.envelopes(channel, waveform, ENVELOPE_RATE, 0.02).fixed
        power = 2 * 10 ** (level / 10) * bandpass.noise_bandwidth(band) / (band[1] - band[0])
        assert np.mean(np.abs(noise) ** 2) == pytest.approx(power, rel=0.04)
        lag_product = frontend.noise_lag_product(level, band, waveform.carrier, ENVELOPE_RATE)
        assert abs(np.vdot(noise[:-1], noise[1:]) / (len(noise) - 1) - lag_product) < 0.04 * abs(lag_product)


def test_range_difference_noise_follows_the_cramer_rao_bound(rng):
    """A tone's RD spread against the Cramer-Rao bound of a phase difference:
    var(RD) >= (lambda / 2 pi)^2 (1/SNR_m + 1/SNR_f) / (2 B T), B the receiver band, T the frame.

    Above the estimator's threshold (in-band SNR 8 and 18 dB here) the spread sits within 0.8-1.3 x
    the bound and falls 10 dB per 10 dB of SNR (slope within 20 %)."""
    source, mobile = np.array([8.0, -6, -12]), np.array([14.0, 4, -8])
    waveform = synthesis.Waveform.random("tone", rng)
    wavelength, band, frame = C / waveform.frequency, 200.0, 0.2
    rd = geometry.range_difference(source, mobile, FIXED)
    spreads, bounds = [], []
    for noise_level in (110.0, 100.0):
        errors = [
            geometry.wrap_to_period(
                measure(
                    waveform, source, np.zeros(3), mobile, np.zeros(3), noise_level_db=noise_level, rng=rng
                ).range_difference
                - rd,
                wavelength,
            )
            for _ in range(200)
        ]
        snr = [
            10 ** ((140.0 - 20 * np.log10(np.linalg.norm(source - receiver)) - noise_level) / 10)
            for receiver in (mobile, FIXED)
        ]
        spreads.append(np.std(errors))
        bounds.append(wavelength / (2 * np.pi) * np.sqrt((1 / snr[0] + 1 / snr[1]) / (2 * band * frame)))
    for spread, bound in zip(spreads, bounds):
        assert 0.8 < spread / bound < 1.3
    slope = 20 * np.log10(spreads[0] / spreads[1]) / 10.0  # dB of spread per dB of SNR
    assert slope == pytest.approx(1.0, rel=0.2)


def test_with_reflections_the_tone_front_end_measures_the_phasor_model(rng):
    """Surface and bed paths on (D = 60 m, a_surf = -0.9, a_bed = 0.3), no noise: the front end's [RD, RRD]
    equals the exact phasor model's apparent RD (modulo one wavelength) over the frame - its mean and its
    least-squares slope, the model evaluated along the frame's straight-line motion, since near an
    interference fringe the apparent RD curves within 0.2 s - within 1 mm and 5 mm/s, while the
    direct-path geometry is often decimetres away."""
    largest_multipath_effect = 0.0
    for _ in range(6):
        source, source_velocity, mobile, mobile_velocity = scene(rng)
        waveform = synthesis.Waveform.random("tone", rng)
        paths = synthesis.path_sources(source, source_velocity, True, 60.0, -0.9, 0.3)
        channel = synthesis.synthesize(
            waveform, 3.0, 0.24, ENVELOPE_RATE, True, paths, mobile, mobile_velocity, FIXED, C, 140.0, None, None
        )
        result = frontend.estimate(frontend.envelopes(channel, waveform, ENVELOPE_RATE, 0.02), waveform, C, MAX_DELAY)
        wavenumber, wavelength = 2 * np.pi * waveform.frequency / C, C / waveform.frequency
        offsets = np.linspace(-0.1, 0.1, 201)[:, None]
        model_rd, _ = geometry.phasor_multipath(
            source + source_velocity * offsets,
            source_velocity,
            mobile + mobile_velocity * offsets,
            mobile_velocity,
            FIXED,
            60.0,
            -0.9,
            0.3,
            wavenumber,
        )
        slope, mean = np.polyfit(offsets[:, 0], model_rd, 1)
        assert abs(geometry.wrap_to_period(result.range_difference - mean, wavelength)) < 1e-3
        assert result.range_rate_difference == pytest.approx(slope, abs=5e-3)
        direct = geometry.range_difference(source, mobile, FIXED)
        largest_multipath_effect = max(
            largest_multipath_effect, abs(geometry.wrap_to_period(mean - direct, wavelength))
        )
    assert largest_multipath_effect > 0.05  # a front end that ignored the images would fail the checks above


def test_a_whole_episode_unwraps_without_a_slip(rng):
    """120 s of frames (5 Hz) while the robot circles the pod at 1 m/s and the source cruises: the
    front end's wrapped RD, unwrapped against the previous value, stays the true RD plus one fixed
    whole number of wavelengths (default noise level, SNR about 30 dB); RD moves by many wavelengths."""
    waveform = synthesis.Waveform.random("tone", rng)
    wavelength = C / waveform.frequency
    unwrapper = frontend.Unwrapper(wavelength)
    source, source_velocity = np.array([10.0, -5.0, -12.0]), np.array([0.4, 0.3, 0.0])
    offsets, truths = [], []
    for time in np.arange(0.0, 120.0, 0.2):
        angle = time / 15.0
        mobile = np.array([15 * np.cos(angle), 15 * np.sin(angle), -7 - 5 * np.sin(2 * np.pi * time / 30)])
        mobile_velocity = np.array([-np.sin(angle), np.cos(angle), -5 * 2 * np.pi / 30 * np.cos(2 * np.pi * time / 30)])
        position = source + source_velocity * time
        result = measure(waveform, position, source_velocity, mobile, mobile_velocity, noise_level_db=80.0, rng=rng)
        truth = geometry.range_difference(position, mobile, FIXED)
        offsets.append((unwrapper(result.range_difference) - truth) / wavelength)
        truths.append(truth)
    offsets = np.array(offsets)
    assert np.ptp(truths) > 10 * wavelength
    assert np.all(np.abs(offsets - np.round(offsets)) < 0.05)  # within 7.5 cm of a whole period
    assert np.all(np.round(offsets) == np.round(offsets[0]))  # and always the same one: no slip


def test_tone_measurement_sd_matches_the_spread_of_the_estimates(rng):
    """The RD and RRD sd the filter is told (the Cramer-Rao values from the frame's SNRs) against the
    spread of 300 noisy frames at an in-band SNR near 15 dB: within 0.8-1.3x each."""
    source, mobile = np.array([8.0, -6, -12]), np.array([14.0, 4, -8])
    waveform = synthesis.Waveform.random("tone", rng)
    wavelength, noise_level = C / waveform.frequency, 104.0
    rd = geometry.range_difference(source, mobile, FIXED)
    results = [
        measure(waveform, source, np.zeros(3), mobile, np.zeros(3), noise_level_db=noise_level, rng=rng)
        for _ in range(300)
    ]
    rd_errors = [geometry.wrap_to_period(r.range_difference - rd, wavelength) for r in results]
    rrd_errors = [r.range_rate_difference for r in results]
    snr = [
        10 ** ((140.0 - 20 * np.log10(np.linalg.norm(source - receiver)) - noise_level) / 10)
        for receiver in (mobile, FIXED)
    ]
    sd_rd, sd_rrd = frontend.tone_measurement_sd(snr[0], snr[1], wavelength, 200.0, 0.2)
    assert 0.8 < np.std(rd_errors) / sd_rd < 1.3
    assert 0.8 < np.std(rrd_errors) / sd_rrd < 1.3


@pytest.mark.parametrize("path", ["fast", "hardware"])
def test_front_end_measures_the_snr_model(path, rng):
    """Each channel's SNR measured from its band power (the noise level known) is the SNR model's,
    source level - 20 log10(range) - noise level, within 1 dB from 15 to 40 dB."""
    source, mobile = np.array([8.0, -6, -12]), np.array([14.0, 4, -8])
    front_end = frontend.FrontEnd(path=path)
    for noise_level in (78.0, 100.0):
        front_end.noise_level_db = noise_level
        snrs = np.array(
            [front_end.measure(rng, 1.0, source, np.zeros(3), mobile, np.zeros(3), FIXED)[1] for _ in range(10)]
        )
        model = [140.0 - 20 * np.log10(np.linalg.norm(source - receiver)) - noise_level for receiver in (mobile, FIXED)]
        np.testing.assert_allclose(10 * np.log10(snrs.mean(axis=0)), model, atol=1.0)


@pytest.mark.parametrize("kind", ["sweep", "hop"])
def test_wideband_spread_is_covered_by_the_filter_noise_model(kind, rng):
    """Sweep and hop frames get the tone formula at the carrier's wavelength over their whole band
    (their delay comes from the correlation phase just as a tone's; the flat spectrum's RMS frequency
    is only 4 % above the carrier). Against 200 noisy frames at in-band SNRs near 12 and 22 dB the
    spread of RD and RRD lies within 0.8-1.4x that sd, so ``signal.sd_inflation`` (1.5) covers it."""
    source, mobile = np.array([8.0, -6, -12]), np.array([14.0, 4, -8])
    waveform = synthesis.Waveform.random(kind, rng)
    rd = geometry.range_difference(source, mobile, FIXED)
    for noise_level in (104.0, 94.0):
        results = [
            measure(waveform, source, np.zeros(3), mobile, np.zeros(3), noise_level_db=noise_level, rng=rng)
            for _ in range(200)
        ]
        snr = [
            10 ** ((140.0 - 20 * np.log10(np.linalg.norm(source - receiver)) - noise_level) / 10)
            for receiver in (mobile, FIXED)
        ]
        sd_rd, sd_rrd = frontend.tone_measurement_sd(
            snr[0], snr[1], C / waveform.carrier, waveform.band[1] - waveform.band[0], 0.2
        )
        assert 0.8 < np.std([r.range_difference - rd for r in results]) / sd_rd < 1.4
        assert 0.8 < np.std([r.range_rate_difference for r in results]) / sd_rrd < 1.4


def test_a_delay_longer_than_a_window_is_measured(rng):
    """A robot 38 m out and a source by the pod: a sweep's delay (about 23 ms) exceeds a 20 ms window,
    so the frame's first window has no aligned samples and is dropped; RD and RRD still match the
    geometry within the noise-free bounds above."""
    source, source_velocity = np.array([1.0, 0.5, -5.0]), np.array([0.3, 0.0, 0.0])
    mobile, mobile_velocity = np.array([38.0, 0.0, -5.0]), np.array([0.0, 1.0, 0.0])
    waveform = synthesis.Waveform.random("sweep", rng)
    result = measure(waveform, source, source_velocity, mobile, mobile_velocity)
    rd = geometry.range_difference(source, mobile, FIXED)
    assert rd > 0.02 * C
    assert result.range_difference == pytest.approx(rd, abs=2e-3 * abs(rd) + 2e-3)
    rrd = geometry.range_rate_difference(source, source_velocity, mobile, mobile_velocity, FIXED)
    assert result.range_rate_difference == pytest.approx(rrd, abs=1.5e-2)


def test_the_detector_hears_a_weak_tone_but_not_a_silent_or_clipped_channel(rng):
    """The front end's CFAR detector: noise alone is exponential per periodogram bin, so its in-band
    peak passes 13 dB (20x the mean per bin) in about (bins) x e^-20 of frames - none of 200 silent
    frames here; a tone at about 0 dB band SNR gathers the band's ~40 bins' worth of power into one
    (+16 dB) and is heard in every frame; a clipped channel (many samples at full scale) never is."""
    source, mobile = np.array([8.0, -6, -12]), np.array([14.0, 4, -8])
    front_end = frontend.FrontEnd()
    measure = lambda fault=None: front_end.measure(rng, 1.0, source, np.zeros(3), mobile, np.zeros(3), FIXED, fault)  # noqa: E731
    silent = synthesis.FrameFault("silent", (True, False))
    assert not any(measure(silent)[2] for _ in range(200))
    clipped = synthesis.FrameFault("clipped", (False, True), clip_level=0.5)
    assert not any(measure(clipped)[2] for _ in range(20))
    assert all(measure()[2] for _ in range(20))
    front_end.noise_level_db = 140.0 - 20 * np.log10(np.linalg.norm(source - FIXED))  # 0 dB at the fixed one
    weak = [measure() for _ in range(50)]
    assert np.all(np.mean([snr for _, snr, _ in weak], axis=0) < 1.5)  # below ~2 dB in the band, as measured
    assert all(heard for _, _, heard in weak)


def test_saturation_is_detected_on_both_paths(rng):
    """An unclipped noisy tone reaches its largest magnitude once; clipped at any level up to 0.9 of its
    RMS amplitude, more than 1 % of its samples sit there (real, and complex parts apart)."""
    times = np.arange(2000) / 10_000
    for samples in (
        np.cos(2 * np.pi * 1000 * times) + rng.normal(0, 0.3, 2000),
        np.exp(2j * np.pi * 3 * times) + rng.normal(0, 0.3, 2000) + 1j * rng.normal(0, 0.3, 2000),
    ):
        assert not frontend.saturated(samples)
        for level in (0.1, 0.5, 0.9):
            assert frontend.saturated(synthesis.clipped(samples, level))
            # Channels stacked: one clipped channel is enough, whichever row it is.
            assert frontend.saturated(np.array([samples, synthesis.clipped(samples, level)]))
            assert frontend.saturated(np.array([synthesis.clipped(samples, level), samples]))
        assert not frontend.saturated(np.array([samples, samples[::-1]]))


def test_the_detection_statistic_is_numpys_formula(rng):
    """The compiled statistic (:func:`aasl_gym.kernels.peak_over_median`) against its NumPy form - the padded
    periodogram's in-band peak over the in-band median over ln 2 - over odd and even bin counts (a median of two
    middle values), one bin, and stacked channels."""
    for width in (0.0, 1.0, 99.0, 100.0):  # band half-widths (Hz): 1, 3, 161 and 161 bins of the 3,200-point FFT
        samples = rng.normal(size=(2, 3, 800)) + 1j * rng.normal(size=(2, 3, 800))
        samples[0, 1] += 3 * np.exp(2j * np.pi * 17.3 * np.arange(800) / 4000)  # a tone in one channel
        spectrum = np.fft.fft(samples, 3200, axis=-1)
        bins = np.flatnonzero(np.abs(np.fft.fftfreq(3200, 1 / 4000)) <= width + 1e-9)
        power = np.abs(spectrum[..., bins]) ** 2
        expected = power.max(axis=-1) / (np.median(power, axis=-1) / np.log(2))
        statistic = frontend.detection_statistic(samples, (-width, width), 4000.0)
        np.testing.assert_allclose(statistic, expected, rtol=1e-14)
    odd, even = np.array([[1.0, 4.0, 2.0]]), np.array([[1.0, 4.0, 2.0, 3.0]])
    np.testing.assert_allclose(kernels.peak_over_median(np.sqrt(odd + 0j), np.arange(3)), [4 / (2 / np.log(2))])
    np.testing.assert_allclose(kernels.peak_over_median(np.sqrt(even + 0j), np.arange(4)), [4 / (2.5 / np.log(2))])


def _detector_frames(rng, count: int = 60) -> list[np.ndarray]:
    """Envelope pairs (2, 800) at 4 kHz about a 1 kHz tone: tones of random level, Doppler (up to 12 Hz, beyond the
    bound's bins) and a second path of random delay and gain, in complex noise within the +-100 Hz band (as the
    envelopes carry it) or white; some noise alone."""
    times = np.arange(800) / 4000
    outside = np.abs(np.fft.fftfreq(800, 1 / 4000)) > 100.0
    frames = []
    for i in range(count):
        pair = (rng.normal(size=(2, 800)) + 1j * rng.normal(size=(2, 800))) * 0.3
        if i % 2:
            spectrum = np.fft.fft(pair)
            spectrum[:, outside] = 0.0
            pair = np.fft.ifft(spectrum)
        if i % 6:  # one frame in six is noise alone
            for row in pair:
                shift, level = rng.uniform(-12, 12), 10 ** rng.uniform(-1.5, 0.5)
                second = rng.uniform(-1, 1) * np.exp(2j * np.pi * rng.uniform())
                row += level * (1 + second) * np.exp(2j * np.pi * (shift * times + rng.uniform()))
        frames.append(pair)
    return frames


def test_the_detectors_lower_bound_never_exceeds_the_statistic(rng):
    """:func:`frontend.detection_lower_bound` (a few bins about the carrier and Parseval) against the padded FFT's
    statistic itself: never above it, over tones inside and beyond the bound's bins, faded ones and noise alone; and
    a clean tone's bound clears the 13 dB threshold, so the FFT is skipped where a source is heard well."""
    band = (-100.0, 100.0)
    for frame in _detector_frames(rng):
        bound = frontend.detection_lower_bound(frame, band, 4000.0)
        statistic = frontend.detection_statistic(frame, band, 4000.0)
        assert np.all(bound <= statistic * (1 + 1e-12)), (bound, statistic)
    tone = np.exp(2j * np.pi * 1.3 * np.arange(800) / 4000) + 0.05 * rng.normal(size=(2, 800))
    assert np.all(frontend.detection_lower_bound(tone, band, 4000.0) > 10**1.3)
    # A band too narrow for the bound's bins (fewer above the median than it takes): no bound.
    assert np.all(frontend.detection_lower_bound(tone, (-5.0, 5.0), 4000.0) == 0)


def test_tone_detected_is_the_statistic_against_its_threshold(rng, monkeypatch):
    """The detector's decision with the bound's short cut equals the statistic's against the threshold, frame by
    frame, at thresholds about the frames' own statistics (where the short cut must not decide); and the short cut
    does skip the FFT for a tone heard well."""
    band = (-100.0, 100.0)
    for frame in _detector_frames(rng, 30):
        statistic = frontend.detection_statistic(frame, band, 4000.0)
        for threshold in (*statistic, *(statistic * 1.001), *(statistic * 0.999), 20.0):
            expected = bool(np.all(statistic >= threshold))
            assert frontend.tone_detected(frame, band, 4000.0, threshold) == expected
    tone = np.exp(2j * np.pi * 1.3 * np.arange(800) / 4000) + 0.05 * rng.normal(size=(2, 800))
    monkeypatch.setattr(frontend, "detection_statistic", lambda *args: pytest.fail("the FFT was taken"))
    assert frontend.tone_detected(tone, band, 4000.0, 20.0)


def test_the_detectors_lower_bound_is_its_formula(rng):
    """:func:`frontend.detection_lower_bound` against its formula in NumPy: with P the 3,200-point periodogram, B the
    band's bins and C the 13 bins within 6 of the carrier's, max_C P ln 2 (|B| // 2 - |C|) / (3200 sum |x|^2 - sum_C
    P); and the compiled sums' table is exp(-2 pi i k n / 3200) at those bins."""
    samples = rng.normal(size=(3, 800)) + 1j * rng.normal(size=(3, 800))
    samples[1] += 4 * np.exp(2j * np.pi * 2.1 * np.arange(800) / 4000)
    near = np.arange(-6, 7)
    table = frontend._near_table(800, 3200, 4000.0, (-100.0, 100.0), 4)
    np.testing.assert_allclose(table[0] + 1j * table[1], np.exp(-2j * np.pi * np.outer(near, np.arange(800)) / 3200))
    band = np.flatnonzero(np.abs(np.fft.fftfreq(3200, 1 / 4000)) <= 100.0)
    power = np.abs(np.fft.fft(samples, 3200)[:, near % 3200]) ** 2
    rest = 3200 * np.sum(np.abs(samples) ** 2, axis=1) - power.sum(axis=1)
    expected = power.max(axis=1) * np.log(2) * (len(band) // 2 - len(near)) / rest
    bound = frontend.detection_lower_bound(samples, (-100.0, 100.0), 4000.0)
    np.testing.assert_allclose(bound, expected, rtol=1e-12)


def test_further_pairs_share_the_robots_recording(rng):
    """Further pairs pair each fixed channel with the robot's channel of the same frame: with every
    channel at the same SNR, two pairs' RD errors e_m - e_a and e_m - e_b share e_m, so their correlation
    is 1/2 (it would be 0 if each pair drew the robot's noise afresh), and the main pair's is 1/2 with each;
    likewise their RRD errors (all still: the true RRD is 0)."""
    source = np.array([0.0, 0.0, -30.0])
    receivers = source + 25.0 * np.array([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]])
    mobile, fixed, others = receivers[0], receivers[1], receivers[2:]
    truth = [geometry.range_difference(source, mobile, r) for r in (fixed, *others)]
    front_end = frontend.FrontEnd(noise_level_db=100.0)  # about 12 dB at 25 m: errors well above rounding
    front_end.reset(rng)
    rd_errors, rrd_errors = [], []
    for _ in range(300):
        main = front_end.measure(rng, 1.0, source, np.zeros(3), mobile, np.zeros(3), fixed)[0]
        results = [main] + [result for result, _, _ in front_end.measure_pairs(rng, source, np.zeros(3), others)]
        rd_errors.append([result.range_difference for result in results] - np.array(truth))
        rrd_errors.append([result.range_rate_difference for result in results])
    for errors in (rd_errors, rrd_errors):
        correlation = np.corrcoef(np.array(errors).T)
        assert np.all(np.abs(correlation[np.triu_indices(3, 1)] - 0.5) < 0.12)


def test_compiled_tone_estimate_is_the_numpy_stages(rng):
    """A tone frame's estimate (:func:`aasl_gym.kernels.tone_estimate`, one compiled pass) against the NumPy stages
    it replaces, :func:`frontend.delay_track` and :func:`frontend.tdoa_fdoa` at lag 0 (a second implementation): noisy
    frames with reflections, robot and source moving fast, so that some delay tracks slip across whole periods, to
    rounding. A frame too short for any window of two samples takes the NumPy stages (NaN)."""
    slipped = 0
    for noise_level_db in (None, 80.0, 100.0):
        for _ in range(4):
            source, source_velocity, mobile, mobile_velocity = scene(rng)
            waveform = synthesis.Waveform.random("tone", rng)
            paths = synthesis.path_sources(source, 3 * source_velocity, True, 60.0, -0.9, 0.3)
            channel = synthesis.synthesize(
                waveform, 3.0, 0.24, ENVELOPE_RATE, True, paths, mobile, 3 * mobile_velocity, FIXED, C, 140.0,
                noise_level_db, rng,
            )  # fmt: skip
            envelope = frontend.envelopes(channel, waveform, ENVELOPE_RATE, 0.02)
            compiled = frontend.estimate(envelope, waveform, C, MAX_DELAY, noise_level_db=noise_level_db)
            track = frontend.delay_track(envelope, waveform, MAX_DELAY, noise_level_db=noise_level_db)
            stages = frontend.tdoa_fdoa(track, C)
            slipped += bool(np.any(np.abs(track.delays) > 0.5 / waveform.frequency))  # unwrapped past a period
            assert compiled.range_difference == pytest.approx(stages.range_difference, rel=1e-12, abs=1e-12)
            assert compiled.range_rate_difference == pytest.approx(stages.range_rate_difference, rel=1e-9, abs=1e-12)
            assert compiled.coherence == pytest.approx(stages.coherence, rel=1e-12)
    assert slipped  # the unwrapping was exercised
    first = slice(0, 3)
    short = frontend.Channel(
        envelope.times[first], envelope.mobile[first], envelope.fixed[first], envelope.rate, envelope.carrier
    )
    with np.errstate(invalid="ignore", divide="ignore"):  # no window left: NaN, as the NumPy stages give it
        assert np.isnan(frontend.estimate(short, waveform, C, MAX_DELAY, windows=10).range_difference)
