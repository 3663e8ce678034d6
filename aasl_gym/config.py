"""Configuration: small frozen dataclasses, loaded from YAML and validated here, in one place.

Every field carries its unit in its name or in the comment beside it. A YAML file may set any subset of
the fields; the rest keep their defaults. Unknown keys, wrong types and out-of-range values raise
:class:`ConfigError` with the dotted path of the offending key and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aasl_gym.facility import loop_radius, pod_hydrophones
from aasl_gym.io import read_yaml
from aasl_gym.synthesis import receiver_band

SOURCE_MOTIONS = ("static", "cv", "ca", "ctrv", "uturn", "mixed")
MEASUREMENT_MODES = ("signal", "geometric")
SIGNAL_PATHS = ("fast", "hardware")
INITIALIZERS = ("lcmap", "naive", "random", "tdoa-ls")
MULTIPATH_MODELS = ("matched", "none", "linear", "phasor")
REFLECTION_MODELS = ("phasor", "linear")
FILTER_MODELS = ("cv", "ca", "ctrv")
PATROLS = ("helix", "spiral", "circle", "lawnmower", "square")
RECEIVER_KINDS = ("auv", "surface")
WAVEFORMS = ("tone", "sweep", "hop")
FAULT_KINDS = ("none", "silent", "clipped", "dropped")
FAULT_CHANNELS = ("mobile", "fixed", "both")


class ConfigError(ValueError):
    """A configuration value or key is not allowed; the message names it and what is allowed."""


def require(condition: bool, path: str, message: str) -> None:
    """Raise :class:`ConfigError` ``"{path}: {message}"`` unless ``condition``: every check of a config
    (and of the training schedule, :mod:`agents.training`) names its key this way."""
    if not condition:
        raise ConfigError(f"{path}: {message}")


def require_choice(value: str, allowed: tuple[str, ...], path: str) -> None:
    """``value`` is one of ``allowed``, or a :class:`ConfigError` at ``path`` lists them."""
    require(value in allowed, path, f"{value!r} is not one of {list(allowed)}")


def _positive(value: float, path: str) -> None:
    require(math.isfinite(value) and value > 0, path, f"must be a finite number > 0, got {value!r}")


def _non_negative(value: float, path: str) -> None:
    require(math.isfinite(value) and value >= 0, path, f"must be a finite number >= 0, got {value!r}")


def _check_finite(section: Any, name: str) -> None:
    """Every number of a config section (and of its lists) is finite: a NaN or an infinity would pass
    most range checks and surface far from its key."""
    for item in dataclasses.fields(section):
        value = getattr(section, item.name)
        values = value if isinstance(value, tuple) else (value,)
        for number in values:
            if isinstance(number, float):
                require(math.isfinite(number), f"{name}.{item.name}", f"must be finite, got {value!r}")


def _ordered_pair(pair: tuple[float, float], path: str, minimum: float = 0.0) -> None:
    require(len(pair) == 2, path, f"must be [low, high], got {list(pair)}")
    low, high = pair
    require(
        minimum <= low <= high and math.isfinite(high), path, f"must satisfy {minimum} <= low <= high, got {list(pair)}"
    )


@dataclass(frozen=True)
class WorldConfig:
    """The water column, the pod and the propagation."""

    sound_speed: float = 1500.0  # m/s
    water_depth: float = 60.0  # m; the bed is at z = -water_depth
    fixed_position: tuple[float, float, float] = (0.0, 0.0, -0.96)  # m, hydrophone on the pod
    region_radius: float = 40.0  # m, horizontal radius of the surveillance region around the origin
    reflections: bool = True  # simulate the surface and bed image paths
    surface_reflection: float = -0.9  # pressure-release surface: negative
    bed_reflection: float = 0.3
    # How reflections shape a geometric-mode RD: phasor, the tone's exact multipath sum (what a front end
    # measures); linear, the reference paper's first-order model RD + a_surf delta_surf + a_bed delta_bed.
    reflection_model: str = "phasor"
    noise_level_db: float = 80.0  # dB re 1 uPa, ambient noise in the receiver band

    def __post_init__(self) -> None:
        _positive(self.sound_speed, "world.sound_speed")
        _positive(self.water_depth, "world.water_depth")
        _positive(self.region_radius, "world.region_radius")
        require(len(self.fixed_position) == 3, "world.fixed_position", "must be [x, y, z] in metres")
        z = self.fixed_position[2]
        require(
            -self.water_depth < z < 0,
            "world.fixed_position",
            f"z = {z} m is outside the water column (-{self.water_depth}, 0)",
        )
        require(
            -1 <= self.surface_reflection <= 0,
            "world.surface_reflection",
            "must lie in [-1, 0] (pressure-release surface)",
        )
        require(0 <= self.bed_reflection <= 1, "world.bed_reflection", "must lie in [0, 1]")
        require_choice(self.reflection_model, REFLECTION_MODELS, "world.reflection_model")


@dataclass(frozen=True)
class SourceConfig:
    """The adversary's sound source: its tone and its (true) motion."""

    motion: str = "cv"  # static, cv, ca, ctrv, uturn, mixed (one of the first four, drawn per episode)
    frequency: float = 1000.0  # Hz, tone f0
    waveform: str = "tone"  # tone, sweep, hop (signal mode; geometric mode treats all as tone-ambiguous only for tone)
    initial_radius: float = 20.0  # m, initial position uniform in the ball of this radius about initial_centre
    initial_centre: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m; the origin: the surface above the pod
    speed_range: tuple[float, float] = (0.2, 1.5)  # m/s, cv / ca initial / ctrv speed
    max_speed: float = 1.5  # m/s, ca never exceeds it
    acceleration_range: tuple[float, float] = (0.002, 0.01)  # m/s^2, ca
    turn_rate_range: tuple[float, float] = (0.02, 0.1)  # rad/s, ctrv and uturn, sign drawn at random
    uturn_start_range: tuple[float, float] = (20.0, 60.0)  # s, uturn: straight this long before its half-turn
    depth: float | None = None  # m below the surface the source is held at (hung from a vessel); None: free
    # m: a moving source is redrawn until its path over the whole episode keeps this close to initial_centre
    # horizontally (the lake trial's paths within 15 m of the dock); None: any path
    keep_within: float | None = None
    max_vertical_speed: float = 0.1  # m/s
    boundary_margin: float = 2.0  # m, the source keeps this far from surface and bed (and region edge if confined)
    confined: bool = False  # reflect at the surveillance region's edge; by default a moving source may leave it
    range_rate_bias: float = 0.0  # m/s, true b_v (clock-rate offset between the two recorders)
    source_level_db: float = 140.0  # dB re 1 uPa at 1 m, in the receiver band

    def __post_init__(self) -> None:
        require_choice(self.motion, SOURCE_MOTIONS, "source.motion")
        require_choice(self.waveform, WAVEFORMS, "source.waveform")
        _positive(self.frequency, "source.frequency")
        _positive(self.initial_radius, "source.initial_radius")
        _ordered_pair(self.speed_range, "source.speed_range")
        _positive(self.max_speed, "source.max_speed")
        require(
            self.speed_range[1] <= self.max_speed,
            "source.speed_range",
            f"upper end must not exceed source.max_speed = {self.max_speed}",
        )
        _ordered_pair(self.acceleration_range, "source.acceleration_range")
        _ordered_pair(self.turn_rate_range, "source.turn_rate_range")
        _ordered_pair(self.uturn_start_range, "source.uturn_start_range")
        require(
            self.motion != "uturn" or self.turn_rate_range[0] > 0,
            "source.turn_rate_range",
            f"a uturn needs turn rates above 0 (its half-turn takes pi / rate), got {list(self.turn_rate_range)}",
        )
        if self.depth is not None:
            _positive(self.depth, "source.depth")
        if self.keep_within is not None:
            _positive(self.keep_within, "source.keep_within")
            require(
                self.keep_within > self.initial_radius,
                "source.keep_within",
                f"must exceed source.initial_radius = {self.initial_radius} m, or no moving source can start inside it",
            )
        _non_negative(self.max_vertical_speed, "source.max_vertical_speed")
        _non_negative(self.boundary_margin, "source.boundary_margin")
        require(math.isfinite(self.range_rate_bias), "source.range_rate_bias", "must be finite")
        require(isinstance(self.confined, bool), "source.confined", f"must be true or false, got {self.confined!r}")


