r"""How well could *any* unbiased estimator do? The Cramer-Rao bound along each study episode.

For every seeded episode of the initializer study (same seeds, same helix, same source), the source's
trajectory is a function of its motion parameters theta = [p(0), v(0), a (ca) or omega (ctrv), b_p].
The Fisher information of the episode's [RD, RRD] measurements about theta (R_eff weighting, the
initializer's priors, the whole-period offset known to ``initializer.range_bias_sd`` as LC-MAP's sheet
fixes it) bounds the covariance of the position at every time. Jacobians are central finite
differences through the truth motion itself (``advance_source``), so the bound uses the exact model of
each motion, speed cap and surface/bed reflections included.

``--model matched`` evaluates the bound with the world's own measurement model: in a world with
reflections the exact phasor model (the apparent RD and RRD of the tone's multipath sums), weighted with
R_eff = R_ac + H_r Sigma_r H_r^T, H_r that model's receiver Jacobian at the truth (near an interference
null the apparent RD moves with the receiver far faster than the direct path's), and in signal mode R_ac
the front end's Cramer-Rao covariance at the SNR each hydrophone receives through the multipath sum.
The phasor model is evaluated at each frame's centre, not averaged over the frame as the tracker's
signal-mode model is.
The default ``direct`` is the direct-path model with the tracker's fixed R (the free field's bound).

``--nav-sd`` (m, one or more sigma_rov levels; velocity sd 0.4 sigma_rov, the matched model) gives the
bound with the navigation error in R_eff, as the receiver-uncertainty study (``paper.py navigation``)
runs it, one row per motion and level, and the bound's RMSE over the episode from the initializer's
burst on (the root of the mean trace, averaged over the episodes): what the study's RMSE can reach.

Reported per motion: the share of episodes whose bound on the position error sd (the root of its
covariance's trace) falls below ``--target`` metres and stays there to the end, the median time it
first does, and the mean chance that an efficient estimator - its error Gaussian with the bound's
covariance - ends within ``--target`` (what a tracker's success at that threshold can be expected to
reach: a bound's sd of 0.8 m still leaves the error beyond 1 m in about a third of the episodes), and the central
90 % range of that estimator's count over the episodes (each episode a coin with its own chance): a share over 100
episodes moves by a few points by luck alone. With ``--tracker``, the chance that the efficient estimator ends within
the target in as few episodes as the tracker did.

``--tracker`` runs the tracker on the same episodes beside the bound (its success and its RMSE after convergence
over the bound's); ``--oracle`` adds the share whose whole-track MAP fit started at the truth (and at the tracker's
estimate, whichever explains the track better; ``SourceTracker.fit_kept_track``) ends within ``--target``: the bound's
share without its Gaussian approximation, what a tracker that always finds the right basin would reach.

    python benchmarks/crb_bound.py --motions static cv ca ctrv --episodes 100 --seed 1000 \
        --config configs/initializer_study.yaml
    python benchmarks/crb_bound.py --model matched --config configs/default.yaml --seed 710000 --target 1.0
    python benchmarks/crb_bound.py --scenario paper-monte-carlo --model matched --motions cv --seed 800000 \
        --target 1.0 --nav-sd 0 0.1 0.2 0.3 0.4 0.5 0.6 0.7
    python benchmarks/crb_bound.py --motions cv --episodes 100 --seed 740000 --config configs/initializer_study.yaml \
        --target 1.0 --tracker --oracle
"""

from __future__ import annotations

import argparse
import copy
from dataclasses import replace

import numpy as np
from scipy.stats import poisson_binom
from tqdm import tqdm

from aasl_gym.config import EnvConfig
from aasl_gym.env import AASLEnv
from aasl_gym.io import atomic_write_text
from aasl_gym.measurement_models import (
    Propagation,
    multipath_measurement,
    received_snr,
    receiver_jacobian,
    receiver_noise,
    signal_noise_sd,
)
from aasl_gym.motion import SourceState, advance_source
from aasl_gym.patrols import REFERENCES
from aasl_gym.scenarios import add_scenario_arguments, command_line_config
from tracker_check import MATCHED  # run as a script: benchmarks/ is on sys.path


def _unpack(kind: str, theta: np.ndarray, template: SourceState) -> SourceState:
    acceleration = theta[6:9] if kind == "ca" else np.zeros(3)
    turn_rate = float(theta[6]) if kind == "ctrv" else 0.0
    return replace(template, position=theta[0:3], velocity=theta[3:6], acceleration=acceleration, turn_rate=turn_rate)


