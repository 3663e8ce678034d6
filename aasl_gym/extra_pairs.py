"""Extra pairs: a facility's other pods, each hydrophone paired with the robot's (issue 15, point 3).

The tracker's state carries the main pair's offsets b_p and b_v. An extra pair's RRD shares b_v (the
robot's recorder runs against one facility clock); its tone RD has a whole-period offset of its own, set by
wherever its unwrapper began. That offset is placed against the leading hypothesis, once that hypothesis
predicts the pair's RD to within a quarter wavelength. The pair then stays on probation and updates
nothing until its normalized innovations under the leader are consistent over ``filter.divergence_window``
(mean NIS at most ``filter.divergence_nis``, each frame's NIS capped as the tracker caps its own under
the phasor model, where one frame at an interference null can miss by many sd).

A gap in the pair's frames may slip its unwrapped track by whole periods: the next frame's offset is
placed again against the leader, as the tracker re-anchors its own pair. When another hypothesis takes
the lead, every offset is placed again against it, and a pair whose offset moves goes back on probation.
A pair is dropped, to be placed afresh later, when it cannot be placed again (the leader's prediction too
wide) and when its NIS window turns inconsistent. Under the phasor model the RD innovation is taken modulo
the wavelength anyway, so there the offset changes nothing but the quarter-wavelength test stands.

The confirmed pairs update each hypothesis together, after the main pair's update, with sigma points
drawn afresh from its mean and covariance. Their errors are not independent: every pair of a frame shares
the robot's recording (its channel's noise, ``shared``, a share of each pair's R_ac) and the robot's
navigation error (the stacked receiver Jacobians' H_r Sigma_r H_r^T, off the diagonal too), with each
other and with the main pair. So the update takes the pairs' joint covariance and conditions it on the
main pair's frame, which the hypothesis has already taken: the pairs' innovation less its regression on the
main pair's innovation, with the conditional covariance, is independent of what was assimilated. A
hypothesis leaves out a pair whose own NIS (given the main frame) is beyond the chi-square gate
(``GATE_QUANTILE``), and undoes the stacked update if its NIS is beyond the gate of its size. Under the
phasor model only a hypothesis that resolved the ripple takes extra pairs. The hypotheses' weights, and
each filter's last innovation, stay the main pair's: the offsets come from the leader, so extra pairs
cannot weigh it against the others.

Why the probation: a first version (session 19) placed offsets at once. In the free field a leader that
was confidently wrong early on placed them wrongly, and every later update pulled the bank towards it.
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, NamedTuple

import numpy as np
from scipy import linalg, stats

from aasl_gym.filters import UnscentedKalmanFilter, merwe_sigma_points, whole_periods
from aasl_gym.measurement_models import receiver_noise
from aasl_gym.sensors import received

if TYPE_CHECKING:
    from aasl_gym.estimator import Hypothesis

# The chi-square quantile of an extra pair's NIS, and of the stacked update's, beyond which it is refused.
GATE_QUANTILE = 0.999

# A pair's [RD, RRD] at a hypothesis's sigma points (2n+1, n) -> (2n+1, 2), and its receiver Jacobian at the
# mean (2, 6): given the hypothesis, the sigma points and the pair's fixed hydrophone (3,), or None for the
# main pair (with b_p). None for a hypothesis that cannot take extra pairs (one yet to resolve the ripple).
PairModel = Callable[["Hypothesis", np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray] | None]


class PairFrame(NamedTuple):
    """One pair's measurement in one frame."""

    z: np.ndarray  # [RD, RRD] (m, m/s); NaN where the pair did not hear
    noise: np.ndarray  # its acoustic R (2, 2)
    hydrophone: np.ndarray | None  # the pair's fixed hydrophone (3,; m); None: the tracker's main pair


@functools.cache
def gate(dof: int) -> float:
    """The NIS of ``dof`` degrees of freedom beyond which an extra pair's update is refused."""
    return float(stats.chi2.ppf(GATE_QUANTILE, dof))


@dataclass
class PairTrack:
    """What the tracker keeps of one extra pair: its RD offset and its recent NIS under the leader."""

    offset: float  # m, whole wavelengths taken off the pair's measured RD
    nis: deque
    confirmed: bool = False  # its NIS window was consistent once: it updates the bank
    reanchor: Literal["", "gap", "leader"] = ""  # why the next frame places the offset again, if it does