@dataclass(frozen=True)
class ReceiverConfig:
    """The robot that carries the mobile hydrophone, and its navigation."""

    kind: str = "auv"  # auv, or surface (a surface vessel ignores the z command)
    max_speed: float = 1.5  # m/s, the action box [-1, 1] maps to this
    start_position: tuple[float, float, float] = (15.0, 0.0, -7.0)  # m
    keep_out_radius: float = 3.0  # m, sphere around the fixed hydrophone the robot never enters
    min_depth: float = 1.0  # m below the surface
    bed_clearance: float = 2.0  # m above the bed
    region_radius: float = 60.0  # m, horizontal distance from the origin the robot may go
    surface_depth: float = 1.0  # m, depth of a surface vessel's hydrophone
    nav_position_sd: float = 0.05  # m, sigma_rov: white error on the reported position
    nav_velocity_sd: float | None = None  # m/s; None means 0.4 * nav_position_sd
    nav_drift_sd: float = 0.0  # m/sqrt(s), random-walk drift of the reported position (0 = none)

    def __post_init__(self) -> None:
        require_choice(self.kind, RECEIVER_KINDS, "receiver.kind")
        _positive(self.max_speed, "receiver.max_speed")
        require(len(self.start_position) == 3, "receiver.start_position", "must be [x, y, z] in metres")
        _non_negative(self.keep_out_radius, "receiver.keep_out_radius")
        _non_negative(self.min_depth, "receiver.min_depth")
        _non_negative(self.bed_clearance, "receiver.bed_clearance")
        _positive(self.region_radius, "receiver.region_radius")
        _positive(self.surface_depth, "receiver.surface_depth")
        _non_negative(self.nav_position_sd, "receiver.nav_position_sd")
        if self.nav_velocity_sd is not None:
            _non_negative(self.nav_velocity_sd, "receiver.nav_velocity_sd")
        _non_negative(self.nav_drift_sd, "receiver.nav_drift_sd")

    @property
    def velocity_sd(self) -> float:
        """Reported-velocity error, m/s."""
        return 0.4 * self.nav_position_sd if self.nav_velocity_sd is None else self.nav_velocity_sd


