"""Synthesis of one frame of both hydrophone channels (SPEC section 3, step 1): the source waveforms, the
paths the sound takes, the pressure each receiver hears, ambient noise and injected faults.

Each receiver hears every path k (direct; surface and bed images when reflections are on) as
``g_k / r_k(t) * s(t - r_k(t) / c)``, with s the emitted waveform and r_k(t) the *time-varying* range
over the frame (source and receiver move on straight lines through their positions at the frame's
centre), so the Doppler shift comes from the geometry itself. ``r_k(t)`` is the instantaneous
source-receiver distance (the quasi-static approximation the SPEC's RD and RRD are defined with).
Everything is first computed as the *analytic* signal ``sum_k g_k / r_k exp(j Phi(t - r_k / c))``
(Phi the waveform's phase); the hardware-rate path takes its real part at ``fs`` (200 kHz), the fast
path its complex envelope ``exp(-j 2 pi f_c t)`` times it, synthesized directly at a low rate.

Amplitudes. ``source_level_db`` is the RMS pressure at 1 m (dB re 1 uPa) and ``noise_level_db`` the
noise power in the receiver band (dB re 1 uPa^2), so a receiver at range r sees
SNR = source_level - 20 log10(r) - noise_level (dB) after its band-pass filter. The noise is white;
the fast path draws it in the frequency domain, only in the bins the band-pass
(:mod:`aasl_gym.bandpass`) lets through. Frames are synthesized with a guard at each end that the
front end drops after filtering (a receiver records continuously, so the guard stands for the
neighbouring frames). What the receivers make of the channels is :mod:`aasl_gym.frontend`'s.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
from scipy import fft

from aasl_gym import geometry, kernels
from aasl_gym.bandpass import band_gain

WAVEFORM_KINDS = ("tone", "sweep", "hop")


def receiver_band(
    kind: str, frequency: float = 1000.0, low: float = 500.0, high: float = 1500.0
) -> tuple[float, float]:
    """Hz, the receiver's band for a waveform: +-10 % about a tone's f0, else the sweep's or hops' range."""
    return (0.9 * frequency, 1.1 * frequency) if kind == "tone" else (low, high)


def carrier_frequency(kind: str, frequency: float = 1000.0, low: float = 500.0, high: float = 1500.0) -> float:
    """Hz, the frequency the complex envelopes are taken about: f0 for a tone, else the band's centre."""
    return frequency if kind == "tone" else 0.5 * (low + high)