@dataclass
class ExtraPairs:
    """The extra pairs of one tracker (see the module's docstring)."""

    wavelength: float | None  # m, the tone's; None: an RD without whole-period ambiguity
    window: int  # frames of the consistency test
    divergence_nis: float  # its mean NIS bound
    nis_cap: float  # the most one frame adds to that mean
    navigation_sd: tuple[float, float]  # m, m/s: the robot's navigation error the filter is told
    residual: Callable[[np.ndarray, np.ndarray], np.ndarray]  # the tracker's z - h
    tracks: dict[tuple[float, ...], PairTrack] = field(default_factory=dict)
    leader: UnscentedKalmanFilter | None = None  # the filter the offsets were placed against

    def reset(self) -> None:
        self.tracks.clear()
        self.leader = None

    def assimilate(
        self,
        bank: Sequence[Hypothesis],
        frames: Sequence[PairFrame],
        model: PairModel,
        main: PairFrame | None,
        shared: np.ndarray,
    ) -> int:
        """Test this step's extra-pair ``frames`` (a NaN measurement is a gap) and assimilate the confirmed
        ones into ``bank``, the likeliest hypothesis first, given the main pair's frame that every
        hypothesis has taken (None if none) and the acoustic covariance every pair of the frame shares
        (``shared``, 2 x 2); returns how many pairs updated the likeliest hypothesis."""
        if not bank:
            return 0
        if bank[0].ukf is not self.leader:
            self.leader = bank[0].ukf
            for track in self.tracks.values():
                track.reanchor = "leader"
        present = []
        for frame in frames:
            key = tuple(float(v) for v in frame.hydrophone)  # type: ignore[union-attr]  # an extra pair's
            if received(frame.z):
                present.append((key, frame))
            elif key in self.tracks and self.tracks[key].reanchor != "leader":
                self.tracks[key].reanchor = "gap"
        if not present:
            return 0
        leader = bank[0]
        try:  # the leader's sigma points and main-pair prediction, which every pair's test shares
            sigmas = merwe_sigma_points(leader.ukf.x, leader.ukf.P, leader.ukf.spread)
            leading = self._predictions(leader, sigmas, [], model, main)
        except np.linalg.LinAlgError:  # the leader's covariance broke: it is dropped at its next update
            return 0
        if leading is None:
            return 0
        confirmed = []
        for key, frame in present:
            try:
                tested = self._tested(key, frame, leader, sigmas, leading, model, main, shared)
            except np.linalg.LinAlgError:
                continue
            if tested is not None and tested.confirmed:
                confirmed.append(frame._replace(z=frame.z - np.array([tested.offset, 0.0])))
        if not confirmed:
            return 0
        taken = [self._update(hypothesis, confirmed, model, main, shared) for hypothesis in bank]
        return taken[0]

    def _tested(
        self,
        key: tuple[float, ...],
        frame: PairFrame,
        leader: Hypothesis,
        sigmas: np.ndarray,
        leading: list[tuple[np.ndarray, np.ndarray]],
        model: PairModel,
        main: PairFrame | None,
        shared: np.ndarray,
    ) -> PairTrack | None:
        """The pair's track after this frame's test under the leader (its ``sigmas`` and, in ``leading``,
        the main pair's prediction there if it has a frame): placed or placed again if it can be (else
        None), dropped (None) once its NIS window is inconsistent, confirmed once it is consistent. The NIS
        is the one the update gates on: given the main pair's frame."""
        ukf = leader.ukf
        prediction = model(leader, sigmas, frame.hydrophone)
        if prediction is None:
            return None
        predictions = leading + [prediction]
        predicted, jacobian = prediction
        track = self.tracks.get(key)
        if track is None or track.reanchor:
            periods: float | None = 0.0
            if self.wavelength is not None:
                variance = frame.noise[0, 0] + receiver_noise(jacobian, *self.navigation_sd)[0, 0]
                periods = whole_periods(frame.z[0], predicted[:, 0], ukf, variance, self.wavelength)
            if periods is None:
                self.tracks.pop(key, None)
                return None
            offset = periods * (self.wavelength or 0.0)
            if track is None or (track.reanchor == "leader" and offset != track.offset):
                track = self.tracks[key] = PairTrack(offset, deque(maxlen=self.window))
            track.offset, track.reanchor = offset, ""
        placed = frame._replace(z=frame.z - np.array([track.offset, 0.0]))
        nis = self._nis(ukf, *self._stacked(ukf, predictions, [placed], main, shared))
        track.nis.append(min(nis, self.nis_cap))
        if len(track.nis) == self.window:
            if np.mean(track.nis) > self.divergence_nis:
                del self.tracks[key]
                return None
            track.confirmed = True
        return track

    def _update(
        self,
        hypothesis: Hypothesis,
        confirmed: list[PairFrame],
        model: PairModel,
        main: PairFrame | None,
        shared: np.ndarray,
    ) -> int:
        """One hypothesis's stacked update with the confirmed pairs' frames (their offsets taken off) whose
        own NIS, given the main pair's frame, is within the gate; undone if the stacked update's NIS is
        beyond it or its covariance breaks. How many pairs it took."""
        ukf = hypothesis.ukf
        x, covariance = ukf.x.copy(), ukf.P.copy()
        try:
            sigmas = merwe_sigma_points(ukf.x, ukf.P, ukf.spread)
            predictions = self._predictions(hypothesis, sigmas, confirmed, model, main)
            if predictions is None:
                return 0
            first = 1 if main is not None else 0
            own = [predictions[:first] + [prediction] for prediction in predictions[first:]]
            kept = [
                i
                for i, frame in enumerate(confirmed)
                if self._nis(ukf, *self._stacked(ukf, own[i], [frame], main, shared)) <= gate(2)
            ]
            if not kept:
                return 0
            taken = predictions[:first] + [predictions[first + i] for i in kept]
            stacked = self._stacked(ukf, taken, [confirmed[i] for i in kept], main, shared)
            ukf.sigmas_f = sigmas
            if ukf.update_stacked(*stacked) <= gate(len(stacked[0])):
                return len(kept)
        except np.linalg.LinAlgError:
            pass
        ukf.x, ukf.P = x, covariance
        return 0

    @staticmethod
    def _predictions(
        hypothesis: Hypothesis, sigmas: np.ndarray, frames: list[PairFrame], model: PairModel, main: PairFrame | None
    ) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """The model's values and receiver Jacobian for the main pair (if it has a frame), then each of
        ``frames``, at ``sigmas``; None if the hypothesis cannot take extra pairs."""
        pairs = ([main] if main is not None else []) + frames
        predictions = [model(hypothesis, sigmas, frame.hydrophone) for frame in pairs]
        return None if any(p is None for p in predictions) else predictions  # type: ignore[return-value]

    def _stacked(
        self,
        ukf: UnscentedKalmanFilter,
        predictions: list[tuple[np.ndarray, np.ndarray]],
        frames: list[PairFrame],
        main: PairFrame | None,
        shared: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The innovation, the sigma points' deviations and the noise of ``frames`` stacked (``predictions``:
        the main pair's first if it has a frame), given the main pair's frame (:func:`conditioned_on_first`)."""
        pairs = ([main] if main is not None else []) + frames
        values = np.stack([value for value, _ in predictions])  # (P, 2n+1, 2)
        means = np.einsum("s,psi->pi", ukf.Wm, values)
        innovation = np.concatenate([self.residual(frame.z, mean) for frame, mean in zip(pairs, means)])
        deviations = np.concatenate(list(values - means[:, None]), axis=1)  # (2n+1, 2P), not wrapped: as update()
        jacobian = np.concatenate([jacobian for _, jacobian in predictions])
        noise = joint_noise([frame.noise for frame in pairs], shared, jacobian, self.navigation_sd)
        if main is None:
            return innovation, deviations, noise
        return conditioned_on_first(innovation, deviations, noise)

    @staticmethod
    def _nis(ukf: UnscentedKalmanFilter, innovation: np.ndarray, deviations: np.ndarray, noise: np.ndarray) -> float:
        covariance = (deviations.T * ukf.Wc) @ deviations + noise
        return float(innovation @ np.linalg.solve(covariance, innovation))


def joint_noise(
    noises: Sequence[np.ndarray], shared: np.ndarray, jacobian: np.ndarray, navigation_sd: tuple[float, float]
) -> np.ndarray:
    """The covariance (2P, 2P) of P pairs' [RD, RRD] errors in one frame: each pair's acoustic R (``noises``)
    on the diagonal, the acoustic covariance they share (``shared``, the robot's channel) between any
    two, and the navigation error's H_r Sigma_r H_r^T over the stacked receiver Jacobians (2P, 6)."""
    count = len(noises)
    between = np.kron(np.ones((count, count)) - np.eye(count), shared)
    scaled = jacobian * np.repeat(navigation_sd, 3)
    return linalg.block_diag(*noises) + between + scaled @ scaled.T


def conditioned_on_first(
    innovation: np.ndarray, deviations: np.ndarray, noise: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs 1.. of a stacked update given pair 0's error: from the stacked innovation (2P,), the sigma
    points' deviations (S, 2P) and the noise (2P, 2P), those (2P - 2 wide) of z_rest - B z_0, where
    B = N_10 N_00^-1 regresses the rest's errors on pair 0's (the first two rows). That measurement's error
    is independent of pair 0's; its covariance is N_11 - B N_01."""
    regression = np.linalg.solve(noise[:2, :2], noise[:2, 2:]).T  # B, (2P - 2, 2)
    return (
        innovation[2:] - regression @ innovation[:2],
        deviations[:, 2:] - deviations[:, :2] @ regression.T,
        noise[2:, 2:] - regression @ noise[:2, 2:],
    )