def _simulate(env: AASLEnv, state: SourceState, steps: int) -> np.ndarray:
    positions = np.empty((steps, 6))
    for k in range(steps):
        state = advance_source(state, env.dt, env.motion_region)
        positions[k, :3], positions[k, 3:] = state.position, state.velocity
    return positions


def matched_weights(
    config: EnvConfig,
    propagation: Propagation,
    truth: np.ndarray,
    mobile: np.ndarray,
    mobile_velocity: np.ndarray,
    fixed: np.ndarray,
) -> np.ndarray:
    """R_eff^-1 (steps, 2, 2) of the world's own model along the true track ``truth`` (steps, 6)."""
    model = "phasor" if config.world.reflections else "none"

    def measure(p, v, p_m, v_m, p_f):
        return multipath_measurement(model, propagation, p, v, p_m, v_m, p_f)

    if config.measurement.mode == "signal":
        snr = [received_snr(config, truth[:, :3], r) for r in (mobile, fixed)]
        sd = signal_noise_sd(config, snr[0], snr[1])
    else:
        sd = np.broadcast_to(
            [config.measurement.range_difference_sd, config.measurement.range_rate_difference_sd], (len(truth), 2)
        )
    acoustic = np.einsum("ki,ij->kij", sd**2, np.eye(2))
    navigation = np.zeros_like(acoustic)
    if config.filter.compensate_navigation:
        jacobian = receiver_jacobian(measure, truth[:, :3], truth[:, 3:], mobile, mobile_velocity, fixed)
        navigation = receiver_noise(jacobian, config.receiver.nav_position_sd, config.receiver.velocity_sd)
    return np.linalg.inv(acoustic + navigation)


def episode_bound(env: AASLEnv, seed: int, model: str = "direct") -> np.ndarray:
    """Bound on the position error sd (m) after every step of episode ``seed``, with the direct-path
    model or the world's own (``model``: direct or matched): the root of the trace of
    :func:`episode_covariance`."""
    return np.sqrt(np.trace(episode_covariance(env, seed, model), axis1=1, axis2=2))


def efficient_success(covariance: np.ndarray, target: float, rng: np.random.Generator, draws: int = 20000) -> float:
    """The chance (Monte Carlo) that an efficient estimator, its position error N(0, ``covariance``)
    (3, 3; m^2), lies within ``target`` (m). A bound's sd just under the target still leaves an
    efficient estimator outside it a third of the time or more."""
    errors = rng.multivariate_normal(np.zeros(3), covariance, size=draws)
    return float(np.mean(np.linalg.norm(errors, axis=1) < target))


def _count_cdf(chances: list[float]) -> np.ndarray:
    """The cdf (0..N) of the number of episodes an efficient estimator ends within the target, each episode on its
    own with its chance in ``chances``: a Poisson-binomial count. (SciPy 1.17's poisson_binom.ppf fails beyond about
    60 episodes, a ufunc's operand limit; its cdf does not.)"""
    return poisson_binom(np.asarray(chances)).cdf(np.arange(len(chances) + 1))


def efficient_count_range(chances: list[float], level: float = 0.9) -> tuple[int, int]:
    """The central ``level`` range of that count (:func:`_count_cdf`): how far a share over this many episodes moves
    by luck alone, with no change in the estimator's quality."""
    tail = (1.0 - level) / 2.0
    cdf = _count_cdf(chances)
    low, high = np.searchsorted(cdf, np.array([tail, 1.0 - tail]) - 1e-12)  # the first count whose cdf reaches each
    return int(low), int(high)


def as_few_chance(chances: list[float], count: int) -> float:
    """The chance that an efficient estimator (its episodes' ``chances``) ends within the target in ``count`` episodes
    or fewer: a tracker's count with a small chance here falls short of the bound; with a fair one, by luck."""
    return float(_count_cdf(chances)[count])