@dataclass(frozen=True)
class Waveform:
    """What the source emits: its phase Phi(t) (rad) and instantaneous frequency (Hz) at emission time t (s).

    ``tone``: f0. ``sweep``: a linear sweep from ``low`` to ``high`` Hz, repeated every ``sweep_period`` s.
    ``hop``: a phase-continuous tone hopping every ``hop_dwell`` s through ``hops`` (Hz, repeated).
    ``phase`` is the random phase drawn per episode. A delay is unambiguous only if the waveform does
    not repeat within twice the largest delay (the sweep's period) and a frame holds many hops.
    """

    kind: str = "tone"
    frequency: float = 1000.0  # Hz, f0 of the tone; the carrier f_c of the others is the band centre
    low: float = 500.0  # Hz
    high: float = 1500.0  # Hz
    sweep_period: float = 0.2  # s
    hop_dwell: float = 0.01  # s
    hops: tuple[float, ...] = ()  # Hz, the hop sequence
    phase: float = 0.0  # rad

    def __post_init__(self) -> None:
        if self.kind not in WAVEFORM_KINDS:
            raise ValueError(f"waveform {self.kind!r} is not one of {list(WAVEFORM_KINDS)}")
        if self.kind == "hop" and not self.hops:
            raise ValueError("a hop waveform needs its hop sequence (hops)")

    @classmethod
    def random(
        cls,
        kind: str,
        rng: np.random.Generator,
        frequency: float = 1000.0,
        low: float = 500.0,
        high: float = 1500.0,
        sweep_period: float = 0.2,
        hop_dwell: float = 0.01,
        hop_count: int = 256,
    ) -> Waveform:
        """A waveform with a random phase (and, for ``hop``, a random sequence of ``hop_count`` frequencies)."""
        hops = tuple(rng.uniform(low, high, hop_count)) if kind == "hop" else ()
        return cls(kind, frequency, low, high, sweep_period, hop_dwell, hops, float(rng.uniform(0.0, 2 * np.pi)))

    @property
    def period(self) -> float:
        """s, the sweep's repetition or the hop's dwell."""
        return self.sweep_period if self.kind == "sweep" else self.hop_dwell

    @property
    def carrier(self) -> float:
        """Hz, the frequency the complex envelope is taken about."""
        return carrier_frequency(self.kind, self.frequency, self.low, self.high)

    @property
    def band(self) -> tuple[float, float]:
        """Hz, the receiver band (tone: +-10 % about f0)."""
        return receiver_band(self.kind, self.frequency, self.low, self.high)

    def phase_at(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if self.kind == "tone":
            return self.phase + 2 * np.pi * self.frequency * t
        cycle, within = np.divmod(t, self.period)
        if self.kind == "sweep":
            rate = (self.high - self.low) / self.period  # Hz/s
            per_cycle = self.low * self.period + 0.5 * rate * self.period**2  # cycles of phase per sweep
            return self.phase + 2 * np.pi * (cycle * per_cycle + self.low * within + 0.5 * rate * within**2)
        hops = np.asarray(self.hops)
        # Phase-continuous: the cycles accumulated over every earlier dwell, then the current one's.
        accumulated = np.concatenate([[0.0], np.cumsum(hops * self.period)])
        slot = cycle.astype(np.int64)
        repeats, index = np.divmod(slot, len(hops))
        return self.phase + 2 * np.pi * (repeats * accumulated[-1] + accumulated[index] + hops[index] * within)

    def frequency_at(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if self.kind == "tone":
            return np.full(t.shape, self.frequency)
        cycle, within = np.divmod(t, self.period)
        if self.kind == "sweep":
            return self.low + (self.high - self.low) / self.period * within
        return np.asarray(self.hops)[cycle.astype(np.int64) % len(self.hops)]


@dataclass(frozen=True)
class Channel:
    """One frame as synthesized: sample times (s) and the two channels (mobile, fixed)."""

    times: np.ndarray  # (N,)
    mobile: np.ndarray  # (N,) real or complex
    fixed: np.ndarray  # (N,)
    rate: float  # Hz, sample rate
    carrier: float  # Hz, 0 for real signals, else the envelope's reference frequency


@dataclass(frozen=True)
class FrameFault:
    """A corrupted frame (:class:`~aasl_gym.config.FaultConfig`): ``kind`` silent (the hydrophone hears ambient
    noise only) or clipped (its samples saturate at ``clip_level`` times their RMS amplitude), on the
    channels where ``channels`` (mobile, fixed) is True."""

    kind: str
    channels: tuple[bool, bool]
    clip_level: float = 0.1


def clipped(samples: np.ndarray, level: float) -> np.ndarray:
    """Samples saturated at ``level`` times their RMS amplitude; a complex envelope's real and
    imaginary parts saturate apart, each at ``level`` times its own share of the power."""
    if np.iscomplexobj(samples):
        return clipped(samples.real, level) + 1j * clipped(samples.imag, level)
    limit = level * np.sqrt(np.mean(samples**2))
    return np.clip(samples, -limit, limit)


def frame_times(centre: float, duration: float, rate: float) -> np.ndarray:
    """Sample times (s) of a frame of ``duration`` s centred on ``centre``."""
    return centre + _frame_offsets(int(round(duration * rate)), rate)


@functools.lru_cache(maxsize=16)
def _frame_offsets(count: int, rate: float) -> np.ndarray:
    """Times (s) of a frame's ``count`` samples at ``rate`` Hz from its centre (read-only): every frame of a run
    shares them."""
    offsets = (np.arange(count) - 0.5 * (count - 1)) / rate
    offsets.setflags(write=False)
    return offsets


def path_sources(
    source: np.ndarray,
    source_velocity: np.ndarray,
    reflections: bool,
    water_depth: float,
    surface_reflection: float,
    bed_reflection: float,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(position, velocity, gain) of every path's (image) source: the direct path, then surface and bed."""
    paths = [(np.asarray(source, float), np.asarray(source_velocity, float), 1.0)]
    if reflections:
        (surface, surface_v), (bed, bed_v) = geometry.image_sources(
            np.asarray(source, float), np.asarray(source_velocity, float), water_depth
        )
        paths += [(surface, surface_v, surface_reflection), (bed, bed_v, bed_reflection)]
    return paths


def received_pressure(
    waveform: Waveform,
    times: np.ndarray,
    centre: float,
    paths,
    receivers: np.ndarray,
    receiver_velocities: np.ndarray,
    sound_speed: float,
    amplitude: float,
    analytic: bool,
    carrier: float = 0.0,
) -> np.ndarray:
    """Pressure sum_k amplitude g_k / r_k(t) exp(j Phi(t - r_k(t)/c)) at each receiver, shape (R, N)
    for receivers (R, 3): complex with ``analytic`` (times exp(-j 2 pi carrier t), the complex envelope,
    for a nonzero ``carrier`` in Hz), else its real part (cosines).

    Positions move linearly through their values at ``centre``; ``amplitude`` is the peak pressure at 1 m.
    """
    offset = times - centre
    receivers, receiver_velocities = np.atleast_2d(receivers), np.atleast_2d(receiver_velocities)
    mixer_phase = 2 * np.pi * carrier * times
    if analytic and waveform.kind == "tone":
        envelope = _tone_envelope(
            waveform, times, offset, paths, receivers, receiver_velocities, sound_speed, amplitude, mixer_phase
        )
        if envelope is not None:
            return envelope
    total = np.zeros((len(receivers), len(times)), dtype=complex if analytic else float)
    for position, velocity, gain in paths:
        relative, relative_velocity = position - receivers, velocity - receiver_velocities  # (R, 3)
        distance = np.sqrt(sum((relative[:, i, None] + relative_velocity[:, i, None] * offset) ** 2 for i in range(3)))
        phase = waveform.phase_at(times - distance / sound_speed)
        pressure = gain * amplitude / distance
        # sin and cos compiled (:func:`aasl_gym.kernels.sincos`): numpy's were most of a frame's cost.
        if analytic:
            sine, cosine = kernels.sincos(phase - mixer_phase)
            total.real += pressure * cosine
            total.imag += pressure * sine
        else:
            total += pressure * kernels.sincos(phase)[1]
    return total


def _tone_envelope(
    waveform: Waveform, times, offset, paths, receivers, receiver_velocities, sound_speed, amplitude, mixer_phase
) -> np.ndarray | None:
    """:func:`received_pressure`'s complex envelope of a tone, compiled (:func:`aasl_gym.kernels.tone_envelope`, the
    same to the last bit): None where its angles are beyond the polynomial sine's range."""
    positions, velocities = (np.array([path[part] for path in paths], dtype=float).reshape(-1, 1, 3) for part in (0, 1))
    relative, relative_velocity = positions - receivers, velocities - receiver_velocities  # (P, R, 3)
    scales = np.array([gain * amplitude for _, _, gain in paths], dtype=float)
    tone = (waveform.phase, 2 * np.pi * waveform.frequency, sound_speed)
    return kernels.tone_envelope(relative, relative_velocity, scales, offset, times, mixer_phase, tone)


def noise_sd(noise_level_db: float, band: tuple[float, float], rate: float, complex_samples: bool = False) -> float:
    """Per-sample sd of white noise at ``rate`` Hz whose power inside ``band`` is ``noise_level_db`` (re 1 uPa^2).

    Real samples spread their power over rate / 2 Hz. A complex envelope spreads it over ``rate`` Hz and
    carries twice the real signal's power, so each of its real and imaginary parts takes sqrt(2) times more.
    """
    bandwidth = band[1] - band[0]
    sd = float(np.sqrt(10 ** (noise_level_db / 10) * (0.5 * rate) / bandwidth))
    return sd * np.sqrt(2.0) if complex_samples else sd


def peak_amplitude(source_level_db: float) -> float:
    """Peak pressure at 1 m (uPa) of a sinusoid whose RMS is ``source_level_db`` dB re 1 uPa."""
    return float(np.sqrt(2.0) * 10 ** (source_level_db / 20))


def synthesize(
    waveform: Waveform,
    centre: float,
    duration: float,
    rate: float,
    baseband: bool,
    paths,
    mobile,
    mobile_velocity,
    fixed,
    sound_speed: float,
    source_level_db: float,
    noise_level_db: float | None,
    rng: np.random.Generator | None,
    fault: FrameFault | None = None,
) -> Channel:
    """Both channels of one frame: real at ``rate`` Hz (the hardware path) or, with ``baseband``, the
    complex envelope about the waveform's carrier at ``rate`` Hz (the fast path). ``noise_level_db``
    None gives noise-free channels; ``fault`` corrupts some of them."""
    corrupted = np.asarray(fault.channels if fault else (False, False))
    times, channels = receiver_channels(
        waveform,
        centre,
        duration,
        rate,
        baseband,
        paths,
        np.array([mobile, fixed], dtype=float),
        np.array([mobile_velocity, np.zeros(3)], dtype=float),
        sound_speed,
        source_level_db,
        noise_level_db,
        rng,
        silent=corrupted if fault and fault.kind == "silent" else None,
    )
    if fault and fault.kind == "clipped":
        for row in np.flatnonzero(corrupted):
            channels[row] = clipped(channels[row], fault.clip_level)
    return Channel(times, channels[0], channels[1], rate, waveform.carrier if baseband else 0.0)


def receiver_channels(
    waveform: Waveform,
    centre: float,
    duration: float,
    rate: float,
    baseband: bool,
    paths,
    receivers: np.ndarray,
    velocities: np.ndarray,
    sound_speed: float,
    source_level_db: float,
    noise_level_db: float | None,
    rng: np.random.Generator | None,
    silent: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The sample times (N,; s) and channels (R, N) of one frame at ``receivers`` (R, 3; m) moving at
    ``velocities`` (R, 3; m/s), as :func:`synthesize` makes them, each with noise of its own; a ``silent``
    channel (R,; bool) carries the noise alone."""
    times = frame_times(centre, duration, rate)
    carrier = waveform.carrier if baseband else 0.0
    amplitude = peak_amplitude(source_level_db)
    channels = received_pressure(
        waveform, times, centre, paths, receivers, velocities, sound_speed, amplitude, baseband, carrier
    )
    if silent is not None:
        channels[silent] = 0.0
    if noise_level_db is not None:
        assert rng is not None, "noise needs an rng"
        sd = noise_sd(noise_level_db, waveform.band, rate, complex_samples=baseband)
        if baseband:
            # White noise's DFT bins are independent complex Gaussians: draw only the bins the band-pass
            # lets through (power gain above 1e-12; the rest it would remove anyway).
            runs = _noise_runs(len(times), rate, carrier, waveform.band)
            drawn = runs[-1][1].stop if runs else 0  # how many bins
            draws = rng.normal(0.0, sd * np.sqrt(len(times)), (2, len(channels), drawn))  # (re / im, channel, bin)
            spectrum = np.zeros(channels.shape, dtype=complex)
            for into, taken in runs:
                spectrum.real[:, into], spectrum.imag[:, into] = draws[:, :, taken]
            channels += fft.ifft(spectrum, axis=-1, overwrite_x=True)  # SciPy's: NumPy's, its plan cached
        else:
            channels += rng.normal(0.0, sd, channels.shape)
    return times, channels


@functools.lru_cache(maxsize=16)
def _noise_bins(count: int, rate: float, carrier: float, band: tuple[float, float]) -> np.ndarray:
    """FFT bins of a ``count``-sample envelope at ``rate`` Hz about ``carrier`` where the band-pass's
    power gain exceeds 1e-12 (read-only)."""
    frequencies = np.fft.fftfreq(count, 1 / rate) + carrier
    bins = np.flatnonzero((frequencies > 0) & (band_gain(frequencies, band) ** 2 > 1e-12))
    bins.setflags(write=False)
    return bins


@functools.lru_cache(maxsize=16)
def _noise_runs(count: int, rate: float, carrier: float, band: tuple[float, float]) -> tuple[tuple[slice, slice], ...]:
    """:func:`_noise_bins` as runs of consecutive bins (the band's positive and negative offsets: one run or two in FFT
    order), each a slice of the spectrum and the slice of the draws that fill it in order: slices place the draws in
    half the time an index array does."""
    bins = _noise_bins(count, rate, carrier, band)
    if not len(bins):
        return ()
    edges = np.r_[0, np.flatnonzero(np.diff(bins) != 1) + 1, len(bins)]
    return tuple(
        (slice(int(bins[first]), int(bins[last - 1]) + 1), slice(int(first), int(last)))
        for first, last in itertools.pairwise(edges)
    )
