"""The acoustic front end's processing (SPEC section 3, steps 2-5): [RD, RRD] and the SNRs from the two
channels of one frame (synthesized by :mod:`aasl_gym.synthesis`), and the whole-period unwrapping of a
tone's RD track.

Filtering. Both paths apply the same 4th-order zero-phase Butterworth band-pass
(:func:`aasl_gym.bandpass.band_gain`, applied in the frequency domain); the hardware path's one real
FFT per channel also yields the analytic signal, mixed down and decimated to the fast path's rate in
the same step. The guard synthesized at each end of a frame is dropped after filtering.

Estimation, on the complex envelopes. For a sweep or a hop, the peak of the cross-correlation
magnitude over the whole frame and the lags the geometry allows gives the coarse delay (whole
samples); a tone's envelope is flat, so its coarse delay is zero. The frame is then cut into short
windows; in each, the phase of the normalized cross-correlation at that lag refines the delay to a
fraction of the carrier period. The delay track's mean is the TDOA (RD = c TDOA) and its time slope
- the slope of the cross-channel phase - the FDOA (RRD = c d(TDOA)/dt). For a tone only the phase
carries the delay, so it is known modulo one period; the caller's :class:`Unwrapper` resolves that
against the previous frame. A tone's windows, delays, mean and slope run in one compiled pass
(:func:`aasl_gym.kernels.tone_estimate`; :func:`delay_track` and :func:`tdoa_fdoa` are its NumPy stages, which the
sweep and the hop take). A sweep's or hop's delay is where two Doppler-scaled copies line up,
which differs from RD / c by RD * rdot_f / c (about 1e-3 of RD); a tone's phase difference *is* the
range difference.

Detection. A frame carries the source only if neither channel is clipped (:func:`saturated`) and,
for a tone, each channel's CFAR statistic (:func:`detection_statistic`) reaches its threshold.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
from scipy import fft, integrate, signal

from aasl_gym import geometry, kernels
from aasl_gym.bandpass import band_gain, noise_bandwidth
from aasl_gym.synthesis import Channel, FrameFault, Waveform, path_sources, receiver_channels, synthesize


def saturated(samples: np.ndarray, share: float = 0.01) -> bool:
    """Whether more than ``share`` of the samples of any channel (..., N) sit at their largest magnitude (a
    clipped channel: an unclipped one reaches it once); a complex envelope's real and imaginary parts are
    tested apart."""
    samples = np.asarray(samples)
    return bool((kernels.peak_counts(samples) > share * samples.shape[-1]).any())


def detection_statistic(samples: np.ndarray, band: tuple[float, float], rate: float, padding: int = 4) -> np.ndarray:
    """A tone channel's CFAR detection statistic (linear) for each channel (..., N) of ``samples``: the
    peak of its envelope's periodogram over the noise's power per bin, both within ``band`` (Hz, about
    the envelope's carrier).

    The noise per bin is the band's median divided by ln 2 (noise alone is exponential per bin), so the
    statistic needs no calibration. A tone gathers a frame's power into one bin (its Doppler shifts it),
    a processing gain of the band's bin count; ``padding`` (zero-padding) keeps a tone between two bins
    from losing up to 3.9 dB. Noise alone: median ~7 dB, above 12 dB in fewer than 1 frame in 300.
    """
    count = padding * np.shape(samples)[-1]
    # SciPy's transform is numpy's to the last bit here, and pads without a copy (a third faster).
    return kernels.peak_over_median(fft.fft(samples, count), _band_bins(count, rate, tuple(band)))


# Relative margin by which the lower bound must clear the threshold to settle a frame: the bound's own rounding and
# the statistic's (its FFT and median) are some 1e-12 of it, so no frame is settled otherwise than the statistic
# would settle it.
BOUND_MARGIN = 1e-6


def detection_lower_bound(samples: np.ndarray, band: tuple[float, float], rate: float, padding: int = 4) -> np.ndarray:
    """A lower bound of :func:`detection_statistic` (linear) for each channel (..., N) of ``samples``, from the
    periodogram's powers at the few bins C about the carrier and the channel's energy alone (7 us for two channels
    against the padded FFT's 40 on the development machine): zero where it bounds nothing.

    Let P_k be the padded periodogram and B the band's bins. The peak is at least max_C P_k. At least |B| // 2
    of the band's bins reach its median, and at most |C| of them lie in C, so the median is at most
    (sum_k P_k - sum_C P_k) / (|B| // 2 - |C|), where sum_k P_k over every bin is the padded length times
    sum_n |x_n|^2 (Parseval). C spans a tone's main lobe (``padding`` bins either side of its frequency) and
    two bins of Doppler (1.25 Hz each at 4 kHz: more than a 1 kHz tone's 3 m/s of closing speed moves it). A
    tone heard well clears the threshold by this bound; a faint or multipath-faded one, noise, or a tone
    beyond C does not, and takes the statistic itself (:func:`tone_detected`).
    """
    samples = np.asarray(samples)
    count = padding * samples.shape[-1]
    table = _near_table(samples.shape[-1], count, rate, tuple(band), padding)
    above = len(_band_bins(count, rate, tuple(band))) // 2 - table.shape[1]
    if above <= 0:
        return np.zeros(samples.shape[:-1])
    return kernels.peak_over_median_bound(samples, table, count, above)


def tone_detected(
    samples: np.ndarray, band: tuple[float, float], rate: float, threshold: float, padding: int = 4
) -> bool:
    """Whether every channel's :func:`detection_statistic` reaches ``threshold`` (linear). The statistic's padded
    FFT is taken only where :func:`detection_lower_bound` does not already clear the threshold (by
    ``BOUND_MARGIN``): the same answer, in most frames at a quarter of the cost (94 % of the default world's frames and
    all of the free field's, tuning seeds)."""
    if (detection_lower_bound(samples, band, rate, padding) >= threshold * (1 + BOUND_MARGIN)).all():
        return True
    return bool((detection_statistic(samples, band, rate, padding) >= threshold).all())


@functools.lru_cache(maxsize=16)
def _near_table(samples: int, count: int, rate: float, band: tuple[float, float], padding: int) -> np.ndarray:
    """cos and -sin of 2 pi k n / ``count`` (2, J, ``samples``) for the bins k within ``padding`` + 2 of the carrier's
    (zero) that lie within ``band`` (Hz): :func:`aasl_gym.kernels.peak_over_median_bound`'s table (read-only)."""
    near = np.arange(-(padding + 2), padding + 3)
    near = near[np.isin(near % count, _band_bins(count, rate, band))]
    angles = 2 * np.pi * np.outer(near, np.arange(samples)) / count
    table = np.stack([np.cos(angles), -np.sin(angles)])
    table.setflags(write=False)
    return table


@functools.lru_cache(maxsize=16)
def _band_bins(count: int, rate: float, band: tuple[float, float]) -> np.ndarray:
    """Indices of a ``count``-point FFT's bins at ``rate`` Hz within ``band`` (Hz), in FFT order (read-only):
    every frame of a run shares them."""
    offsets = np.fft.fftfreq(count, 1.0 / rate)
    bins = np.flatnonzero((offsets >= band[0]) & (offsets <= band[1]))
    bins.setflags(write=False)
    return bins


@functools.lru_cache(maxsize=64)
def _frame_gain(
    count: int, rate: float, carrier: float, band: tuple[float, float], analytic_bins: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """(bins, gain): the band gain on a frame's FFT grid, cached since every frame of a run shares it.

    For an envelope of ``count`` samples (``analytic_bins`` None) bins is empty and gain covers its FFT;
    for the real path, bins are the ``analytic_bins`` positive-frequency bins nearest the carrier's, in
    FFT order about it. The arrays are read-only.
    """
    if analytic_bins is None:
        # The band-pass of an analytic signal: its mirror band at negative frequencies holds only noise.
        frequencies = np.fft.fftfreq(count, 1 / rate) + carrier
        bins, gain = np.empty(0, dtype=int), band_gain(frequencies, band) * (frequencies > 0)
    else:
        resolution = rate / count
        centre = int(round(carrier / resolution))
        bins = centre + np.fft.fftfreq(analytic_bins, 1 / analytic_bins).astype(int)
        bins = bins[(bins > 0) & (bins <= count // 2)]
        gain = band_gain(bins * resolution, band)
    bins.setflags(write=False)
    gain.setflags(write=False)
    return bins, gain


def envelopes(channel: Channel, waveform: Waveform, envelope_rate: float, guard: float = 0.0) -> Channel:
    """Both channels as complex envelopes about the waveform's carrier, band-passed, with ``guard``
    seconds dropped at each end (where the filter wraps around; synthesize that much extra).

    Both paths apply the same zero-phase Butterworth band-pass (:func:`band_gain`) in the frequency
    domain. Real channels (the hardware path) go through one real FFT each: the band-passed positive
    frequencies, doubled, are the analytic signal; shifting the bins about the carrier down to zero and
    keeping those within +-``envelope_rate`` / 2 mixes down and decimates in the same inverse FFT.
    Complex envelopes (the fast path) are filtered at their own rate.
    """
    count = len(channel.times)
    channels = np.array([channel.mobile, channel.fixed])
    if channel.carrier:  # already an envelope about the carrier
        _, gain = _frame_gain(count, channel.rate, channel.carrier, waveform.band, None)
        # SciPy's transforms: NumPy's to the last bit, with their plans cached (NumPy builds one per call).
        filtered = fft.ifft(fft.fft(channels, axis=-1) * gain, axis=-1, overwrite_x=True)
        times, rate = channel.times, channel.rate
    else:
        kept = int(round(count * envelope_rate / channel.rate))  # bins of the decimated envelope
        rate = channel.rate * kept / count
        resolution = channel.rate / count  # Hz per bin
        centre = int(round(waveform.carrier / resolution))
        # The positive-frequency bins (the analytic signal) within +-rate/2 of the carrier's, FFT order.
        bins, gain = _frame_gain(count, channel.rate, waveform.carrier, waveform.band, kept)
        times = channel.times[0] + np.arange(kept) / rate
        # Shifting by the carrier's bin mixes with its frequency from the frame's first sample; the
        # remaining factor makes it exp(-j 2 pi f_c t) in absolute time, as the fast path's is.
        correction = np.exp(
            -2j * np.pi * (centre * resolution * channel.times[0] + (waveform.carrier - centre * resolution) * times)
        )
        spectrum = np.zeros((2, kept), dtype=complex)
        for row, samples in enumerate(channels):  # one long real FFT per channel (faster here than one over both rows)
            spectrum[row, (bins - centre) % kept] = 2 * fft.rfft(samples)[bins] * gain
        filtered = fft.ifft(spectrum, axis=-1, overwrite_x=True) * (kept / count) * correction
    keep = slice(int(round(guard * rate)), len(times) - int(round(guard * rate)))
    return Channel(times[keep], filtered[0][keep], filtered[1][keep], rate, waveform.carrier)


@dataclass(frozen=True)
class FrameEstimate:
    range_difference: float  # m, c * TDOA (a tone's modulo one wavelength)
    range_rate_difference: float  # m/s, c * d(TDOA)/dt = (c / f0) * FDOA
    coherence: float  # mean normalized cross-correlation magnitude at the chosen lags, in [0, 1]


def coarse_lag(envelope: Channel, max_lag: int) -> int:
    """Lag (samples) of the peak of |R(k)|, R(k) = sum_t m(t) conj(f(t - k)), over the whole frame and
    |k| <= max_lag: where the mobile channel best matches the fixed one. Needs a wideband waveform (a
    sweep or hop whose repetition is longer than twice ``max_lag``)."""
    count = len(envelope.times)
    max_lag = min(max_lag, (count - 1) // 3)
    inner = envelope.mobile[max_lag : count - max_lag]
    full = signal.correlate(envelope.fixed, inner, mode="valid", method="fft")  # n -> conj(R(max_lag - n))
    return int(max_lag - np.argmax(np.abs(full)))


@functools.lru_cache(maxsize=16)
def noise_lag_product(noise_level_db: float, band: tuple[float, float], carrier: float, rate: float) -> complex:
    """E[conj(n_t) n_(t+1)] of band-passed noise in a complex envelope about ``carrier`` at ``rate`` Hz
    (uPa^2): its autocorrelation at one sample, the integral of its spectrum 2 N / B |H(f)|^4 times
    exp(j 2 pi (f - f_c) / rate), N the noise level in the band B (an envelope carries twice the power)."""
    width = band[1] - band[0]
    frequencies = np.linspace(max(band[0] - 2 * width, 0.0), band[1] + 2 * width, 4001)
    density = 2 * 10 ** (noise_level_db / 10) / width * band_gain(frequencies, band) ** 2
    return complex(integrate.trapezoid(density * np.exp(2j * np.pi * (frequencies - carrier) / rate), frequencies))


def _window_delays(
    envelope: Channel, edges: np.ndarray, lag: int, tone: bool, noise_lag: complex = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per window [edges[i], edges[i+1]) of the mobile channel: its delay (s) behind the fixed one near
    ``lag`` samples, the normalized correlation there, and the time (s) the delay belongs to (the mean
    time of the mobile samples used: a large lag leaves fewer of them in the frame's first or last
    window, or none, and an empty window is dropped).

    The analytic signals' correlation at the lag has phase 2 pi f_mean (lag - delay), with f_mean the
    received mean frequency: the carrier for a tone (Doppler moves it by 1e-3 at most), else measured
    from the aligned fixed samples' mean phase increment. Band-limited noise adds its own increments,
    which lean toward the band's centre; ``noise_lag`` (:func:`noise_lag_product`) is their expected
    value per sample, taken off the sum. A tone does without the estimate.
    """
    count, rate = len(envelope.fixed), envelope.rate
    low, high = max(0, lag), min(count, count + lag)  # mobile samples whose t - lag lies inside the frame
    mobile, aligned = envelope.mobile[low:high], envelope.fixed[low - lag : high - lag]
    bounds = np.minimum(np.maximum(edges, low), high) - low  # np.clip's dispatch costs more than the frame's sums
    starts = _window_starts(bounds)
    lengths = np.empty_like(starts)  # np.diff(starts, append=high - low), without its dispatch
    lengths[:-1] = starts[1:] - starts[:-1]
    lengths[-1:] = high - low - starts[-1:]
    correlation = np.add.reduceat(np.conj(aligned) * mobile, starts)
    energy = np.sqrt(np.add.reduceat(np.abs(mobile) ** 2, starts) * np.add.reduceat(np.abs(aligned) ** 2, starts))
    mean_frequency: float | np.ndarray = envelope.carrier  # a sweep or hop measures one per window
    if not tone:
        products = np.conj(aligned[:-1]) * aligned[1:]
        products[starts[1:] - 1] = 0.0  # increments stay within their window
        increments = np.add.reduceat(products, starts) - (lengths - 1) * noise_lag
        mean_frequency += np.angle(increments) * rate / (2 * np.pi)
    if lag:  # (a tone's is zero: the factor would be one)
        correlation = correlation * np.exp(2j * np.pi * envelope.carrier * lag / rate)
    analytic_phase = np.angle(correlation)  # wrapped to (-pi, pi]
    delays = lag / rate - analytic_phase / (2 * np.pi * mean_frequency)
    centres = np.add.reduceat(envelope.times[low:high], starts) / lengths
    return delays, np.abs(correlation) / energy, centres


def _window_starts(bounds: np.ndarray) -> np.ndarray:
    """The first sample of each window [bounds[i], bounds[i+1]) of two samples or more: the windows a delay is
    measured in (a shorter one's samples join the window before it)."""
    return bounds[:-1][bounds[1:] > bounds[:-1] + 1]


@functools.lru_cache(maxsize=16)
def _window_edges(count: int, windows: int) -> np.ndarray:
    """The first sample of each of ``windows`` equal windows of ``count`` samples, then ``count`` (read-only): every
    frame of a run shares them."""
    edges = np.linspace(0, count, windows + 1).astype(int)
    edges.setflags(write=False)
    return edges


@dataclass(frozen=True)
class DelayTrack:
    """Per-window delays of one frame: what the correlation stage hands to the TDOA / FDOA stage."""

    delays: np.ndarray  # s, mobile behind fixed (a tone's continuous across windows, modulo one period overall)
    times: np.ndarray  # s, the time each delay belongs to
    coherences: np.ndarray  # normalized correlation magnitude per window


def delay_track(
    envelope: Channel, waveform: Waveform, max_delay: float, windows: int = 10, noise_level_db: float | None = None
) -> DelayTrack:
    """The correlation stage: coarse lag (sweep, hop) and each window's sub-sample delay.

    ``max_delay`` (s) bounds the coarse lag search (the baseline over c, plus margin). A known
    ``noise_level_db`` (dB re 1 uPa^2 in the band) debiases a sweep's or hop's mean frequency.
    """
    tone = waveform.kind == "tone"
    noise_lag = (
        0.0
        if noise_level_db is None
        else noise_lag_product(noise_level_db, waveform.band, waveform.carrier, envelope.rate)
    )
    lag = 0 if tone else coarse_lag(envelope, int(np.ceil(max_delay * envelope.rate)))
    delays, coherences, times = _window_delays(
        envelope, _window_edges(len(envelope.times), windows), lag, tone, noise_lag
    )
    if tone:  # each window's delay is known modulo one period: keep the track continuous across windows
        period = 1.0 / waveform.frequency
        delays = geometry.unwrap_to_period(delays, period)
    return DelayTrack(delays, times, coherences)


def tdoa_fdoa(track: DelayTrack, sound_speed: float) -> FrameEstimate:
    """The TDOA / FDOA stage: RD from the track's mean delay, RRD from its least-squares time slope."""
    # The means as ndarray.mean() takes them (the sum over the count), without its dispatch.
    count = len(track.times)
    offsets = track.times - np.add.reduce(track.times) / count
    slope = np.dot(offsets, track.delays) / np.dot(offsets, offsets)
    return FrameEstimate(
        float(sound_speed * (np.add.reduce(track.delays) / count)),
        float(sound_speed * slope),
        float(np.add.reduce(track.coherences) / count),
    )


def estimate(
    envelope: Channel,
    waveform: Waveform,
    sound_speed: float,
    max_delay: float,
    windows: int = 10,
    noise_level_db: float | None = None,
) -> FrameEstimate:
    """[RD, RRD] of one frame from the two channels' complex envelopes (see the module docstring and
    :func:`delay_track`). A tone's (lag 0) in one compiled pass, :func:`aasl_gym.kernels.tone_estimate`."""
    starts = _tone_starts(len(envelope.times), windows) if waveform.kind == "tone" else None
    if starts is None or not len(starts):  # a sweep or a hop, or a frame too short for a window
        return tdoa_fdoa(delay_track(envelope, waveform, max_delay, windows, noise_level_db), sound_speed)
    delay, slope, coherence = kernels.tone_estimate(
        envelope.mobile, envelope.fixed, envelope.times, starts, envelope.carrier, 1.0 / waveform.frequency
    )
    return FrameEstimate(sound_speed * delay, sound_speed * slope, coherence)


@functools.lru_cache(maxsize=16)
def _tone_starts(count: int, windows: int) -> np.ndarray:
    """The first sample of each of :func:`_window_edges`' windows of two samples or more, as :func:`_window_delays`
    keeps them at lag 0 (read-only)."""
    starts = _window_starts(_window_edges(count, windows))
    starts.setflags(write=False)
    return starts


def tone_measurement_sd(
    snr_mobile: float, snr_fixed: float, wavelength: float, bandwidth: float, duration: float
) -> tuple[float, float]:
    """Cramer-Rao sd of a tone frame's RD (m) and RRD (m/s) from the two channels' in-band SNRs (linear).

    A channel's phase over a frame of T seconds in a band of B Hz has Fisher information 2 SNR B T
    (rad^-2), its phase rate 2 SNR B T^3 / 12; RD and RRD are lambda / (2 pi) times the difference of
    the two channels' phase and phase rate.
    """
    inverse_snr = 1.0 / snr_mobile + 1.0 / snr_fixed
    scale = wavelength / (2 * np.pi)
    return (
        scale * np.sqrt(inverse_snr / (2 * bandwidth * duration)),
        scale * np.sqrt(6 * inverse_snr / (bandwidth * duration**3)),
    )


@dataclass
class FrontEnd:
    """One hydrophone pair's front end: synthesizes a frame and estimates [RD, RRD] and the SNRs from it.

    ``path`` is ``fast`` (complex baseband at ``envelope_rate``) or ``hardware`` (real at ``sample_rate``).
    The ambient noise level is taken as known (a receiver calibrates it); each channel's SNR is measured
    as its band power over that noise, so nothing from the true geometry leaks into it.
    """

    waveform_kind: str = "tone"
    frequency: float = 1000.0  # Hz
    path: str = "fast"
    frame: float = 0.2  # s
    guard: float = 0.02  # s synthesized at each end and dropped after filtering
    sample_rate: float = 200_000.0  # Hz, hardware path
    envelope_rate: float = 4_000.0  # Hz, fast path and the envelopes both paths estimate on
    windows: int = 10
    sound_speed: float = 1500.0  # m/s
    source_level_db: float = 140.0  # dB re 1 uPa at 1 m (RMS)
    noise_level_db: float = 80.0  # dB re 1 uPa^2 in the band
    reflections: bool = False
    water_depth: float = 60.0  # m
    surface_reflection: float = -0.9
    bed_reflection: float = 0.3
    max_delay: float = 0.03  # s, coarse lag search (baseline / c with margin)
    detection_snr_db: float = 13.0  # dB, the tone detector's threshold (:func:`detection_statistic`)
    waveform: Waveform | None = None
    channel: Channel | None = None  # the latest frame synthesized
    channel_time: float = 0.0  # s, its centre

    def reset(self, rng: np.random.Generator) -> None:
        """A new episode: a fresh random phase (and hop sequence)."""
        self.waveform = Waveform.random(self.waveform_kind, rng, frequency=self.frequency)
        self.channel = None

    def measure(
        self,
        rng: np.random.Generator,
        time: float,
        source,
        source_velocity,
        mobile,
        mobile_velocity,
        fixed,
        fault: FrameFault | None = None,
    ) -> tuple[FrameEstimate, np.ndarray, bool]:
        """The frame centred on ``time`` (s), corrupted by ``fault`` if given: its estimate, the two
        channels' measured SNRs (linear) and whether the source was heard in it (:meth:`heard`)."""
        if self.waveform is None:
            self.reset(rng)
        assert self.waveform is not None  # reset() drew it
        paths = path_sources(
            source, source_velocity, self.reflections, self.water_depth, self.surface_reflection, self.bed_reflection
        )
        baseband = self.path == "fast"
        rate = self.envelope_rate if baseband else self.sample_rate
        channel = synthesize(
            self.waveform,
            time,
            self.frame + 2 * self.guard,
            rate,
            baseband,
            paths,
            mobile,
            mobile_velocity,
            fixed,
            self.sound_speed,
            self.source_level_db,
            self.noise_level_db,
            rng,
            fault,
        )
        self.channel, self.channel_time = channel, time  # the latest frame, whose robot channel measure_pairs shares
        return self.process(channel)

    def process(self, channel: Channel) -> tuple[FrameEstimate, np.ndarray, bool]:
        """One synthesized frame's estimate, its channels' measured SNRs (linear) and whether the source
        was heard in it (:meth:`heard`)."""
        assert self.waveform is not None  # the frame was synthesized with it
        envelope = envelopes(channel, self.waveform, self.envelope_rate, self.guard)
        result = estimate(envelope, self.waveform, self.sound_speed, self.max_delay, self.windows, self.noise_level_db)
        return result, self.snr(envelope), self.heard(channel, envelope)

    def measure_pairs(
        self, rng: np.random.Generator, source, source_velocity, hydrophones: np.ndarray
    ) -> list[tuple[FrameEstimate, np.ndarray, bool]]:
        """The latest frame (:meth:`measure`'s, the source as it took it) at each further fixed hydrophone
        (K, 3; m), each paired with that frame's robot channel (one recording: its noise is every pair's),
        as :meth:`process` gives them."""
        if self.channel is None or self.waveform is None:
            raise RuntimeError("measure() must synthesize the robot's frame before measure_pairs()")
        mobile, time = self.channel, self.channel_time
        paths = path_sources(
            source, source_velocity, self.reflections, self.water_depth, self.surface_reflection, self.bed_reflection
        )
        _, channels = receiver_channels(
            self.waveform,
            time,
            self.frame + 2 * self.guard,
            mobile.rate,
            self.path == "fast",
            paths,
            np.asarray(hydrophones, dtype=float),
            np.zeros((len(hydrophones), 3)),
            self.sound_speed,
            self.source_level_db,
            self.noise_level_db,
            rng,
        )
        return [self.process(replace(mobile, fixed=fixed)) for fixed in channels]

    def heard(self, channel: Channel, envelope: Channel) -> bool:
        """Whether the frame carries the source on both channels: neither is clipped (:func:`saturated`:
        its phase is lost) and, for a tone, each one's :func:`detection_statistic` reaches
        ``detection_snr_db``. (A sweep or hop spreads over the band; only clipping is detected for them.)"""
        if saturated(np.array([channel.mobile, channel.fixed])):
            return False
        assert self.waveform is not None  # called on a frame measure() synthesized
        if self.waveform.kind != "tone":
            return True
        low, high = self.waveform.band
        band = (low - self.waveform.carrier, high - self.waveform.carrier)
        threshold = 10 ** (self.detection_snr_db / 10)
        return tone_detected(np.array([envelope.mobile, envelope.fixed]), band, envelope.rate, threshold)

    def snr(self, envelope: Channel) -> np.ndarray:
        """Each channel's in-band SNR (linear): band power above the known noise floor, over the noise level.

        An envelope's power is twice the real signal's; the filtered noise keeps the share of the band's
        power that the filter's gain passes (its noise bandwidth over the band).
        """
        assert self.waveform is not None  # called on a frame measure() synthesized
        band = self.waveform.band
        noise = 10 ** (self.noise_level_db / 10)
        filtered_noise = noise * noise_bandwidth(band) / (band[1] - band[0])
        power = np.array([0.5 * np.vdot(x, x).real / len(x) for x in (envelope.mobile, envelope.fixed)])
        return np.maximum(power - filtered_noise, 1e-3 * noise) / noise


class Unwrapper:
    """Whole-period unwrapping of a range-difference track (period = one wavelength, m)."""

    def __init__(self, period: float | None):
        self.period = period
        self.previous: float | None = None

    def reset(self) -> None:
        self.previous = None

    def __call__(self, range_difference: float) -> float:
        if self.period is None:
            return float(range_difference)
        wrapped = float(geometry.wrap_to_period(range_difference, self.period))
        if self.previous is None:
            value = wrapped
        else:
            value = wrapped + self.period * np.round((self.previous - wrapped) / self.period)
        self.previous = value
        return value