def episode_covariance(env: AASLEnv, seed: int, model: str = "direct") -> np.ndarray:
    """The Cramer-Rao bound on the position covariance (steps, 3, 3; m^2) after every step of episode
    ``seed`` (see :func:`episode_bound`)."""
    env.reset(seed=seed)
    source = env.source
    steps = env.max_steps
    mobile = np.empty((steps, 3))
    mobile_velocity = np.empty((steps, 3))
    for k in range(steps):
        env.step(np.zeros(3))
        mobile[k], mobile_velocity[k] = env.receiver_position, env.receiver_velocity
    kind = source.kind
    kinematic = np.concatenate(
        [source.position, source.velocity]
        + ([source.acceleration] if kind == "ca" else [[source.turn_rate]] if kind == "ctrv" else [])
    )
    ini = env.config.initializer
    prior_sd = (
        [ini.position_sd] * 3
        + [ini.velocity_prior_sd] * 3
        + ([0.02] * 3 if kind == "ca" else [0.05] if kind == "ctrv" else [])
    )
    n = len(kinematic)

    config = env.config
    propagation = Propagation.from_config(config.world, config.source.frequency)
    world_model = "phasor" if model == "matched" and config.world.reflections else "none"

    def trajectory(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        truth = _simulate(env, _unpack(kind, theta, source), steps)
        z = multipath_measurement(
            world_model, propagation, truth[:, :3], truth[:, 3:], mobile, mobile_velocity, env.fixed
        )
        return truth[:, :3], z

    if model == "matched":
        weights = matched_weights(
            config, propagation, _simulate(env, source, steps), mobile, mobile_velocity, env.fixed
        )
    else:
        weights = np.broadcast_to(np.linalg.inv(env.filter_covariance), (steps, 2, 2))

    # The two biases the tracker estimates: b_p adds to every RD, b_v to every RRD (a clock-rate offset the
    # tracker cannot assume away, with the initializer's prior sd, whatever the world's true one).
    d_position = np.zeros((steps, 3, n + 2))
    d_measurement = np.zeros((steps, 2, n + 2))
    d_measurement[:, 0, n] = d_measurement[:, 1, n + 1] = 1.0
    if kind == "static":  # the motion model pins it; estimate it as the CV filter does
        kind = "cv"
        source = replace(source, kind="cv")
    for i in range(n):
        step = 1e-5 * max(1.0, abs(kinematic[i]))
        plus, minus = kinematic.copy(), kinematic.copy()
        plus[i] += step
        minus[i] -= step
        (p_plus, z_plus), (p_minus, z_minus) = trajectory(plus), trajectory(minus)
        d_position[:, :, i] = (p_plus - p_minus) / (2 * step)
        d_measurement[:, :, i] = (z_plus - z_minus) / (2 * step)
    information = np.diag(np.array(prior_sd + [ini.range_bias_sd, ini.rate_bias_sd]) ** -2.0)
    increments = np.einsum("kia,kij,kjb->kab", d_measurement, weights, d_measurement)
    cumulative = information + np.cumsum(increments, axis=0)
    covariance = np.linalg.inv(cumulative)
    return np.einsum("kia,kab,kjb->kij", d_position, covariance, d_position)


def run_tracker(env: AASLEnv, seed: int) -> tuple[SourceState, list[dict]]:
    """Episode ``seed`` of ``env`` (the tracker's) on the scripted patrol: the source's state at the start and every
    step's info."""
    env.reset(seed=seed)
    initial = copy.deepcopy(env.source)
    return initial, [env.step(np.zeros(3))[4] for _ in range(env.max_steps)]


def tracked_squares(infos: list[dict], covariance: np.ndarray, target: float) -> tuple[bool, np.ndarray]:
    """From an episode's ``infos``: whether the tracker succeeded at ``target`` and [the sum of its squared
    position errors, the sum of the bound's traces] (m^2) over the steps from its convergence on (zeros
    if it did not converge), whose ratio's root is its RMSE after convergence over the bound's.
    ``covariance`` (steps, 3, 3) is the bound after each step."""
    converged, success = float(infos[-1]["convergence_time"]), bool(infos[-1]["success"][str(target)])
    if not np.isfinite(converged):
        return success, np.zeros(2)
    errors = np.array([info["position_error"] for info in infos])
    kept = np.array([info["time"] >= converged - 1e-9 for info in infos])
    return success, np.array([np.sum(errors[kept] ** 2), np.sum(np.trace(covariance[kept], axis1=1, axis2=2))])


def true_state(env: AASLEnv, initial: SourceState, last: dict) -> np.ndarray:
    """The source's state at the episode's end in the tracker's filter layout: its start (``initial``: position,
    velocity, turn rate or acceleration) run on by the tracker's own motion model (a CA state's velocity is the one
    without the speed limit, the fold at the depth bounds the world's bounce), the whole-period RD offset the
    unwrapped track carries (the measured RD's offset from the truth's at the end, rounded to whole periods;
    ``last`` the last step's info) and the rate bias."""
    tracker = env.tracker
    state = np.zeros(tracker.model.dim)
    state[0:3], state[3:6] = initial.position, initial.velocity
    if tracker.model.name == "ctrv":
        state[6] = initial.turn_rate
    elif tracker.model.name == "ca":
        state[6:9] = initial.acceleration
    state = tracker.track_model.trajectory(state[None], np.array([last["time"]]))[0, 0]
    period = tracker.wavelength
    offset = last["measurement"][0] - last["measurement_true"][0]
    state[-2] = 0.0 if period is None else period * np.round(offset / period)
    state[-1] = env.config.source.range_rate_bias
    return state


def oracle_error(env: AASLEnv, initial: SourceState, last: dict) -> float:
    """After an episode of ``env`` (``initial`` the source's start, ``last`` the last step's info): the position
    error (m) at the end of the whole track's MAP fit (:meth:`aasl_gym.estimator.SourceTracker.fit_kept_track`)
    started at the truth and at the tracker's estimate, the fit that explains the track better. An estimator that
    never has to search for its basin ends there; the bound's Gaussian approximates it."""
    tracker = env.tracker
    truth = true_state(env, initial, last)
    starts = np.stack([truth, tracker.ukf.x]) if tracker.initialized else truth[None]
    fit = tracker.fit_kept_track(starts)
    best = int(np.argmin(fit.costs))
    return float(np.linalg.norm(fit.states[best, 0:3] - truth[0:3]))


def print_table(header: list[str], rows, out: str | None) -> None:
    """Print a markdown table row by row as ``rows`` yields them (long jobs show progress), then write it to ``out``."""
    lines = list(header)
    print(lines[0], flush=True)
    for line in rows:
        print(line, flush=True)
        lines.append(line)
    if out:
        atomic_write_text(out, "\n".join(lines) + "\n")


def episode_rmse_bound(covariance: np.ndarray, dt: float, start: float) -> float:
    """The bound on an episode's RMSE (m) over the steps from time ``start`` (s) on: the root of the mean
    trace of ``covariance`` (steps, 3, 3; m^2), the bound after each step of ``dt`` s."""
    times = dt * np.arange(1, len(covariance) + 1)
    kept = covariance[times >= start - 1e-9]
    return float(np.sqrt(np.mean(np.trace(kept, axis1=1, axis2=2))))


def navigation_config(base: EnvConfig, level: float) -> EnvConfig:
    """``base`` with a navigation error of sd ``level`` (m; velocity sd from the config's ratio) and R_eff."""
    receiver = {"nav_position_sd": level, "nav_velocity_sd": None}
    return base.replace(receiver=receiver, filter={"compensate_navigation": True})


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--motions", nargs="+", default=["static", "cv", "ca", "ctrv"], choices=["static", "cv", "ca", "ctrv"]
    )
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1000)
    add_scenario_arguments(parser)
    parser.add_argument("--target", type=float, default=0.5, help="bound on the position error sd, m")
    parser.add_argument(
        "--model",
        choices=["direct", "matched"],
        default="direct",
        help="measurement model: the direct path, or the world's own (phasor with reflections)",
    )
    parser.add_argument(
        "--nav-sd",
        type=float,
        nargs="+",
        default=None,
        help="navigation error levels sigma_rov (m, >= 0; with --model matched): one row per motion and level",
    )
    parser.add_argument("--patrol", default="helix", choices=sorted(REFERENCES), help="the scripted patrol")
    parser.add_argument("--out", default=None, help="markdown file for the table")
    parser.add_argument(
        "--tracker",
        action="store_true",
        help="run the config's tracker (its initializer, the filter matched to the motion) beside the bound",
    )
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="with --tracker: the whole track's MAP fit started at the truth, within --target at the end",
    )
    args = parser.parse_args(argv)
    if args.oracle and not args.tracker:
        parser.error("--oracle fits the tracker's kept track: it needs --tracker")
    if args.nav_sd is not None:
        if args.model != "matched":
            parser.error("--nav-sd: the navigation error enters R_eff only with --model matched")
        if any(not np.isfinite(level) or level < 0 for level in args.nav_sd):
            parser.error(f"--nav-sd: levels must be finite and >= 0 m, got {args.nav_sd}")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_arguments(argv)
    base = command_line_config(args.scenario, args.config, "configs/initializer_study.yaml")
    levels = [None] if args.nav_sd is None else args.nav_sd
    tracker_columns = (
        f" tracker's success at {args.target} m | an efficient estimator's chance of as few |"
        " its RMSE after convergence / the bound's |"
    )
    oracle_column = f" the whole track's MAP from the truth within {args.target} m at the end |"
    navigation = args.nav_sd is not None
    header = [
        ("| motion | sigma_rov (m) |" if navigation else "| motion |")
        + f" episodes | bound < {args.target} m to the end | median first time (s) "
        f"| efficient estimator within {args.target} m at the end | its count, 90 % range |"
        + (" bound's RMSE from the burst on (m) |" if navigation else "")
        + (tracker_columns if args.tracker else "")
        + (oracle_column if args.oracle else ""),
        ("|---|---|" if navigation else "|---|")
        + "---|---|---|---|---|"
        + ("---|" if navigation else "")
        + ("---|---|---|" if args.tracker else "")
        + ("---|" if args.oracle else ""),
    ]
    rng = np.random.default_rng(args.seed)

    def rows():
        for motion in args.motions:
            for level in levels:
                config = base if level is None else navigation_config(base, level)
                yield motion_row(args, config, motion, level, rng)

    print_table(header, rows(), args.out)


