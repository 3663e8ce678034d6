"""The observation: its layout, the encoder the env builds it with and the decoder the agents read it with.

The vector is flat (so SB3's MlpPolicy takes it) and holds only what the robot knows - no ground truth.
:class:`Observation` is the same content in SI units; :func:`encode_observation` scales it into the
vector (entries that do not exist yet are 0, everything is clipped to +-:data:`OBSERVATION_BOUND`)
and :func:`decode_observation` undoes the scaling. Scales come from the env's config.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aasl_gym.config import EnvConfig

# (name, length, what it holds)
OBSERVATION_LAYOUT = (
    ("relative_estimate", 3, "estimated source position minus reported receiver position, / region_radius"),
    ("estimate_velocity", 3, "estimated source velocity, / source.max_speed"),
    ("receiver_position", 3, "reported receiver position, / region_radius"),
    ("receiver_velocity", 3, "reported receiver velocity, / receiver.max_speed"),
    ("log_variance", 3, "natural log of the estimate's position variances (m^2), / 10"),
    ("measurement", 2, "latest [RD / region_radius, RRD / source.max_speed]"),
    ("innovation", 2, "latest innovation divided by its predicted sd, / 10"),
    ("time", 1, "elapsed time / episode duration"),
    ("initialized", 1, "1 once the filter runs, else 0"),
)


def _slices(layout) -> dict[str, slice]:
    """Each entry's slice of the vector, the entries laid end to end."""
    slices, start = {}, 0
    for name, length, _ in layout:
        slices[name] = slice(start, start + length)
        start += length
    return slices


OBSERVATION_SLICES: dict[str, slice] = _slices(OBSERVATION_LAYOUT)
OBSERVATION_SIZE = OBSERVATION_SLICES[OBSERVATION_LAYOUT[-1][0]].stop
OBSERVATION_BOUND = 10.0
VARIANCE_FLOOR = 1e-12  # m^2, keeps the log finite


@dataclass(frozen=True)
class Observation:
    """What the robot knows after a step, in SI units. The estimate's entries are None until the filter
    starts (``initialized`` False)."""

    time: float  # s since the episode started
    receiver_position: np.ndarray  # m, as navigation reports it
    receiver_velocity: np.ndarray  # m/s, likewise
    measurement: np.ndarray  # [RD m, RRD m/s], the latest measured (0 before the first)
    innovation: np.ndarray  # the latest innovation over its predicted sd (0 when there is none)
    initialized: bool
    estimate_position: np.ndarray | None = None  # m
    estimate_velocity: np.ndarray | None = None  # m/s
    position_variance: np.ndarray | None = None  # m^2, the diagonal of the estimate's position covariance


def encode_observation(observation: Observation, config: EnvConfig) -> np.ndarray:
    """The observation vector (float32, laid out as :data:`OBSERVATION_LAYOUT`) of ``observation`` for envs
    built from ``config``."""
    scale = config.world.region_radius
    vector = np.zeros(OBSERVATION_SIZE)
    s = OBSERVATION_SLICES
    if observation.initialized:
        # An initialized observation carries the estimate (see Observation).
        assert observation.estimate_position is not None and observation.estimate_velocity is not None
        assert observation.position_variance is not None
        vector[s["relative_estimate"]] = (observation.estimate_position - observation.receiver_position) / scale
        vector[s["estimate_velocity"]] = observation.estimate_velocity / config.source.max_speed
        vector[s["log_variance"]] = np.log(np.maximum(observation.position_variance, VARIANCE_FLOOR)) / 10.0
        vector[s["initialized"]] = 1.0
    vector[s["receiver_position"]] = observation.receiver_position / scale
    vector[s["receiver_velocity"]] = observation.receiver_velocity / config.receiver.max_speed
    vector[s["measurement"]] = observation.measurement / np.array([scale, config.source.max_speed])
    vector[s["innovation"]] = observation.innovation / 10.0
    vector[s["time"]] = observation.time / config.episode.duration
    # np.clip's numbers (NaN kept), without its dispatch.
    np.minimum(np.maximum(vector, -OBSERVATION_BOUND, out=vector), OBSERVATION_BOUND, out=vector)
    return vector.astype(np.float32)


def decode_observation(vector: np.ndarray, config: EnvConfig) -> Observation:
    """The :class:`Observation` one env's observation vector holds (as clipped and rounded to float32)."""
    vector = np.asarray(vector, dtype=float)
    s = OBSERVATION_SLICES
    scale = config.world.region_radius
    receiver_position = vector[s["receiver_position"]] * scale
    initialized = bool(vector[s["initialized"]][0] > 0.5)
    estimate = {}
    if initialized:
        estimate = {
            "estimate_position": vector[s["relative_estimate"]] * scale + receiver_position,
            "estimate_velocity": vector[s["estimate_velocity"]] * config.source.max_speed,
            "position_variance": np.exp(10.0 * vector[s["log_variance"]]),
        }
    return Observation(
        time=float(vector[s["time"]][0]) * config.episode.duration,
        receiver_position=receiver_position,
        receiver_velocity=vector[s["receiver_velocity"]] * config.receiver.max_speed,
        measurement=vector[s["measurement"]] * np.array([scale, config.source.max_speed]),
        innovation=vector[s["innovation"]] * 10.0,
        initialized=initialized,
        **estimate,
    )