@dataclass(frozen=True)
class MeasurementConfig:
    """How [RD, RRD] is produced each step."""

    mode: str = "signal"  # signal (the acoustic front end, see SignalConfig) or geometric (z = h(x) + noise)
    rate: float = 5.0  # Hz, one measurement per env step
    range_difference_sd: float = 0.05  # m, sigma_R (geometric mode; signal mode derives it from each frame's SNR)
    range_rate_difference_sd: float = 0.02  # m/s, sigma_V (geometric mode; likewise)

    def __post_init__(self) -> None:
        require_choice(self.mode, MEASUREMENT_MODES, "measurement.mode")
        _positive(self.rate, "measurement.rate")
        _positive(self.range_difference_sd, "measurement.range_difference_sd")
        _positive(self.range_rate_difference_sd, "measurement.range_rate_difference_sd")


@dataclass(frozen=True)
class SignalConfig:
    """The acoustic front end (measurement.mode = signal): synthesis and estimation of one frame per step."""

    path: str = "fast"  # fast (complex baseband) or hardware (real samples at sample_rate)
    frame_duration: float = 0.2  # s, centred on the step's time
    guard: float = 0.02  # s synthesized at each end of a frame and dropped after filtering
    sample_rate: float = 200_000.0  # Hz, hardware path
    # Hz, the fast path's rate and the rate both paths estimate at: the band (a tone's +-10 %, a sweep's 1 kHz) and
    # the filter's skirts fit with room. Noise-free frames measure as at 10 kHz: a tone's RD and RRD within 1e-3 mm
    # and mm/s; in the free field a sweep's or hop's within 1 mm and 20 mm/s (session 13)
    envelope_rate: float = 4_000.0
    windows: int = 10  # short windows per frame for the delay track (TDOA mean, FDOA slope)
    sd_inflation: float = 1.5  # the filter's R uses the Cramer-Rao sd from the frame's SNRs times this
    min_range_difference_sd: float = 0.002  # m, floor of the filter's RD sd
    min_range_rate_difference_sd: float = 0.005  # m/s, floor of the filter's RRD sd
    # dB: a tone frame is a measurement only if, on each channel, the peak of its periodogram exceeds
    # the noise per bin by this (a CFAR detector, frontend.detection_statistic; noise alone passed 0 of 3,000)
    detection_snr_db: float = 13.0

    def __post_init__(self) -> None:
        require_choice(self.path, SIGNAL_PATHS, "signal.path")
        require(
            math.isfinite(self.detection_snr_db),
            "signal.detection_snr_db",
            f"must be finite, got {self.detection_snr_db}",
        )
        for name in (
            "frame_duration",
            "sample_rate",
            "envelope_rate",
            "min_range_difference_sd",
            "min_range_rate_difference_sd",
        ):
            _positive(getattr(self, name), f"signal.{name}")
        _non_negative(self.guard, "signal.guard")
        require(
            isinstance(self.windows, int) and self.windows >= 2,
            "signal.windows",
            f"must be an integer >= 2, got {self.windows!r}",
        )
        require(self.sd_inflation >= 1, "signal.sd_inflation", "must be >= 1")
        require(
            self.envelope_rate <= self.sample_rate,
            "signal.envelope_rate",
            f"must not exceed signal.sample_rate = {self.sample_rate}",
        )


@dataclass(frozen=True)
class FaultConfig:
    """Corrupted frames injected into the sensor, to test recovery: one burst of ``duration`` s from ``start``.

    ``silent``: the ``channel``'s hydrophone carries ambient noise only (it dropped out); ``clipped``: its
    samples saturate at ``clip_level`` times the frame's RMS amplitude (real and imaginary parts apart);
    both need measurement.mode signal. ``dropped``: no frame arrives at all (either mode).
    """

    kind: str = "none"  # none, silent, clipped, dropped
    channel: str = "mobile"  # mobile, fixed or both (silent, clipped)
    start: float = 60.0  # s, time of the first corrupted frame
    duration: float = 5.0  # s
    clip_level: float = 0.1  # saturation, in units of the frame's RMS amplitude (clipped)

    def __post_init__(self) -> None:
        require_choice(self.kind, FAULT_KINDS, "fault.kind")
        require_choice(self.channel, FAULT_CHANNELS, "fault.channel")
        _non_negative(self.start, "fault.start")
        _non_negative(self.duration, "fault.duration")
        _positive(self.clip_level, "fault.clip_level")

    def active(self, time: float) -> bool:
        """Whether the frame at ``time`` (s) is corrupted."""
        return self.kind != "none" and self.start <= time < self.start + self.duration

    @property
    def channels(self) -> tuple[bool, bool]:
        """Which channels (mobile, fixed) the fault corrupts."""
        return self.channel in ("mobile", "both"), self.channel in ("fixed", "both")


