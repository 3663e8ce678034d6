"""``AASL-Facility-v0``: one patrol robot for a facility of several pods (issue 15; the layout is
:mod:`aasl_gym.facility`, the config section :class:`~aasl_gym.config.FacilityConfig`).

An episode: the attack begins at a time drawn from ``facility.onset_range``, next to a pod drawn at random
(the source starts in the ball of ``source.initial_radius`` about that pod's hydrophone and stays silent and
still until then). Until a pod's hydrophone hears it (``facility.detection_snr_db``), the robot circles the
facility and the tracker has no pair to measure with. On detection the robot heads for the pod that hears
the source loudest and flies the spiral about it; the tracker pairs the mobile hydrophone with that pod's,
as the reference paper does, with its prior about that pod. With ``facility.pairs: all`` every other pod
whose hydrophone hears the source adds an extra pair: its channel of the robot's frame, paired with the
robot's channel (:meth:`~aasl_gym.sensors.Sensor.measure_pairs`; :mod:`aasl_gym.extra_pairs` says how the
tracker tests and takes them). The action is a residual on that scripted command, as in the other patrol
ids, and the observation, reward and metrics are theirs (the metrics count from the tracker's estimate, so
from after detection). The observation does not say which pod is paired or whether the attack was heard; a
policy sees it through the estimate once the tracker runs. The robot is kept out of the paired pod's sphere
only; the config requires the patrols to pass above every pod.

Extra ``info`` keys: ``detected`` (bool), ``pod`` (the paired pod's index, -1 before detection),
``extra_pairs`` (how many extra pairs updated the likeliest hypothesis this step), ``source_pod`` (the pod
the attack began next to) and ``detection_time`` (s, inf before); ``fixed_position`` is the paired pod's
hydrophone (before detection: ``world.fixed_position``, the facility's centre). Before detection there is
no frame: ``measured`` is False, ``measurement`` zeros (no frame received yet) and ``snr_db`` -inf.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from aasl_gym.config import ConfigError, EnvConfig
from aasl_gym.env import AASLEnv
from aasl_gym.estimator import SourceTracker, TrackerOutput
from aasl_gym.extra_pairs import PairFrame
from aasl_gym.facility import loop_radius, pod_hydrophones
from aasl_gym.measurement_models import received_snr
from aasl_gym.motion import SourceState, sample_source, source_region
from aasl_gym.patrols import PatrolGeometry, patrol_command
from aasl_gym.registration import FACILITY_ID, check_env_fits


def hydrophone_snr_db(config: EnvConfig, source: np.ndarray, hydrophones: np.ndarray) -> np.ndarray:
    """In-band SNR (dB) of a source at ``source`` (3,; m) at each hydrophone (N, 3): spreading from the
    source level to the world's noise level, times the multipath sum's gain with reflections on."""
    return 10 * np.log10(received_snr(config, source, hydrophones))


class FacilityEnv(AASLEnv):
    """A patrol robot for a facility of ``facility.pods`` pods (see the module's docstring); arguments as
    :class:`~aasl_gym.env.AASLEnv`'s but ``patrol`` (the facility's own: the loop, then the spiral), the
    scenario ``facility`` by default."""

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
        render_mode: str | None = None,
        scenario: str | None = "facility",
        **overrides: Any,
    ):
        if "patrol" in overrides:
            raise ConfigError("patrol: AASL-Facility-v0 flies its own patrol (a loop, then a spiral); it takes none")
        super().__init__(config, patrol=None, render_mode=render_mode, scenario=scenario, **overrides)
        cfg = self.config
        self.hydrophones = pod_hydrophones(cfg.facility, cfg.world.fixed_position)
        centre = self.hydrophones.mean(axis=0)
        self.loop = replace(cfg.patrol, radius=loop_radius(cfg.facility, self.hydrophones))
        self.loop_geometry = PatrolGeometry(centre, np.asarray(cfg.receiver.start_position, dtype=float))
        self.unpaired_tracker = self.tracker  # the config's: its prior about the facility, until a pod hears
        self.source_pod, self.onset, self.pod, self.detection_time = 0, 0.0, -1, math.inf

    def _check_pods(self) -> None:
        """A facility of several pods (``facility.pods`` > 1), refused by name otherwise."""
        check_env_fits(FACILITY_ID, self.config, "config")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        # Unpaired again before the base class resets the tracker and its prior's information.
        self.tracker, self.pod, self.detection_time = self.unpaired_tracker, -1, math.inf
        self.extra_pods: set[int] = set()  # the other pods that have heard the source
        self.extra_frames: list[PairFrame] = []  # this step's
        self.extra_used = 0
        self.fixed = np.asarray(self.config.world.fixed_position, dtype=float)
        self.patrol_geometry = PatrolGeometry.from_config(self.config)
        observation, info = super().reset(seed=seed, options=options)
        # The extra pairs draw their noise from a stream of their own: the main pair's, the navigation's and
        # the tracker's draws are the same with and without them (a paired comparison on each seed).
        self.extra_rng = self.np_random.spawn(1)[0]  # spawned from its seed: no draw from it
        return observation, info | self._facility_info()

    def _sample_source(self, rng: np.random.Generator) -> SourceState:
        """Next to a pod drawn at random, with the attack's onset (s) drawn too."""
        cfg = self.config
        self.source_pod = int(rng.integers(len(self.hydrophones)))
        self.onset = float(rng.uniform(*cfg.facility.onset_range))
        near = replace(cfg.source, initial_centre=tuple(self.hydrophones[self.source_pod]))
        return sample_source(rng, cfg.source.motion, near, cfg.world, cfg.episode.duration)

    def _advance_source(self) -> None:
        if self._time >= self.onset - 1e-9:  # silent and still until the attack begins
            super()._advance_source()

    def _command(self, action: np.ndarray) -> np.ndarray:
        command = action * self.config.receiver.max_speed
        if self.pod < 0:
            return command + patrol_command("circle", self._time, self.reported_position, self.loop, self.loop_geometry)
        elapsed = self._time - self.detection_time
        return command + patrol_command(
            "spiral", elapsed, self.reported_position, self.config.patrol, self.patrol_geometry
        )

    def _measure(self) -> np.ndarray:
        """Before detection only the navigation reports (no pair, no frame); on the step a pod first hears
        the source, the pair and the tracker change to that pod's, and frames flow."""
        if self.pod < 0 and self._time >= self.onset - 1e-9:
            snr_db = hydrophone_snr_db(self.config, self.source.position, self.hydrophones)
            if snr_db.max() >= self.config.facility.detection_snr_db:
                self._pair_with(int(np.argmax(snr_db)))
        if self.pod >= 0:
            z = super()._measure()
            if self.config.facility.pairs == "all":
                self.extra_frames = self._measure_extra_pairs()
            return z
        self._report_navigation()
        return np.full(2, np.nan)

    def _measure_extra_pairs(self) -> list[PairFrame]:
        """The frame's extra pairs (:meth:`~aasl_gym.sensors.Sensor.measure_pairs`): the robot's hydrophone
        with every other pod's that hears the source, and NaN for a pod that heard it before and no
        longer does (a gap in its track)."""
        cfg = self.config
        heard = hydrophone_snr_db(cfg, self.source.position, self.hydrophones) >= cfg.facility.detection_snr_db
        self.extra_pods |= {int(pod) for pod in np.flatnonzero(heard)} - {self.pod}
        hearing = {pod: self.hydrophones[pod] for pod in sorted(self.extra_pods) if heard[pod]}
        measured = self.sensor.measure_pairs(
            self.extra_rng,
            self.source.position,
            self.source.velocity,
            self.receiver_position,
            self.receiver_velocity,
            hearing,
            cfg.source.range_rate_bias,
        )
        frames = []
        for pod in sorted(self.extra_pods):
            z, noise = measured.get(pod, (np.full(2, np.nan), np.eye(2)))
            frames.append(PairFrame(z, noise, self.hydrophones[pod]))
        return frames

    def _track(self, z: np.ndarray) -> TrackerOutput:
        out = super()._track(z)
        frames, self.extra_frames = self.extra_frames, []
        shared = self.sensor.shared_covariance()
        self.extra_used = self.tracker.assimilate_pairs(frames, self.reported_position, self.reported_velocity, shared)
        return out

    def _pair_with(self, pod: int) -> None:
        """The tracker, the pair and the spiral move to pod ``pod``: a tracker of that pod's hydrophone,
        its prior about it (where the source must be, since it is heard loudest there)."""
        hydrophone = tuple(float(v) for v in self.hydrophones[pod])
        paired = self.config.replace(  # a one-pod world about that pod (the layout no longer centred on it)
            world={"fixed_position": hydrophone}, source={"initial_centre": hydrophone}, facility={"pods": 1, "rows": 1}
        )
        self.pod, self.detection_time, self.fixed = pod, self._time, self.hydrophones[pod].copy()
        self.tracker = SourceTracker(paired, source_region(paired.world, paired.source), self.acoustic_covariance)
        self.tracker.reset()
        self.information.reset(self.tracker.prior_covariance)
        self._fim_logdet = self.information.logdet  # a new prior is no information gained
        self.patrol_geometry = PatrolGeometry(self.fixed, self.reported_position.copy())

    def _drawn_hydrophones(self) -> np.ndarray:
        return self.hydrophones

    def _info(self, *args, **kwargs) -> dict[str, Any]:
        info = super()._info(*args, **kwargs) | self._facility_info()
        if self.pod < 0:
            info["snr_db"] = -math.inf  # no pair, no frame: nothing heard
        return info

    def _facility_info(self) -> dict[str, Any]:
        return {
            "detected": self.pod >= 0,
            "pod": self.pod,
            "source_pod": self.source_pod,
            "detection_time": self.detection_time,
            "extra_pairs": self.extra_used,
        }
