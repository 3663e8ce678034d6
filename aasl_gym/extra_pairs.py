"""Extra pairs: a facility's other pods, each hydrophone paired with the robot's (issue 15, point 3).

The tracker's state carries the main pair's offsets b_p and b_v. An extra pair's RRD shares b_v (the
robot's recorder runs against one facility clock); its tone RD has a whole-period offset of its own, set by
wherever its unwrapper began. That offset is placed against the leading hypothesis, once that hypothesis
predicts the pair's RD to within a quarter wavelength. The pair then stays on probation and updates
nothing until its normalized innovations under the leader are consistent over ``filter.divergence_window``
(mean NIS at most ``filter.divergence_nis``: the test the tracker applies to its own hypotheses).

A gap in the pair's frames may slip its unwrapped track by whole periods: the next frame's offset is
placed again against the leader, as the tracker re-anchors its own pair (the pair is dropped if the leader
cannot tell the period then). When another hypothesis takes the lead, every offset is placed again against
it, and a pair whose offset moves goes back on probation. A pair is dropped, to be placed afresh, when its
NIS window turns inconsistent. A confirmed pair updates every hypothesis whose own NIS for it lies within
the chi-square gate ``GATE``. Each update draws its sigma points afresh from that hypothesis's mean and
covariance after the main pair's update. The hypotheses' weights are the main pair's alone: the offsets
come from the leader, so extra pairs cannot weigh it against the others.

Why the probation: a first version (session 19) placed offsets at once. In the free field a leader that
was confidently wrong early on placed them wrongly, and every later update pulled the bank towards it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from aasl_gym.filters import UnscentedKalmanFilter

if TYPE_CHECKING:
    from aasl_gym.estimator import Hypothesis

GATE = float(stats.chi2.ppf(0.999, 2))  # NIS beyond which one hypothesis does not take an extra pair's frame

# An extra pair's [RD, RRD] at a hypothesis's fresh sigma points (2n+1, 2), without b_p, and the navigation
# noise it adds to R (2, 2): given the hypothesis and the pair's hydrophone (3,).
PairPrediction = Callable[["Hypothesis", np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class PairTrack:
    """What the tracker keeps of one extra pair: its RD offset and its recent NIS under the leader."""

    offset: float  # m, whole wavelengths taken off the pair's measured RD
    nis: deque
    confirmed: bool = False  # its NIS window was consistent once: it updates the bank
    reanchor: str = ""  # "gap" or "leader": the next frame places the offset again (see the module's docstring)


@dataclass
class ExtraPairs:
    """The extra pairs of one tracker (see the module's docstring)."""

    wavelength: float | None  # m, the tone's; None: an RD without whole-period ambiguity
    window: int  # frames of the consistency test
    divergence_nis: float  # its mean NIS bound
    residual: Callable[[np.ndarray, np.ndarray], np.ndarray]  # the tracker's z - h
    tracks: dict[tuple[float, ...], PairTrack] = field(default_factory=dict)
    leader: UnscentedKalmanFilter | None = None  # the filter the offsets were placed against

    def reset(self) -> None:
        self.tracks.clear()
        self.leader = None

    def assimilate(
        self,
        bank: Sequence[Hypothesis],
        pairs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
        predict: PairPrediction,
    ) -> int:
        """Test and assimilate this step's extra pairs (measurement [RD, RRD], hydrophone (3,), acoustic R
        (2, 2); a NaN measurement is a gap) into ``bank``, the likeliest hypothesis first; returns how many
        updated it."""
        if not bank:
            return 0
        if bank[0].ukf is not self.leader:
            self.leader = bank[0].ukf
            for track in self.tracks.values():
                track.reanchor = track.reanchor or "leader"
        used = 0
        for z, hydrophone, noise in pairs:
            key = tuple(float(v) for v in np.round(hydrophone, 6))
            if not np.all(np.isfinite(z)):
                if key in self.tracks:
                    self.tracks[key].reanchor = "gap"
                continue
            tested = self._tested(key, np.asarray(z, dtype=float), hydrophone, noise, bank[0], predict)
            if tested is None or not tested.confirmed:
                continue
            measured = z - np.array([tested.offset, 0.0])
            for hypothesis in bank:
                self._update(hypothesis, measured, hydrophone, noise, predict)
            used += 1
        return used

    def _tested(
        self,
        key: tuple[float, ...],
        z: np.ndarray,
        hydrophone: np.ndarray,
        noise: np.ndarray,
        leader: Hypothesis,
        predict: PairPrediction,
    ) -> PairTrack | None:
        """The pair's track after this frame's test under the leader: placed or placed again if it can
        be (else None), dropped (None) once its NIS window is inconsistent, confirmed once it is consistent."""
        predicted, navigation = predict(leader, hydrophone)
        ukf = leader.ukf
        mean = ukf.Wm @ predicted
        deviation = self.residual(predicted, mean)
        covariance = (deviation.T * ukf.Wc) @ deviation + noise + navigation
        track = self.tracks.get(key)
        if track is None or track.reanchor:
            if self.wavelength is not None and covariance[0, 0] > (0.25 * self.wavelength) ** 2:
                self.tracks.pop(key, None)  # the leader cannot tell the pair's whole period
                return None
            offset = 0.0 if self.wavelength is None else np.round((z[0] - mean[0]) / self.wavelength) * self.wavelength
            if track is None or (track.reanchor == "leader" and offset != track.offset):
                track = self.tracks[key] = PairTrack(float(offset), deque(maxlen=self.window))
            track.offset, track.reanchor = float(offset), ""
        innovation = self.residual(z - np.array([track.offset, 0.0]), mean)
        track.nis.append(float(innovation @ np.linalg.solve(covariance, innovation)))
        if len(track.nis) == self.window:
            if np.mean(track.nis) > self.divergence_nis:
                del self.tracks[key]
                return None
            track.confirmed = True
        return track

    def _update(
        self,
        hypothesis: Hypothesis,
        z: np.ndarray,
        hydrophone: np.ndarray,
        noise: np.ndarray,
        predict: PairPrediction,
    ) -> None:
        """One hypothesis's update with a confirmed pair's frame, undone if its NIS is beyond the gate."""
        ukf = hypothesis.ukf
        x, covariance = ukf.x.copy(), ukf.P.copy()
        try:
            predicted, navigation = predict(hypothesis, hydrophone)
            ukf.update(z, noise + navigation, lambda _: predicted, self.residual)
        except np.linalg.LinAlgError:
            ukf.x, ukf.P = x, covariance
            return
        if ukf.nis > GATE:
            ukf.x, ukf.P = x, covariance