@dataclass(frozen=True)
class FilterConfig:
    """The UKF: motion model, process noise, measurement model, sigma points, divergence handling."""

    motion_model: str = "cv"  # cv, ca, ctrv
    # The filter's RD model: matched (phasor with reflections, else none), none, linear, phasor.
    multipath: str = "matched"
    acceleration_psd: float = 1e-5  # m^2/s^3, white-acceleration spectral density (cv, ctrv)
    jerk_psd: float = 1e-6  # m^2/s^5, white-jerk spectral density (ca)
    turn_rate_psd: float = 1e-6  # rad^2/s^3 (ctrv)
    range_bias_psd: float = 1e-6  # m^2/s, random walk of b_p
    rate_bias_psd: float = 1e-6  # m^2/s^3, random walk of b_v
    compensate_navigation: bool = True  # use R_eff = R_ac + diag(sigma_rov^2, sigma_rov_v^2)
    alpha: float = 0.5
    beta: float = 2.0
    kappa: float = 0.0
    divergence_window: float = 5.0  # s, window of the moving-average NIS
    divergence_nis: float = 8.0  # mean NIS over the window above this (2 expected) = inconsistent: search again
    reinit_window: float = 10.0  # s of recent measurements a recovery or re-start searches
    reinit_cooldown: float = 5.0  # s after a (re)start or re-seed before consistency is tested again
    prune_log_ratio: float = 12.0  # a hypothesis whose log-likelihood trails the best's by this is dropped
    ripple_lock_sd: float = 0.25  # m: phasor model only; above this position sd the ripple is treated as noise
    ripple_split_sd: float = 0.6  # m: a hypothesis this certain picks its point on the ripple from a lattice
    ripple_window: float = 10.0  # s of recent measurements that lattice is weighed on
    recovery_inflation: float = 4.0  # an inconsistent filter re-seeds with its covariance times this
    window_fit: bool = True  # re-seeds refine their best hypotheses by a sliding-window MAP (aasl_gym.window)
    # s: after the growing window, test the neighbouring whole-period sheets (0: never)
    sheet_check_interval: float = 10.0
    # each sheet check fits the likeliest filter's whole track since its start and the filter adopts the fit
    track_fit: bool = True
    # phasor model, with track_fit: where that fit explains the track poorly, search about the filter (aasl_gym.search)
    track_search: bool = True
    frame_samples: int = 3  # signal mode, phasor model: times per frame the model is averaged over (1: the centre)
    # m/s, ca only: the top speed at which a constant acceleration stops, as the world's CA sources do;
    # matched: the world's source.max_speed; null: none
    speed_limit: float | str | None = "matched"

    def __post_init__(self) -> None:
        require_choice(self.motion_model, FILTER_MODELS, "filter.motion_model")
        require_choice(self.multipath, MULTIPATH_MODELS, "filter.multipath")
        for name in ("acceleration_psd", "jerk_psd", "turn_rate_psd", "range_bias_psd", "rate_bias_psd"):
            _non_negative(getattr(self, name), f"filter.{name}")
        require(0 < self.alpha <= 1, "filter.alpha", f"must lie in (0, 1], got {self.alpha}")
        _non_negative(self.beta, "filter.beta")
        require(math.isfinite(self.kappa), "filter.kappa", "must be finite")
        _positive(self.divergence_window, "filter.divergence_window")
        _positive(self.divergence_nis, "filter.divergence_nis")
        _positive(self.reinit_window, "filter.reinit_window")
        _non_negative(self.reinit_cooldown, "filter.reinit_cooldown")
        _positive(self.prune_log_ratio, "filter.prune_log_ratio")
        _positive(self.ripple_lock_sd, "filter.ripple_lock_sd")
        _positive(self.ripple_split_sd, "filter.ripple_split_sd")
        _positive(self.ripple_window, "filter.ripple_window")
        require(
            isinstance(self.window_fit, bool), "filter.window_fit", f"must be true or false, got {self.window_fit!r}"
        )
        _non_negative(self.sheet_check_interval, "filter.sheet_check_interval")
        for name in ("track_fit", "track_search"):
            value = getattr(self, name)
            require(isinstance(value, bool), f"filter.{name}", f"must be true or false, got {value!r}")
        require(
            isinstance(self.frame_samples, int) and self.frame_samples >= 1,
            "filter.frame_samples",
            f"must be an integer >= 1, got {self.frame_samples!r}",
        )
        require(
            self.recovery_inflation >= 1, "filter.recovery_inflation", f"must be >= 1, got {self.recovery_inflation}"
        )
        limit = self.speed_limit
        require(
            limit is None
            or limit == "matched"
            or (isinstance(limit, (int, float)) and not isinstance(limit, bool) and math.isfinite(limit) and limit > 0),
            "filter.speed_limit",
            f"must be 'matched', a finite speed > 0 (m/s) or null, got {limit!r}",
        )


