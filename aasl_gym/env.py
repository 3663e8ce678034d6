"""The Gymnasium environment: the stages of the pipeline wired together, one measurement per step."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from aasl_gym import kernels, metrics, rewards
from aasl_gym.config import PATROLS, ConfigError, EnvConfig, from_dict, load_config, merge, to_dict
from aasl_gym.estimator import SourceTracker, TrackerOutput
from aasl_gym.filters import ConstantVelocity
from aasl_gym.fisher import InformationTracker, measurement_jacobian
from aasl_gym.geometry import vector_norm
from aasl_gym.measurement_models import navigation_covariance
from aasl_gym.motion import (
    NavigationError,
    SourceState,
    advance_source,
    motion_region,
    move_receiver,
    receiver_region,
    sample_source,
    source_region,
)
from aasl_gym.observation import OBSERVATION_BOUND, OBSERVATION_SIZE, Observation, encode_observation
from aasl_gym.patrols import PatrolGeometry, patrol_command
from aasl_gym.planning import GreedyPlanner
from aasl_gym.registration import ENV_IDS, FACILITY_ID, check_env_fits
from aasl_gym.scenarios import scenario_fields
from aasl_gym.sensors import make_sensor, received

if TYPE_CHECKING:
    from aasl_gym.render import Renderer  # imported when first rendering: matplotlib is slow to import

# Keyword arguments of gym.make / AASLEnv that override one config field each.
OVERRIDES: dict[str, tuple[str, str]] = {
    "source_motion": ("source", "motion"),
    "measurement": ("measurement", "mode"),
    "initializer": ("initializer", "name"),
    "reflections": ("world", "reflections"),
    "multipath": ("filter", "multipath"),
    "filter_model": ("filter", "motion_model"),
}

ENV_PATROLS = (*PATROLS, "greedy")  # what an env's action may be a residual on (``patrol``)


def resolve_config(
    config: EnvConfig | Mapping[str, Any] | str | Path | None, scenario: str | None = None, **overrides: Any
) -> EnvConfig:
    """An :class:`EnvConfig` from a named scenario, a config (object, nested dict or YAML path) and keyword
    overrides, each over the one before.

    ``scenario`` is a name of :func:`~aasl_gym.scenarios.scenario_names`; a ``config`` given with it is a
    dict or a file of the fields to change (an :class:`EnvConfig` is complete, so it cannot be). ``overrides``
    are the keys of :data:`OVERRIDES`; ``None`` leaves a field alone. Bad values raise :class:`ConfigError`
    naming the keyword.
    """
    fields = {} if scenario is None else scenario_fields(scenario)
    if config is None:
        base = from_dict(fields)
    elif isinstance(config, EnvConfig):
        if scenario is not None:
            raise ConfigError(
                f"scenario={scenario!r} with config=EnvConfig(...): an EnvConfig sets every field; pass the "
                "fields to change as a dict or a YAML file"
            )
        base = config
    elif isinstance(config, Mapping):
        base = from_dict(merge(fields, config))
    elif isinstance(config, (str, Path)):
        base = load_config(config, base=fields)
    else:
        raise ConfigError(
            f"config: expected a path to a YAML file, a mapping or an EnvConfig, got {type(config).__name__}"
        )
    unknown = sorted(set(overrides) - set(OVERRIDES))
    if unknown:
        raise ConfigError(f"{unknown[0]}: unknown override; allowed: {sorted(OVERRIDES)}, config and scenario")
    data = to_dict(base)
    for keyword, value in overrides.items():
        if value is None:
            continue
        section, key = OVERRIDES[keyword]
        data[section][key] = value
        try:
            from_dict(data)
        except ConfigError as exc:
            raise ConfigError(f"{keyword}={value!r}: {exc}") from exc
    return from_dict(data)


class AASLEnv(gym.Env):
    """Steer a mobile hydrophone so that a TDOA/FDOA tracker localizes an underwater sound source fast.

    ## Description
    A narrowband source (a tone near 1 kHz) moves near an underwater data-center pod. One hydrophone is
    fixed on the pod, the other rides on the robot this environment steers. Every step (0.2 s) the two
    channels yield a range difference (RD, m) and a range-rate difference (RRD, m/s); an unscented
    Kalman filter started by the LC-MAP initializer tracks the source in 3-D. The robot's path decides
    how observable the source is, and so how fast the estimate converges. See ``shared/SPEC.md`` for
    the physics and sign conventions. Each source follows its motion model exactly (only surface and
    bed reflect it), so a fast one can leave the surveillance region within an episode; set
    ``source.confined`` for a source that turns back at the region's edge. LC-MAP starts a bank of
    UKFs, one per likely whole-period sheet, and re-runs on its growing window (fitting the filter's
    motion model) for the first 60 s, and again on the recent window whenever the likeliest filter
    stops explaining the data; the reported estimate is the likeliest filter's (``aasl_gym.estimator``).
    ``measurement.mode`` chooses how [RD, RRD] is made (``aasl_gym.sensors``): ``signal``, the default
    (``aasl_gym.synthesis`` synthesizes both channels for a 0.2 s frame each step, the front end of
    ``aasl_gym.frontend`` processes them, the filter's R follows each frame's measured SNR, and its
    multipath model is the frame's mean and slope, as the front end measures them), or
    ``geometric`` (the geometry plus Gaussian noise, as in the reference paper's study).

    ## Action Space
    ``Box(-1, 1, (3,), float32)``: a velocity command scaled by ``receiver.max_speed`` (1.5 m/s). In
    ``AASL-v0`` it is the command itself; in the patrol variants (``AASL-Helix-v0``, ``-Spiral-``,
    ``-Circle-``, ``-Lawnmower-``, ``-Square-``) it is a residual added to the pattern's command, so a zero action
    flies the pure scripted patrol; in ``AASL-Greedy-v0`` it is a residual on the information-greedy
    planner's command (``aasl_gym.planning``, from the estimate; the helix until the filter starts), so
    a zero action flies what the ``greedy`` policy flies. The command's norm is clipped to the speed
    limit; a surface vessel ignores z. Finite actions outside the box are clipped to it; NaN or infinite actions raise
    ``ValueError``. The robot never leaves the water column (``receiver.min_depth``,
    ``bed_clearance``), its region (``receiver.region_radius``) or enters the keep-out sphere
    (``receiver.keep_out_radius`` about the fixed hydrophone): a command that would is projected and
    penalized.

    ## Observation Space
    ``Box(-10, 10, (21,), float32)``, built only from what the robot knows (no ground truth); its
    layout, encoder and decoder are ``aasl_gym.observation``'s:

    | index | meaning | scale |
    |-------|---------|-------|
    | 0-2   | estimated source position minus reported receiver position | / world.region_radius |
    | 3-5   | estimated source velocity | / source.max_speed |
    | 6-8   | reported receiver position | / world.region_radius |
    | 9-11  | reported receiver velocity | / receiver.max_speed |
    | 12-14 | log of the estimate's position variances (m^2) | / 10 |
    | 15-16 | latest measurement [RD, RRD] | / region_radius, / source.max_speed |
    | 17-18 | latest innovation over its predicted sd | / 10 |
    | 19    | elapsed time | / episode.duration |
    | 20    | 1 once the filter runs, else 0 | |

    Entries are 0 where they do not exist yet (before the first measurement or initialization) and
    clipped to [-10, 10].

    ## Rewards
    A weighted sum (weights in ``reward``) of ``information_gain`` (increase of the log-determinant of
    the position Fisher information at the estimate, nats; under the direct path's Jacobian and R_eff's
    diagonal in every world - the phasor model's ripple is not rewarded), ``error_shrinkage`` (decrease
    of the true error, m; privileged), ``control_effort`` (-|action|^2), ``constraint_penalty`` (-1 on a
    step that hits a limit) and ``success_bonus`` (1 when the error first falls below
    ``success_threshold``). Each weighted term is in ``info["reward_terms"]``.

    ## Starting State
    The robot starts at ``receiver.start_position``. The source starts uniformly within
    ``source.initial_radius`` (20 m) of ``source.initial_centre`` (the origin) inside the water column and follows
    ``source.motion`` (static, cv, ca, ctrv, uturn or mixed) with parameters drawn from the seed (held at
    ``source.depth`` if set, its path kept within ``source.keep_within`` if set). The filter starts after
    ``initializer.burst_duration`` seconds of measurements. (``AASL-Facility-v0`` differs:
    :mod:`aasl_gym.facility_env`.)

    ## Episode End
    * Termination: only if ``episode.terminate_on_convergence`` is true, when the position error
      falls below ``episode.convergence_threshold``.
    * Truncation: at ``episode.duration`` (120 s = 600 steps at 5 Hz). The environment truncates
      itself, so a config with another duration or rate needs no other wrapper.

    ## Info
    ``reset`` gives ``time`` and ``source_motion`` (the motion drawn, for ``mixed``). Every step:
    ``time``, ``source_position``, ``source_velocity``, ``receiver_position``, ``receiver_velocity``,
    ``receiver_position_reported``, ``fixed_position``, ``estimate_position``, ``estimate_velocity``,
    ``position_error`` (of that estimate) and ``position_covariance`` (3x3), ``measurement`` (the last
    [RD, RRD] the estimator received, as the observation shows it: held over lost frames, zeros before
    the first), ``measured`` (whether that frame is this step's), ``measurement_true`` (noise-free
    direct-path [RD, RRD]), ``snr_db`` (of the weaker channel: in signal mode as the front end measures
    it, else from the source level, spreading and noise level), ``initialized``, ``converged`` (error
    below the threshold now), ``reinitialized``, ``fim_logdet``, ``reward_terms``. Until the filter
    starts (``initialized`` False) the estimate is the prior's - a finite mean and covariance
    (``aasl_gym.fisher.information_prior``) - so no value is NaN and Gymnasium's ``check_env`` passes. A
    lost frame - one the ``fault`` option drops, or in which the front end's detector hears no source
    (``signal.detection_snr_db``) - has ``measured`` False (and, if dropped, ``snr_db`` NaN); the filter
    only predicts. On the last step also ``convergence_time``, ``rmse``, ``final_error``, ``success``
    (threshold -> bool), ``time_to_first_estimate`` and ``reinitializations``; these count from the
    tracker's own estimate (the prior never converges and is not in the RMSE). The ones that can be NaN
    (``convergence_time`` when it never converged) are 0-d float64 arrays;
    ``numpy.testing.assert_equal`` compares them NaN for NaN, Gymnasium's ``np.allclose`` does not.

    ## Arguments
    ``AASLEnv(config=None, patrol=None, render_mode=None, scenario=None, source_motion=None,
    measurement=None, initializer=None, reflections=None, multipath=None, filter_model=None)``.
    ``scenario`` names a world of the reference paper's studies (``aasl_gym.scenarios``: ``default``,
    ``paper-monte-carlo``, ``shallow-water``, ``submerged-pod``, ``lake``, ``facility``). ``config`` is an
    :class:`~aasl_gym.config.EnvConfig`, a nested dict or the path of a YAML file (with a scenario, a dict
    or file of the fields to change); the other keywords override one field each, over both, and are
    validated with errors that name them. ``render_mode`` is
    ``"rgb_array"`` (works headless) or ``"human"`` (a matplotlib window).

    ## Version History
    * v0: initial version (signal measurement mode by default, geometric on request).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 5}  # noqa: RUF012  (Gymnasium's class attribute)

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | str | Path | None = None,
        patrol: str | None = None,
        render_mode: str | None = None,
        scenario: str | None = None,
        **overrides: Any,
    ):
        self.config = resolve_config(config, scenario, **overrides)
        if patrol is not None and patrol not in ENV_PATROLS:
            raise ConfigError(f"patrol={patrol!r}: allowed values are {list(ENV_PATROLS)} or None")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            allowed = self.metadata["render_modes"]
            raise ConfigError(f"render_mode={render_mode!r}: allowed values are {allowed} or None")
        self.patrol = patrol
        self.render_mode = render_mode
        self._check_pods()
        cfg = self.config
        self.dt = cfg.dt
        self.max_steps = cfg.max_steps
        self.fixed = np.asarray(cfg.world.fixed_position, dtype=float)
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.observation_space = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (OBSERVATION_SIZE,), np.float32)
        self.source_region = source_region(cfg.world, cfg.source)
        self.motion_region = motion_region(cfg.world, cfg.source)
        self.receiver_region = receiver_region(cfg.world, cfg.receiver)
        self.patrol_geometry = PatrolGeometry.from_config(cfg)
        measurement_sd = np.array([cfg.measurement.range_difference_sd, cfg.measurement.range_rate_difference_sd])
        self.acoustic_covariance = np.diag(measurement_sd**2)
        # The navigation term of R_eff (zero without compensation); the acoustic R is the sensor's, per frame.
        self.navigation_covariance = navigation_covariance(cfg)
        self.filter_covariance = self.acoustic_covariance + self.navigation_covariance
        self.sensor = make_sensor(cfg)
        self.tracker = SourceTracker(cfg, self.source_region, self.acoustic_covariance)
        receiver = cfg.receiver
        self.navigation = NavigationError(receiver.nav_position_sd, receiver.velocity_sd, receiver.nav_drift_sd)
        self.information = InformationTracker(ConstantVelocity(cfg.filter).process_noise(self.dt))
        self.surface_depth = cfg.receiver.surface_depth if cfg.receiver.kind == "surface" else None
        self.planner = GreedyPlanner(cfg) if patrol == "greedy" else None
        self._renderer: Renderer | None = None
        self._time = 0.0

    # -- episode -------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        cfg = self.config
        rng = self.np_random
        self.source = self._sample_source(rng)
        self.receiver_position = np.asarray(cfg.receiver.start_position, dtype=float).copy()
        if self.surface_depth is not None:
            self.receiver_position[2] = -self.surface_depth
        self.receiver_velocity = np.zeros(3)
        self.navigation.reset()
        self.reported_position, self.reported_velocity = self.navigation.report(
            rng, self.receiver_position, self.receiver_velocity, self.dt
        )
        self.sensor.reset(rng)
        self.tracker.reset()
        self.information.reset(self.tracker.prior_covariance)
        if self.planner is not None:
            self.planner.reset()
        self._time = 0.0
        self._steps = 0
        self._fim_logdet = self.information.logdet
        self._error = math.nan
        self._succeeded = False
        self._last_measurement = np.zeros(2)  # [RD, RRD] the observation shows (it keeps it over lost frames)
        self._last_innovation = np.zeros(2)  # over its predicted sd
        self._times: list[float] = []
        self._errors: list[float] = []
        self.trajectory: dict[str, list[np.ndarray]] = {
            "receiver": [self.receiver_position.copy()],
            "source": [self.source.position.copy()],
            "estimate": [],
        }
        if self.render_mode == "human":
            self.render()
        return self._observation(), {"time": 0.0, "source_motion": self.source.kind}

    def _sample_source(self, rng: np.random.Generator) -> SourceState:
        """The episode's source, drawn from the config's motion and start region."""
        cfg = self.config
        return sample_source(rng, cfg.source.motion, cfg.source, cfg.world, cfg.episode.duration)

    def _command(self, action: np.ndarray) -> np.ndarray:
        command = action * self.config.receiver.max_speed
        if self.planner is not None and self.tracker.initialized:  # from the estimate: what the robot knows
            return command + self.planner.command(self.tracker.position, self.tracker.velocity, self.reported_position)
        if self.patrol is not None:
            # The greedy flies the helix until it has an estimate.
            pattern = "helix" if self.patrol == "greedy" else self.patrol
            command = command + patrol_command(
                pattern, self._time, self.reported_position, self.config.patrol, self.patrol_geometry
            )
        return command

    def _check_pods(self) -> None:
        """This env flies one pod: a config with a facility of several (``facility.pods``) is refused by name, where the
        env would ignore all but the first (:class:`~aasl_gym.facility_env.FacilityEnv` flies them)."""
        env_id = next(env_id for env_id, patrol in ENV_IDS.items() if patrol == self.patrol)
        check_env_fits(env_id, self.config, "config", remedy=f" (gym.make({FACILITY_ID!r}, ...))")

    def step(self, action):
        action = self._checked_action(action)
        hit = self._move(action)
        z = self._measure()
        out = self._track(z)
        fim_logdet = self._gather_information(z)
        error = self._position_error()
        # The metrics and rewards count from the tracker's own estimate; info reports the prior's error before it.
        terms = self._reward_terms(action, hit, fim_logdet, error if out.initialized else math.nan)
        converged = self._error < self.config.episode.convergence_threshold
        terminated = bool(self.config.episode.terminate_on_convergence and converged)
        truncated = self._steps >= self.max_steps
        info = self._info(z, out, fim_logdet, terms, converged, error)
        if terminated or truncated:
            info.update(self.episode_summary())
        self._record_trajectory(out.initialized)
        if self.render_mode == "human":
            self.render()
        return self._observation(), float(sum(terms.values())), terminated, truncated, info

    # -- the stages of a step ------------------------------------------------------------------

    @staticmethod
    def _checked_action(action) -> np.ndarray:
        """The action as a (3,) float array, clipped to the box; a wrong shape or type or a non-finite entry raises."""
        action = np.asarray(action)
        if action.shape != (3,):
            raise ValueError(f"action must have shape (3,), got {action.shape}")
        if action.dtype.kind not in "iuf":
            raise ValueError(f"action must be three real numbers, got {action.dtype} values {action.tolist()}")
        action = action.astype(float)
        if not np.isfinite(action).all():
            raise ValueError(f"action must be finite, got {action.tolist()}")
        return np.clip(action, -1.0, 1.0)

    def _move(self, action: np.ndarray) -> bool:
        """The robot flies its command and the source its motion for one step; whether the robot hit a limit."""
        receiver = self.config.receiver
        self.receiver_position, self.receiver_velocity, hit = move_receiver(
            self.receiver_position,
            self._command(action),
            self.dt,
            receiver.max_speed,
            self.receiver_region,
            self.fixed,
            receiver.keep_out_radius,
            self.surface_depth,
        )
        self._advance_source()
        self._steps += 1
        self._time = self._steps * self.dt
        return hit

    def _advance_source(self) -> None:
        self.source = advance_source(self.source, self.dt, self.motion_region)

    def _measure(self) -> np.ndarray:
        """The sensor's [RD, RRD] from the true geometry (NaN for a lost frame); then navigation reports the
        robot's state with its error."""
        z = self.sensor.measure(
            self.np_random,
            self._time,
            self.source.position,
            self.source.velocity,
            self.receiver_position,
            self.receiver_velocity,
            self.fixed,
            self.config.source.range_rate_bias,
        )
        self._report_navigation()
        return z

    def _report_navigation(self) -> None:
        """What the robot's navigation reports of its position and velocity this step."""
        self.reported_position, self.reported_velocity = self.navigation.report(
            self.np_random, self.receiver_position, self.receiver_velocity, self.dt
        )

    def _track(self, z: np.ndarray) -> TrackerOutput:
        """The tracker takes the frame with the acoustic R the sensor gives it (the tracker adds the
        navigation term itself, from its model at each hypothesis); the planner and the observation follow."""
        out = self.tracker.step(
            self._time, z, self.reported_position, self.reported_velocity, self.np_random, self.sensor.covariance()
        )
        if self.planner is not None:
            self.planner.observe(
                out.initialized,
                self.tracker.position,
                self.tracker.velocity,
                self.reported_position,
                self.reported_velocity,
            )
        if received(z):  # the observation holds the last measurement over lost frames
            self._last_measurement[:] = z
        innovation_known = np.isfinite(out.innovation).all()
        self._last_innovation[:] = out.innovation / out.innovation_sd if innovation_known else 0.0
        return out

    def _gather_information(self, z: np.ndarray) -> float:
        """log det of the position information at the estimate after this frame, under the direct path's
        R_eff; a lost frame (dropped by config.fault, or rejected by the detector: NaN) only predicts."""
        jacobian = measurement_jacobian(
            self.tracker.position, self.tracker.velocity, self.reported_position, self.reported_velocity, self.fixed
        )
        measured = received(z)
        noise = self.sensor.covariance() + self.navigation_covariance
        return self.information.step(self.dt, jacobian if measured else None, noise)

    def _position_error(self) -> float:
        """m, of the reported estimate (the prior's mean before the filter starts)."""
        return vector_norm(self.tracker.position - self.source.position)

    def _reward_terms(self, action: np.ndarray, hit: bool, fim_logdet: float, error: float) -> dict[str, float]:
        """The step's weighted reward terms, ``error`` (m) that of the tracker's estimate (NaN before it
        starts); the running information and error, and the episode's error history, move on to this step's."""
        cfg = self.config
        first_success = not self._succeeded and error < cfg.reward.success_threshold
        self._succeeded |= first_success
        terms = rewards.weighted_terms(
            cfg.reward,
            {
                "information_gain": rewards.information_gain(self._fim_logdet, fim_logdet),
                "error_shrinkage": rewards.error_shrinkage(self._error, error),
                "control_effort": rewards.control_effort(action),
                "constraint_penalty": rewards.constraint_penalty(hit),
                "success_bonus": rewards.success_bonus(first_success),
            },
        )
        self._fim_logdet, self._error = fim_logdet, error
        self._times.append(self._time)
        self._errors.append(error)
        return terms

    def _info(
        self,
        z: np.ndarray,
        out: TrackerOutput,
        fim_logdet: float,
        terms: dict[str, float],
        converged: bool,
        position_error: float,
    ) -> dict[str, Any]:
        """The step's ``info`` (see the class docstring); ``position_error`` (m) is the reported estimate's."""
        return {
            "time": self._time,
            "source_position": self.source.position.copy(),
            "source_velocity": self.source.velocity.copy(),
            "receiver_position": self.receiver_position.copy(),
            "receiver_velocity": self.receiver_velocity.copy(),
            "receiver_position_reported": self.reported_position.copy(),
            "fixed_position": self.fixed.copy(),
            "estimate_position": self.tracker.position,
            "estimate_velocity": self.tracker.velocity,
            "position_error": position_error,
            "position_covariance": self.tracker.position_covariance,
            "measurement": self._last_measurement.copy(),
            "measured": received(z),
            "measurement_true": kernels.direct_path(
                self.source.position, self.source.velocity, self.receiver_position, self.receiver_velocity, self.fixed
            )[0],
            "snr_db": float(10 * np.log10(self.sensor.snr().min())),
            "initialized": out.initialized,
            "converged": bool(converged),
            "reinitialized": out.reinitialized,
            "fim_logdet": fim_logdet,
            "reward_terms": terms,
        }

    def _record_trajectory(self, initialized: bool) -> None:
        """The robot's, the source's and (once there is one) the estimate's paths, for rendering."""
        self.trajectory["receiver"].append(self.receiver_position.copy())
        self.trajectory["source"].append(self.source.position.copy())
        if initialized:
            self.trajectory["estimate"].append(self.tracker.position)

    # -- episode metrics and observation -------------------------------------------------------

    def episode_summary(self) -> dict[str, Any]:
        """The episode's metrics so far (added to ``info`` on the last step)."""
        times, errors = np.asarray(self._times), np.asarray(self._errors)
        return {
            "convergence_time": np.array(
                metrics.convergence_time(times, errors, self.config.episode.convergence_threshold)
            ),
            "rmse": np.array(metrics.rmse(errors)),
            "final_error": np.array(errors[-1] if errors.size else math.nan),
            "success": metrics.success(times, errors),
            "time_to_first_estimate": np.array(metrics.time_to_first_estimate(times, errors)),
            "reinitializations": self.tracker.reinitializations,
        }

    def _observation(self) -> np.ndarray:
        """The observation vector: what the robot knows (:mod:`aasl_gym.observation`)."""
        tracker = self.tracker
        estimate = {}
        if tracker.initialized:
            estimate = {
                "estimate_position": tracker.position,
                "estimate_velocity": tracker.velocity,
                "position_variance": tracker.ukf.P.diagonal()[:3],
            }
        known = Observation(
            self._time,
            self.reported_position,
            self.reported_velocity,
            self._last_measurement,
            self._last_innovation,
            tracker.initialized,
            **estimate,
        )
        return encode_observation(known, self.config)

    # -- rendering -----------------------------------------------------------------------------

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        from aasl_gym.render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(self.config, human=self.render_mode == "human")
        covariance = self.tracker.position_covariance if self.tracker.initialized else None
        return self._renderer.draw(self.trajectory, self._drawn_hydrophones(), covariance, self._time)

    def _drawn_hydrophones(self) -> np.ndarray:
        """The fixed hydrophones a rendering shows: (3,) for one pod."""
        return self.fixed

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
