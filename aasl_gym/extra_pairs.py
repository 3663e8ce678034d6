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
main pair's innovation, with the conditional covariance, is independent of what was assimilated. The
update is undone if its NIS exceeds the chi-square gate (0.999). Under the phasor model only a hypothesis
that resolved the ripple takes extra pairs. The hypotheses' weights, and each filter's last innovation,
stay the main pair's: the offsets come from the leader, so extra pairs cannot weigh it against the others.

Why the probation: a first version (session 19) placed offsets at once. In the free field a leader that
was confidently wrong early on placed them wrongly, and every later update pulled the bank towards it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from scipy import linalg, stats

from aasl_gym.filters import UnscentedKalmanFilter, merwe_sigma_points, whole_periods
from aasl_gym.measurement_models import receiver_noise

if TYPE_CHECKING:
    from aasl_gym.estimator import Hypothesis

GATE_QUANTILE = 0.999  # chi-square quantile of an extra-pair update's NIS beyond which it is undone

# A pair's [RD, RRD] at a hypothesis's sigma points (2n+1, n) -> (2n+1, 2), and its receiver Jacobian at the
# mean (2, 6): given the hypothesis, the sigma points and the pair's fixed hydrophone (3,), or None for the
# main pair (with b_p). None for a hypothesis that cannot take extra pairs (one yet to resolve the ripple).
PairModel = Callable[["Hypothesis", np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray] | None]
Frame = tuple[np.ndarray, np.ndarray, np.ndarray]  # an extra pair's [RD, RRD], hydrophone (3,) and acoustic R


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
        frames: Sequence[Frame],
        model: PairModel,
        main: tuple[np.ndarray, np.ndarray] | None,
        shared: np.ndarray,
    ) -> int:
        """Test this step's extra-pair ``frames`` (a NaN measurement is a gap) and assimilate the confirmed
        ones into ``bank``, the likeliest hypothesis first, given the main pair's frame this step (its z and
        acoustic R, None if it had none) and the acoustic covariance every pair of the frame shares
        (``shared``, 2 x 2); returns how many pairs updated a hypothesis."""
        if not bank:
            return 0
        if bank[0].ukf is not self.leader:
            self.leader = bank[0].ukf
            for track in self.tracks.values():
                track.reanchor = "leader"
        confirmed = []
        for z, hydrophone, noise in frames:
            key = tuple(float(v) for v in hydrophone)
            if not np.all(np.isfinite(z)):
                if key in self.tracks and self.tracks[key].reanchor != "leader":
                    self.tracks[key].reanchor = "gap"
                continue
            try:
                tested = self._tested(key, np.asarray(z, dtype=float), hydrophone, noise, bank[0], model)
            except np.linalg.LinAlgError:  # the leader's covariance broke: it is dropped at its next update
                continue
            if tested is not None and tested.confirmed:
                confirmed.append((z - np.array([tested.offset, 0.0]), hydrophone, noise))
        if not confirmed:
            return 0
        updated = [self._update(hypothesis, confirmed, model, main, shared) for hypothesis in bank]
        return len(confirmed) if any(updated) else 0

    def _tested(
        self,
        key: tuple[float, ...],
        z: np.ndarray,
        hydrophone: np.ndarray,
        noise: np.ndarray,
        leader: Hypothesis,
        model: PairModel,
    ) -> PairTrack | None:
        """The pair's track after this frame's test under the leader: placed or placed again if it can
        be (else None), dropped (None) once its NIS window is inconsistent, confirmed once it is consistent."""
        ukf = leader.ukf
        prediction = model(leader, merwe_sigma_points(ukf.x, ukf.P, ukf.spread), hydrophone)
        if prediction is None:
            return None
        predicted, jacobian = prediction
        covariance = noise + receiver_noise(jacobian, *self.navigation_sd)
        track = self.tracks.get(key)
        if track is None or track.reanchor:
            periods: float | None = 0.0
            if self.wavelength is not None:
                periods = whole_periods(z[0], predicted[:, 0], ukf, covariance[0, 0], self.wavelength)
            if periods is None:
                self.tracks.pop(key, None)
                return None
            offset = periods * (self.wavelength or 0.0)
            if track is None or (track.reanchor == "leader" and offset != track.offset):
                track = self.tracks[key] = PairTrack(offset, deque(maxlen=self.window))
            track.offset, track.reanchor = offset, ""
        mean = ukf.Wm @ predicted
        deviation = predicted - mean  # as the filter's update spreads them: not wrapped
        covariance = covariance + (deviation.T * ukf.Wc) @ deviation
        innovation = self.residual(z - np.array([track.offset, 0.0]), mean)
        track.nis.append(min(float(innovation @ np.linalg.solve(covariance, innovation)), self.nis_cap))
        if len(track.nis) == self.window:
            if np.mean(track.nis) > self.divergence_nis:
                del self.tracks[key]
                return None
            track.confirmed = True
        return track

    def _update(
        self,
        hypothesis: Hypothesis,
        confirmed: list[Frame],
        model: PairModel,
        main: tuple[np.ndarray, np.ndarray] | None,
        shared: np.ndarray,
    ) -> bool:
        """One hypothesis's joint update with the confirmed pairs' frames (their offsets taken off),
        conditioned on the main pair's (see the module's docstring); undone if its NIS is beyond the gate
        or its covariance breaks. Whether it stood."""
        ukf = hypothesis.ukf
        x, covariance = ukf.x.copy(), ukf.P.copy()
        frames = ([(main[0], None, main[1])] if main is not None else []) + confirmed
        try:
            sigmas = merwe_sigma_points(ukf.x, ukf.P, ukf.spread)
            predictions = [model(hypothesis, sigmas, hydrophone) for _, hydrophone, _ in frames]
            if any(prediction is None for prediction in predictions):
                return False
            values = np.stack([prediction[0] for prediction in predictions])  # type: ignore[index]
            jacobian = np.concatenate([prediction[1] for prediction in predictions])  # type: ignore[index]
            means = np.einsum("s,psi->pi", ukf.Wm, values)
            innovation = np.concatenate([self.residual(z, mean) for (z, _, _), mean in zip(frames, means)])
            deviations = np.concatenate(list(values - means[:, None]), axis=1)  # (2n+1, 2 P)
            noise = joint_noise([noise for _, _, noise in frames], shared, jacobian, self.navigation_sd)
            if main is not None:
                innovation, deviations, noise = conditioned_on_first(innovation, deviations, noise)
            ukf.sigmas_f = sigmas
            nis = ukf.update_stacked(innovation, deviations, noise)
            stood = nis <= stats.chi2.ppf(GATE_QUANTILE, len(innovation))
        except np.linalg.LinAlgError:
            stood = False
        if not stood:
            ukf.x, ukf.P = x, covariance
        return stood


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
    """Pairs 1.. of a stacked update given pair 0's error (the first two rows): the innovation (2P,), the
    sigma points' deviations (S, 2P) and the noise (2P, 2P) of z_rest - B z_0, where B = N_10 N_00^-1
    regresses the rest's errors on pair 0's; that measurement's error is independent of pair 0's, its
    covariance N_11 - B N_01."""
    regression = np.linalg.solve(noise[:2, :2], noise[:2, 2:]).T  # B, (2P - 2, 2)
    return (
        innovation[2:] - regression @ innovation[:2],
        deviations[:, 2:] - deviations[:, :2] @ regression.T,
        noise[2:, 2:] - regression @ noise[:2, 2:],
    )