@dataclass(frozen=True)
class InitializerConfig:
    """How the filter is started from an early burst of measurements."""

    name: str = "lcmap"  # lcmap, naive, random, tdoa-ls
    burst_duration: float = 2.0  # s of measurements before the filter starts
    candidate_directions: int = 200  # lcmap / random: directions on the locus per whole-period offset
    information_weight: float = 1.0  # lambda in J - lambda * log det F (1 = Jeffreys prior)
    velocity_prior_sd: float = 1.0  # m/s, MAP prior on the source velocity
    max_source_speed: float = 2.0  # m/s, plausibility bound
    position_sd: float = 15.0  # m, prior / non-lcmap initial position spread
    range_bias_sd: float = 0.05  # m, initial sd of b_p once the whole-period offset is chosen
    rate_bias_sd: float = 0.02  # m/s, initial sd of b_v
    covariance_inflation: float = 1.0  # lcmap's local-information covariance is multiplied by this
    hypotheses: int = 12  # lcmap: distinct candidates (best of each sheet first) that each start a UKF; 1 = one filter
    reseed_interval: float = 5.0  # s; after an lcmap start, lcmap re-runs on the growing window this often (0 = never)
    reseed_until: float = 60.0  # s, longest such window; no scheduled re-seed after it
    # A scheduled re-seed runs LC-MAP afresh only if no running filter explains its window: a window cost
    # above this quantile of its chi-square distribution (0 = LC-MAP at every re-seed).
    reseed_search_quantile: float = 0.99
    max_turn_rate: float = 0.12  # rad/s; lcmap with a ctrv filter fits turns on a grid over +- this
    turn_rate_steps: int = 9  # values in that grid (odd keeps 0, the straight line)
    acceleration_prior_sd: float = 0.01  # m/s^2; lcmap with a ca filter fits the acceleration under this prior
    search_spacing: float = 2.5  # m; phasor filter: the lattice of the phasor search from the prior (0 = none)

    def __post_init__(self) -> None:
        require_choice(self.name, INITIALIZERS, "initializer.name")
        _positive(self.burst_duration, "initializer.burst_duration")
        require(self.candidate_directions >= 8, "initializer.candidate_directions", "must be >= 8")
        require(math.isfinite(self.information_weight), "initializer.information_weight", "must be finite")
        _non_negative(self.reseed_interval, "initializer.reseed_interval")
        _non_negative(self.reseed_until, "initializer.reseed_until")
        require(
            0 <= self.reseed_search_quantile < 1,
            "initializer.reseed_search_quantile",
            f"must be in [0, 1), got {self.reseed_search_quantile!r}",
        )
        require(
            isinstance(self.hypotheses, int) and self.hypotheses >= 1,
            "initializer.hypotheses",
            f"must be an integer >= 1, got {self.hypotheses!r}",
        )
        for name in ("velocity_prior_sd", "max_source_speed", "position_sd", "range_bias_sd", "rate_bias_sd"):
            _positive(getattr(self, name), f"initializer.{name}")
        require(self.covariance_inflation >= 1, "initializer.covariance_inflation", "must be >= 1")
        _positive(self.max_turn_rate, "initializer.max_turn_rate")
        _positive(self.acceleration_prior_sd, "initializer.acceleration_prior_sd")
        require(
            self.search_spacing == 0 or 0.5 <= self.search_spacing < math.inf,
            "initializer.search_spacing",
            f"must be 0 (no search) or a finite spacing >= 0.5 m, got {self.search_spacing!r}",
        )
        require(
            isinstance(self.turn_rate_steps, int) and self.turn_rate_steps >= 1,
            "initializer.turn_rate_steps",
            f"must be an integer >= 1, got {self.turn_rate_steps!r}",
        )

    @property
    def turn_rates(self) -> np.ndarray:
        """The turn rates (rad/s) LC-MAP tries with a ctrv filter."""
        return (
            np.linspace(-self.max_turn_rate, self.max_turn_rate, self.turn_rate_steps)
            if self.turn_rate_steps > 1
            else np.zeros(1)
        )


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the reward terms (each term is reported in info['reward_terms']); the scale of each
    term over an episode is tabulated in :mod:`aasl_gym.rewards`."""

    information_gain: float = 1.0  # per nat of log det Fisher information gained
    error_shrinkage: float = 0.1  # per metre of true position error removed (privileged)
    control_effort: float = 0.01  # per unit |action|^2
    constraint_penalty: float = 1.0  # per step the robot hits a keep-out / region / depth limit
    success_bonus: float = 10.0  # once, when the error first falls below success_threshold
    success_threshold: float = 1.0  # m

    def __post_init__(self) -> None:
        for name in ("information_gain", "error_shrinkage", "control_effort", "constraint_penalty", "success_bonus"):
            require(math.isfinite(getattr(self, name)), f"reward.{name}", "must be finite")
        _positive(self.success_threshold, "reward.success_threshold")


@dataclass(frozen=True)
class EpisodeConfig:
    duration: float = 120.0  # s; the episode is truncated here
    convergence_threshold: float = 1.0  # m
    terminate_on_convergence: bool = False

    def __post_init__(self) -> None:
        _positive(self.duration, "episode.duration")
        _positive(self.convergence_threshold, "episode.convergence_threshold")


@dataclass(frozen=True)
class PatrolConfig:
    """Scripted patrol geometry, centred on the fixed hydrophone (the helix, the spiral, the lawnmower and the square
    as the sweeps in reports/patrol_sweep/ chose them; the circle shares the helix's radius)."""

    speed: float = 1.0  # m/s along the path
    radius: float = 15.0  # m, helix / circle radius, the square's half-side
    depth_min: float = 2.0  # m, helix depth oscillates between depth_min and depth_max
    depth_max: float = 12.0  # m
    depth_period: float = 30.0  # s, period of the helix's depth oscillation
    spiral_radius_min: float = 4.0  # m, spiral starts just outside the keep-out zone
    spiral_radius_max: float = 35.0  # m (the sweep in reports/patrol_sweep/)
    spiral_period: float = 60.0  # s, out and back
    spiral_depth: float = 11.0  # m
    lawnmower_width: float = 40.0  # m, side of the square the lawnmower sweeps
    lawnmower_spacing: float = 10.0  # m between legs
    position_gain: float = 0.5  # 1/s, feedback that pulls the robot onto the pattern

    def __post_init__(self) -> None:
        for name in (
            "speed",
            "radius",
            "depth_period",
            "spiral_radius_max",
            "spiral_period",
            "lawnmower_width",
            "lawnmower_spacing",
            "position_gain",
        ):
            _positive(getattr(self, name), f"patrol.{name}")
        _non_negative(self.depth_min, "patrol.depth_min")
        require(self.depth_min <= self.depth_max, "patrol.depth_max", "must be >= patrol.depth_min")
        _non_negative(self.spiral_radius_min, "patrol.spiral_radius_min")
        require(
            self.spiral_radius_min < self.spiral_radius_max,
            "patrol.spiral_radius_max",
            "must be > patrol.spiral_radius_min",
        )
        _non_negative(self.spiral_depth, "patrol.spiral_depth")


@dataclass(frozen=True)
class FacilityConfig:
    """A facility of several pods on the bed, one fixed hydrophone atop each, and one patrol robot
    (``AASL-Facility-v0``, :mod:`aasl_gym.facility`). The pods stand in ``rows`` rows, ``spacing`` apart,
    centred on ``world.fixed_position`` (whose depth their hydrophones share). The attack begins at a time
    drawn from ``onset_range``, next to a pod drawn at random; a pod's hydrophone hears it once its SNR
    (spreading, the multipath sum with reflections on, the world's noise level) reaches ``detection_snr_db``.
    The tracker pairs the robot with the loudest pod; with ``pairs: all`` every other pod that hears the
    source adds an extra pair (:mod:`aasl_gym.extra_pairs`)."""

    pods: int = 1  # 1: a single pod, world.fixed_position (the other ids ignore this section)
    rows: int = 1
    spacing: float = 30.0  # m between neighbouring pods
    onset_range: tuple[float, float] = (5.0, 30.0)  # s, when the attack begins
    detection_snr_db: float = 20.0  # dB
    loop_margin: float = 10.0  # m: before detection the robot circles this far outside the outermost pods
    pairs: str = "loudest"  # loudest: the paper's one pair; all: every other pod that hears adds an extra pair

    def __post_init__(self) -> None:
        require_choice(self.pairs, ("loudest", "all"), "facility.pairs")
        require(
            isinstance(self.pods, int) and self.pods >= 1,
            "facility.pods",
            f"must be an integer >= 1, got {self.pods!r}",
        )
        require(
            isinstance(self.rows, int) and 1 <= self.rows <= self.pods,
            "facility.rows",
            f"must be an integer from 1 to facility.pods = {self.pods}, got {self.rows!r}",
        )
        columns = math.ceil(self.pods / self.rows)
        require(
            (self.rows - 1) * columns < self.pods,
            "facility.rows",
            f"{self.rows} rows of {columns} leave the last row empty for {self.pods} pods: use fewer rows",
        )
        _positive(self.spacing, "facility.spacing")
        _ordered_pair(self.onset_range, "facility.onset_range")
        require(math.isfinite(self.detection_snr_db), "facility.detection_snr_db", "must be finite")
        _positive(self.loop_margin, "facility.loop_margin")


@dataclass(frozen=True)
class EnvConfig:
    world: WorldConfig = field(default_factory=WorldConfig)
    source: SourceConfig = field(default_factory=SourceConfig)
    receiver: ReceiverConfig = field(default_factory=ReceiverConfig)
    measurement: MeasurementConfig = field(default_factory=MeasurementConfig)
    signal: SignalConfig = field(default_factory=SignalConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    initializer: InitializerConfig = field(default_factory=InitializerConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    patrol: PatrolConfig = field(default_factory=PatrolConfig)
    fault: FaultConfig = field(default_factory=FaultConfig)
    facility: FacilityConfig = field(default_factory=FacilityConfig)

    def __post_init__(self) -> None:
        for section in dataclasses.fields(self):
            _check_finite(getattr(self, section.name), section.name)
        start = self.receiver.start_position
        depth = self.world.water_depth
        require(
            -depth + self.receiver.bed_clearance <= start[2] <= -self.receiver.min_depth,
            "receiver.start_position",
            f"z = {start[2]} m must lie between -{depth} + bed_clearance and -min_depth",
        )
        require(
            self.patrol.depth_max < depth - self.receiver.bed_clearance,
            "patrol.depth_max",
            f"must be shallower than the bed ({depth} m) less receiver.bed_clearance",
        )
        require(
            self.source.initial_radius <= self.world.region_radius,
            "source.initial_radius",
            f"must not exceed world.region_radius = {self.world.region_radius}",
        )
        self._check_initial_centre()
        self._check_source_depth()
        self._check_facility()
        require(
            2 * self.source.boundary_margin < depth, "source.boundary_margin", "leaves no water column for the source"
        )
        require(
            self.signal.frame_duration <= 1.0 / self.measurement.rate + 1e-12,
            "signal.frame_duration",
            f"must not exceed one step (1 / measurement.rate = {1.0 / self.measurement.rate} s)",
        )
        require(
            self.world.reflection_model == "phasor" or self.measurement.mode == "geometric",
            "world.reflection_model",
            f"{self.world.reflection_model!r} generates geometric measurements only (the signal front end hears "
            "the exact phasor sum): set measurement.mode to geometric or world.reflection_model to phasor",
        )
        self._check_sampling()
        require(
            self.fault.kind in ("none", "dropped") or self.measurement.mode == "signal",
            "fault.kind",
            f"{self.fault.kind!r} corrupts a synthesized frame: it needs measurement.mode signal",
        )

    def _check_sampling(self) -> None:
        """On the hardware path (real samples at ``signal.sample_rate``) the receiver band lies below the Nyquist
        frequency; else the tone folds over and no frame is heard: the env would run, deaf, without a word."""
        if self.measurement.mode != "signal" or self.signal.path != "hardware":
            return
        kind, frequency = self.source.waveform, self.source.frequency
        low, high = receiver_band(kind, frequency)
        require(
            high < self.signal.sample_rate / 2,
            "signal.sample_rate",
            f"samples up to {self.signal.sample_rate / 2:g} Hz (its Nyquist frequency): too little for the receiver "
            f"band {low:g}-{high:g} Hz (source.waveform {kind}, source.frequency {frequency:g} Hz)",
        )

    def _check_source_depth(self) -> None:
        """A source held at a depth must be held where it may be: ``source.boundary_margin`` below the
        surface and above the bed."""
        depth, margin, water = self.source.depth, self.source.boundary_margin, self.world.water_depth
        if depth is not None:
            require(
                margin <= depth <= water - margin,
                "source.depth",
                f"{depth} m must lie source.boundary_margin = {margin} m below the surface and above the bed "
                f"(world.water_depth = {water} m)",
            )

    def _check_facility(self) -> None:
        """Every pod's source ball lies in the world's region, and the robot may fly the loop around the pods."""
        if self.facility.pods == 1:
            return
        hydrophones = pod_hydrophones(self.facility, self.world.fixed_position)
        farthest = float(np.max(np.hypot(hydrophones[:, 0], hydrophones[:, 1])))
        require(
            farthest + self.source.initial_radius <= self.world.region_radius,
            "facility.spacing",
            f"puts a pod {farthest:.1f} m from the origin: with source.initial_radius = {self.source.initial_radius} "
            f"m its sources reach beyond world.region_radius = {self.world.region_radius} m",
        )
        reach = float(np.hypot(*hydrophones[:, :2].mean(axis=0))) + loop_radius(self.facility, hydrophones)
        require(
            reach <= self.receiver.region_radius,
            "facility.loop_margin",
            f"the patrol loop reaches {reach:.1f} m from the origin, beyond receiver.region_radius = "
            f"{self.receiver.region_radius} m",
        )
        # The robot is kept out of the paired pod's sphere only: its patrols must pass over the others.
        deepest = max(self.patrol.depth_max, self.patrol.spiral_depth)
        clearance = -float(hydrophones[0, 2]) - deepest
        require(
            clearance >= self.receiver.keep_out_radius,
            "patrol.depth_max",
            f"the patrols reach {deepest} m, {clearance:.2f} m above the pods' hydrophones: keep at least "
            f"receiver.keep_out_radius = {self.receiver.keep_out_radius} m above them",
        )
        require(
            self.facility.onset_range[1] < self.episode.duration,
            "facility.onset_range",
            f"the attack may begin after the episode ends (episode.duration = {self.episode.duration} s)",
        )

    def _check_initial_centre(self) -> None:
        """The ball the source starts in must reach the water it may start in - the region less
        ``source.boundary_margin`` (:func:`aasl_gym.motion.source_region`) - or rejection sampling never ends."""
        x, y, z = self.source.initial_centre
        radius, margin, depth = self.source.initial_radius, self.source.boundary_margin, self.world.water_depth
        reach = self.world.region_radius - margin
        require(
            -depth <= z <= 0,
            "source.initial_centre",
            f"z = {z} m must lie in the water column [-{depth}, 0] (world.water_depth = {depth})",
        )
        require(
            math.hypot(x, y) - radius < reach and z - radius < -margin and z + radius > -depth + margin,
            "source.initial_centre",
            f"its ball of source.initial_radius = {radius} m about {[x, y, z]} must reach the water a source may "
            f"start in: within world.region_radius - source.boundary_margin = {reach} m of the origin horizontally, "
            f"{margin} m below the surface and above the bed ({depth} m)",
        )

    @property
    def filter_multipath(self) -> str:
        """The filter's multipath model, ``matched`` resolved against the world: the world's own
        ``reflection_model`` where it has reflections, the direct path where it has none."""
        if self.filter.multipath != "matched":
            return self.filter.multipath
        return self.world.reflection_model if self.world.reflections else "none"

    @property
    def filter_speed_limit(self) -> float | None:
        """The CA filter's top speed (m/s), ``matched`` resolved against the world: its sources' ``max_speed``."""
        limit = self.filter.speed_limit
        return self.source.max_speed if limit == "matched" else limit  # type: ignore[return-value]

    @property
    def dt(self) -> float:
        """Step length, s."""
        return 1.0 / self.measurement.rate

    @property
    def max_steps(self) -> int:
        return int(round(self.episode.duration * self.measurement.rate))

    @property
    def wavelength(self) -> float:
        """Tone wavelength c / f0, m."""
        return self.world.sound_speed / self.source.frequency

    def replace(self, **sections: Mapping[str, Any]) -> EnvConfig:
        """A copy with some fields changed, e.g. ``replace(filter={"multipath": "none"})``."""
        return from_dict(merge(to_dict(self), sections))


def to_dict(config: Any) -> dict[str, Any]:
    """The config as plain, YAML-ready Python values."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = to_dict(value)
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """Recursive dict merge; ``update`` wins."""
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def _coerce(value: Any, annotation: Any, path: str) -> Any:
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(annotation)
        if value is None and type(None) in options:
            return None
        kinds = [a for a in options if a is not type(None)]
        if len(kinds) == 1:
            return _coerce(value, kinds[0], path)
        for kind in kinds:  # e.g. a speed or ``matched``: the first type the value is
            try:
                return _coerce(value, kind, path)
            except ConfigError:
                continue
        names = " or ".join(getattr(kind, "__name__", str(kind)) for kind in kinds)
        raise ConfigError(f"{path}: must be a {names}, got {value!r}")
    if origin is tuple:
        require(isinstance(value, (list, tuple)), path, f"must be a list, got {value!r}")
        inner = typing.get_args(annotation)
        if len(inner) == 2 and inner[1] is Ellipsis:
            return tuple(_coerce(v, inner[0], f"{path}[{i}]") for i, v in enumerate(value))
        require(len(value) == len(inner), path, f"must have {len(inner)} entries, got {len(value)}")
        return tuple(_coerce(v, t, f"{path}[{i}]") for i, (v, t) in enumerate(zip(value, inner)))
    if annotation is bool:
        require(isinstance(value, bool), path, f"must be true or false, got {value!r}")
        return value
    # NumPy's scalars count (a dict built with NumPy's help holds them); True and False do not.
    if annotation is int:
        integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        require(integral, path, f"must be an integer, got {value!r}")
        return int(value)
    if annotation is float:
        real = isinstance(value, numbers.Real) and not isinstance(value, bool)
        require(real, path, f"must be a number, got {value!r}")
        return float(value)
    if annotation is str:
        require(isinstance(value, str), path, f"must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported annotation {annotation!r} at {path}")


def build_section(cls: type, data: Mapping[str, Any], path: str) -> Any:
    """The dataclass ``cls`` from plain values, its sections built in turn and every value converted to
    its field's type; an unknown key, a wrong type or a failed check raises :class:`ConfigError` naming
    the key under ``path``."""
    require(isinstance(data, Mapping), path or "config", f"must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    prefix = f"{path}." if path else ""
    if unknown:
        raise ConfigError(f"{prefix}{unknown[0]}: unknown key; allowed keys are {sorted(fields)}")
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):  # a section (hints are classes)
            kwargs[name] = build_section(hint, value, f"{prefix}{name}")
        else:
            kwargs[name] = _coerce(value, hint, f"{prefix}{name}")
    return cls(**kwargs)


def from_dict(data: Mapping[str, Any] | None) -> EnvConfig:
    """Build and validate an :class:`EnvConfig` from nested plain values (missing keys keep defaults)."""
    return build_section(EnvConfig, data or {}, "")


def read_config_file(
    path: str | Path, extra_keys: tuple[str, ...] = (), base: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The fields a YAML config file sets (nested plain values; an empty file sets none) and any of the
    top-level ``extra_keys`` it has (e.g. a scenario's ``description``), checked as a config over ``base``
    (the fields it changes, e.g. a scenario's) or over the defaults; errors name the file and the key."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} " + ("is a folder" if path.is_dir() else "does not exist"))
    try:
        data = read_yaml(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from exc
    data = {} if data is None else data
    require(isinstance(data, Mapping), str(path), f"must be a mapping of config sections, got {type(data).__name__}")
    try:
        from_dict(merge(base or {}, {key: value for key, value in data.items() if key not in extra_keys}))
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    return dict(data)


def load_config(path: str | Path, base: Mapping[str, Any] | None = None) -> EnvConfig:
    """Load a YAML config file, its fields over ``base`` (nested plain values, e.g. a scenario's) or
    over the defaults; errors name the file and the offending key."""
    return from_dict(merge(base or {}, read_config_file(path, base=base)))


def save_config(config: EnvConfig, path: str | Path) -> None:
    """Write the config as YAML, atomically (write a temporary file, then rename)."""
    from aasl_gym.io import atomic_write_text

    atomic_write_text(path, yaml.safe_dump(to_dict(config), sort_keys=False))