def bound_env(base: EnvConfig, motion: str, patrol: str) -> AASLEnv:
    """The env whose episodes :func:`episode_covariance` bounds: ``base`` with ``motion``'s sources, flown by ``patrol``
    (the bound needs no tracker: the naive initializer, the cheapest)."""
    return AASLEnv(base.replace(source={"motion": motion}, initializer={"name": "naive"}), patrol=patrol)


def motion_row(args: argparse.Namespace, base: EnvConfig, motion: str, level: float | None, rng) -> str:
    """One table row: the bound (and the tracker, with ``--tracker``) over the episodes of ``motion``."""
    env = bound_env(base, motion, args.patrol)
    if args.tracker:
        matched = base.replace(source={"motion": motion}, filter={"motion_model": MATCHED[motion]})
        tracker_env = AASLEnv(matched, patrol=args.patrol)
        if args.oracle and tracker_env.tracker.track_length == 0:
            raise SystemExit("--oracle: the tracker keeps no whole track here (filter.track_fit is off)")
    times, efficient, successes, squared, rmse_bounds, oracle = [], [], [], np.zeros(2), [], []
    for seed in tqdm(range(args.seed, args.seed + args.episodes), desc=motion, unit="ep", leave=False):
        covariance = episode_covariance(env, seed, args.model)
        if args.tracker:
            initial, infos = run_tracker(tracker_env, seed)
            success, squares = tracked_squares(infos, covariance, args.target)
            successes.append(success)
            squared += squares
            if args.oracle:
                oracle.append(oracle_error(tracker_env, initial, infos[-1]) < args.target)
        bound = np.sqrt(np.trace(covariance, axis1=1, axis2=2))
        above = np.nonzero(bound >= args.target)[0]
        last_above = above[-1] if len(above) else -1
        times.append((last_above + 2) * env.dt if last_above + 1 < len(bound) else np.inf)
        efficient.append(efficient_success(covariance[-1], args.target, rng))
        rmse_bounds.append(episode_rmse_bound(covariance, env.dt, base.initializer.burst_duration))
    times = np.array(times)
    reached = np.isfinite(times)
    median = np.median(times[reached]) if reached.any() else float("nan")
    line = f"| {motion} |" + ("" if level is None else f" {level:g} |")
    low, high = efficient_count_range(efficient)
    line += f" {len(times)} | {reached.mean():.0%} | {median:.1f} | {np.mean(efficient):.0%} | {low}-{high} |"
    if level is not None:
        line += f" {np.mean(rmse_bounds):.2f} |"
    if args.tracker:
        chance = as_few_chance(efficient, int(np.sum(successes)))
        line += f" {np.mean(successes):.0%} | {chance:.0%} | {np.sqrt(squared[0] / squared[1]):.2f} |"
    if args.oracle:
        line += f" {np.mean(oracle):.0%} |"
    return line


if __name__ == "__main__":
    main()
