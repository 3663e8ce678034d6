"""Compare patrol policies and initializers on the same seeds; write report.md, results.json and plots.

Each finished episode is also appended to OUT/episodes.jsonl; ``--resume`` continues an interrupted
run from it.

Every policy x initializer x motion combination runs the episodes with seeds S, S+1, ..., so the
comparisons are paired. Example (the reference paper's initializer study):

    python evaluate.py --policies helix --initializers lcmap naive random tdoa-ls \\
        --motions static cv ca ctrv --episodes 100 --reflections off --out reports/initializers
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import shlex
import sys
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from aasl_gym.config import INITIALIZERS, MEASUREMENT_MODES, MULTIPATH_MODELS, ConfigError, EnvConfig, load_config, to_dict
from aasl_gym.io import atomic_write, atomic_write_json, atomic_write_text
from aasl_gym.metrics import SUCCESS_THRESHOLDS
from agents import POLICIES as SCRIPTED_POLICIES  # what agents.make_policy builds by name

MOTIONS = ("static", "cv", "ca", "ctrv", "mixed")
FILTER_CHOICES = ("cv", "ca", "ctrv", "matched")
MATCHED_FILTER = {"static": "cv", "cv": "cv", "ca": "ca", "ctrv": "ctrv", "mixed": "cv"}


@dataclass(frozen=True)
class Job:
    policy: str
    initializer: str
    motion: str
    measurement: str
    seed: int
    config: dict
    filter_model: str | None
    record: bool = False  # keep the episode's paths for the trajectory plots


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", default=["helix", "spiral", "greedy"], help=f"{' '.join(SCRIPTED_POLICIES)}, or ALGO:PATH")
    parser.add_argument("--motions", nargs="+", default=["static", "cv", "ca", "ctrv"], choices=MOTIONS)
    parser.add_argument("--initializers", nargs="+", default=["lcmap"], choices=INITIALIZERS)
    parser.add_argument("--episodes", type=int, default=10, help="episodes per combination (seeds S .. S+N-1)")
    parser.add_argument("--seed", type=int, default=1000, help="first seed")
    parser.add_argument("--measurement", choices=MEASUREMENT_MODES, default=None, help="default: the config's")
    parser.add_argument("--reflections", choices=("on", "off"), default=None, help="surface/bed paths in the world")
    parser.add_argument("--multipath", choices=MULTIPATH_MODELS, default=None, help="the filter's multipath model")
    parser.add_argument("--filter-model", choices=FILTER_CHOICES, default=None,
                        help="filter motion model; 'matched' uses cv for static/cv, ca for ca, ctrv for ctrv")
    parser.add_argument("--config", type=Path, default=None, help="YAML config (default: configs/default.yaml)")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: every core this process may use)")
    parser.add_argument("--backend", choices=("process", "ray"), default="process",
                        help="process: a local process pool; ray: Ray tasks (pip install -e '.[distributed]')")
    parser.add_argument("--ray-address", default=None, help="a Ray cluster to join (default: start Ray locally with --workers CPUs)")
    parser.add_argument("--out", type=Path, default=Path("results/evaluation"))
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--trajectories", type=int, default=2, help="episodes per policy and motion drawn in top and depth views")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the episodes already in OUT/episodes.jsonl (an interrupted run with the same config; "
                             "models are trusted to be unchanged at their paths)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.trajectories < 0:
        parser.error(f"--trajectories must be >= 0, got {args.trajectories}")
    if args.workers is None:
        args.workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if args.ray_address is not None and args.backend != "ray":
        parser.error("--ray-address needs --backend ray")
    for policy in args.policies:
        if ":" not in policy and policy not in SCRIPTED_POLICIES:
            parser.error(f"--policies: unknown policy {policy!r}; allowed: {' '.join(SCRIPTED_POLICIES)}, or ALGO:PATH")
    return args


def default_config_path() -> Path:
    return Path(__file__).resolve().parent / "configs" / "default.yaml"


@lru_cache(maxsize=8)
def _model(spec: str):
    from agents.sb3 import load_model

    return load_model(spec)


def run_episode(job: Job) -> dict[str, Any]:
    """One episode; returns its results row. Scripted policies fly ``AASL-v0``; a trained model flies
    the env it was trained on (a residual model needs its patrol's command), with the same source,
    noise and metrics for the same seed."""
    from agents import make_policy
    from agents.rollout import play_episode
    from aasl_gym.env import AASLEnv
    from aasl_gym.registration import ENV_IDS

    policy = _model(job.policy) if ":" in job.policy else None
    patrol = ENV_IDS[policy.env_id] if policy is not None else None
    env = AASLEnv(job.config, source_motion=job.motion, initializer=job.initializer, measurement=job.measurement,
                  filter_model=job.filter_model, patrol=patrol)
    if policy is None:
        policy = make_policy(job.policy, env.config, seed=job.seed)
    info = play_episode(env, policy, job.seed)
    env.close()

    def number(value) -> float | None:
        value = float(value)
        return value if math.isfinite(value) else None

    row = {
        "policy": job.policy,
        "initializer": job.initializer,
        "motion": job.motion,
        "source_motion": env.source.kind,
        "measurement": job.measurement,
        "seed": job.seed,
        "convergence_time": number(info["convergence_time"]),
        "success": info["success"],
        "rmse": number(info["rmse"]),
        "final_error": number(info["final_error"]),
        "time_to_first_estimate": number(info["time_to_first_estimate"]),
        "reinitializations": int(info["reinitializations"]),
    }
    if job.record:
        row["trajectory"] = {name: np.asarray(points).tolist() for name, points in env.trajectory.items()}
    return row


def mean_ci95(values: np.ndarray) -> tuple[float | None, list[float | None]]:
    """Mean and a 95 % Student-t confidence interval (None where it cannot be computed)."""
    from scipy import stats

    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return None, [None, None]
    mean = float(values.mean())
    if values.size < 2:
        return mean, [None, None]
    half = float(stats.t.ppf(0.975, values.size - 1) * values.std(ddof=1) / np.sqrt(values.size))
    return mean, [mean - half, mean + half]


def summarize(rows: list[dict[str, Any]], duration: float) -> list[dict[str, Any]]:
    keys = sorted({(r["policy"], r["initializer"], r["motion"], r["measurement"]) for r in rows}, key=str)
    summary = []
    for policy, initializer, motion, measurement in keys:
        group = [r for r in rows if (r["policy"], r["initializer"], r["motion"], r["measurement"]) == (policy, initializer, motion, measurement)]
        times = np.array([r["convergence_time"] for r in group if r["convergence_time"] is not None])
        censored = np.array([duration if r["convergence_time"] is None else r["convergence_time"] for r in group])
        mean, ci = mean_ci95(times)
        rmses = [r["rmse"] for r in group if r["rmse"] is not None]
        finals = [r["final_error"] for r in group if r["final_error"] is not None]
        summary.append({
            "policy": policy, "initializer": initializer, "motion": motion, "measurement": measurement,
            "n": len(group),
            "success_rate": {k: float(np.mean([r["success"][k] for r in group])) for k in group[0]["success"]},
            "mean_convergence_time": mean,
            "convergence_time_ci95": ci,
            "mean_convergence_time_censored": float(censored.mean()),
            "rmse_median": float(np.median(rmses)) if rmses else None,
            "final_error_median": float(np.median(finals)) if finals else None,
            "mean_reinitializations": float(np.mean([r["reinitializations"] for r in group])),
        })
    return summary


def paired_comparisons(rows: list[dict[str, Any]], duration: float, field: str, baseline: str) -> list[dict[str, Any]]:
    """Per motion, each ``field`` value (policy or initializer) against ``baseline`` on shared seeds.

    Convergence times are compared two ways: on the seeds where both converged (ratio of means), and
    with a non-converged episode counted as the full duration (censored).
    """
    out = []
    index = {(r[field], r["motion"], r["seed"], r["policy"] if field == "initializer" else r["initializer"]): r for r in rows}
    others = sorted({r[field] for r in rows} - {baseline})
    for motion in sorted({r["motion"] for r in rows}):
        for other in others:
            pairs = [(index[(other, m, s, k)], index[(baseline, m, s, k)]) for (f, m, s, k) in index
                     if f == other and m == motion and (baseline, m, s, k) in index]
            if not pairs:
                continue
            both = [(a["convergence_time"], b["convergence_time"]) for a, b in pairs if a["convergence_time"] is not None and b["convergence_time"] is not None]
            censored = np.array([[duration if a["convergence_time"] is None else a["convergence_time"],
                                  duration if b["convergence_time"] is None else b["convergence_time"]] for a, b in pairs])
            diff_mean, diff_ci = mean_ci95(censored[:, 0] - censored[:, 1])
            both = np.array(both).reshape(-1, 2)
            out.append({
                field: other, "baseline": baseline, "motion": motion, "pairs": len(pairs), "both_converged": len(both),
                "time_ratio_both": float(both[:, 0].mean() / both[:, 1].mean()) if len(both) and both[:, 1].mean() > 0 else None,
                "time_ratio_censored": float(censored[:, 0].mean() / censored[:, 1].mean()),
                "time_difference_censored": diff_mean, "time_difference_censored_ci95": diff_ci,
                "success_difference_1m": float(np.mean([a["success"]["1.0"] for a, _ in pairs]) - np.mean([b["success"]["1.0"] for _, b in pairs])),
            })
    return out


def _fmt(value, digits: int = 1) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}"


def plain_summary(summary: list[dict]) -> list[str]:
    """A few sentences on what the summary table says: per motion, which combination found the source
    (to within 1 m, and kept it) most often against the others; the re-initializations; how far a
    share at this many episodes can be trusted."""
    several_initializers = len({s["initializer"] for s in summary}) > 1
    label = (lambda s: f"{s['policy']} with {s['initializer']}") if several_initializers else (lambda s: s["policy"])
    sentences = []
    for motion in dict.fromkeys(s["motion"] for s in summary):
        rows = [s for s in summary if s["motion"] == motion]
        best = max(rows, key=lambda s: (s["success_rate"]["1.0"], -(s["mean_convergence_time_censored"] or math.inf)))
        others = ", ".join(f"{label(s)} {s['success_rate']['1.0']:.0%}" for s in rows if s is not best)
        sentences.append(f"{motion.upper() if motion != 'static' else 'Static'} sources: {label(best)} found and kept the source "
                         f"to within 1 m in {best['success_rate']['1.0']:.0%} of {best['n']} episode{'s' * (best['n'] != 1)}" + (f" ({others})." if others else "."))
    busiest = max(summary, key=lambda s: s["mean_reinitializations"])
    sentences.append(f"The tracker re-initialized {min(s['mean_reinitializations'] for s in summary):.1f}-"
                     f"{busiest['mean_reinitializations']:.1f} times per episode on average (most: {label(busiest)}, {busiest['motion']}).")
    fewest = min(s["n"] for s in summary)
    sentences.append(f"With {fewest} episodes per combination a success share is known to about "
                     f"+-{98 / math.sqrt(fewest):.0f} points (95 %); smaller differences may be chance.")
    return ["In short: " + " ".join(sentences), ""]


def write_report(path: Path, command: str, config: EnvConfig, summary: list[dict], comparisons: dict[str, list[dict]], plots: list[str]) -> None:
    if config.measurement.mode == "geometric":
        measurements = f"Measurement noise: sigma_R = {config.measurement.range_difference_sd} m, sigma_V = {config.measurement.range_rate_difference_sd} m/s; "
    else:
        measurements = (f"Measurements: the acoustic front end ({config.signal.path} path, {config.signal.frame_duration} s frames, source level "
                        f"{config.source.source_level_db} dB, noise level {config.world.noise_level_db} dB; R from each frame's SNR); ")
    lines = [
        "# AASL-Gym evaluation", "",
        *plain_summary(summary),
        f"Command: `{command}`", "",
        measurements +
        f"navigation sigma_rov = {config.receiver.nav_position_sd} m; reflections {'on' if config.world.reflections else 'off'}; "
        f"filter multipath model `{config.filter_multipath}`; episode {config.episode.duration:.0f} s at {config.measurement.rate:.0f} Hz.", "",
        "Convergence time: first time the error falls below 1 m and stays below to the end; its mean and 95 % CI are over "
        "the episodes that converged, the censored mean counts a non-converged episode as the full duration. "
        "Success at a threshold: the error converged below it within the episode.", "",
        "## Summary", "",
        "| policy | initializer | motion | n | success 0.5 m | success 1 m | success 3 m | mean conv. time (s) [95 % CI] | censored mean (s) | median RMSE (m) | median final error (m) | re-inits |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        ci = s["convergence_time_ci95"]
        lines.append(
            f"| {s['policy']} | {s['initializer']} | {s['motion']} | {s['n']} | {s['success_rate']['0.5']:.0%} | {s['success_rate']['1.0']:.0%} | "
            f"{s['success_rate']['3.0']:.0%} | {_fmt(s['mean_convergence_time'])} [{_fmt(ci[0])}, {_fmt(ci[1])}] | {_fmt(s['mean_convergence_time_censored'])} | "
            f"{_fmt(s['rmse_median'], 2)} | {_fmt(s['final_error_median'], 2)} | {s['mean_reinitializations']:.1f} |"
        )
    for field, rows in comparisons.items():
        if not rows:
            continue
        plural = {"policy": "policies", "initializer": "initializers"}[field]
        lines += ["", f"## Paired comparison of {plural} against `{rows[0]['baseline']}` (same seeds)", "",
                  f"| {field} | motion | pairs | both converged | time ratio (both converged) | time ratio (censored) | time difference (censored) [95 % CI] (s) | success 1 m difference |",
                  "|---|---|---|---|---|---|---|---|"]
        for c in rows:
            ci = c["time_difference_censored_ci95"]
            lines.append(f"| {c[field]} | {c['motion']} | {c['pairs']} | {c['both_converged']} | {_fmt(c['time_ratio_both'], 2)} | {_fmt(c['time_ratio_censored'], 2)} | "
                         f"{_fmt(c['time_difference_censored'])} [{_fmt(ci[0])}, {_fmt(ci[1])}] | {c['success_difference_1m']:+.0%} |")
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    atomic_write_text(path, "\n".join(lines) + "\n")


def write_plots(out: Path, rows: list[dict], summary: list[dict]) -> list[str]:
    from matplotlib.figure import Figure

    def save(figure: Figure, name: str) -> str:
        atomic_write(out / name, lambda tmp: figure.savefig(tmp, dpi=110, bbox_inches="tight", format="png"))
        return name

    names = []
    groups = sorted({(s["policy"], s["initializer"]) for s in summary}, key=str)
    motions = sorted({s["motion"] for s in summary}, key=lambda m: MOTIONS.index(m) if m in MOTIONS else 99)
    figure = Figure(figsize=(max(6, 2.2 * len(motions)), 4))
    ax = figure.subplots()
    width = 0.8 / max(1, len(groups))
    for g, (policy, initializer) in enumerate(groups):
        data = [[r["convergence_time"] for r in rows if (r["policy"], r["initializer"], r["motion"]) == (policy, initializer, m) and r["convergence_time"] is not None] for m in motions]
        positions = np.arange(len(motions)) + (g - (len(groups) - 1) / 2) * width
        filled = [d if d else [np.nan] for d in data]
        parts = ax.boxplot(filled, positions=positions, widths=width * 0.9, patch_artist=True, manage_ticks=False)
        colour = f"C{g}"
        for box in parts["boxes"]:
            box.set_facecolor(colour)
            box.set_alpha(0.6)
        ax.plot([], [], color=colour, lw=6, alpha=0.6, label=f"{policy} / {initializer}")
    ax.set_xticks(np.arange(len(motions)), motions)
    ax.set_ylabel("convergence time to 1 m (s), converged episodes")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # outside: boxes fill the axes
    ax.grid(alpha=0.3)
    names.append(save(figure, "convergence_time.png"))

    figure = Figure(figsize=(max(6, 3 * len(motions)), 3.5))
    axes = np.atleast_1d(figure.subplots(1, len(motions), sharey=True))
    thresholds = [str(float(t)) for t in SUCCESS_THRESHOLDS]
    for ax, motion in zip(axes, motions):
        for g, (policy, initializer) in enumerate(groups):
            match = [s for s in summary if (s["policy"], s["initializer"], s["motion"]) == (policy, initializer, motion)]
            if match:
                ax.plot(SUCCESS_THRESHOLDS, [match[0]["success_rate"][t] for t in thresholds], "o-", color=f"C{g}", label=f"{policy} / {initializer}")
        ax.set_xscale("log")
        ax.set_xticks(SUCCESS_THRESHOLDS, [f"{t:g}" for t in SUCCESS_THRESHOLDS])
        ax.set_title(motion)
        ax.set_xlabel("threshold (m)")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("success rate within the episode")
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    names.append(save(figure, "success_vs_threshold.png"))
    return names


def write_trajectory_plots(out: Path, trajectories: list[tuple[str, str, int, dict]], config: EnvConfig) -> list[str]:
    """One figure per motion: for each recorded episode (policy, seed) the top and depth views of the
    robot's path, the source's and the estimate's (``aasl_gym.render.draw_episode``)."""
    from matplotlib.figure import Figure

    from aasl_gym.render import draw_episode

    names = []
    fixed = np.asarray(config.world.fixed_position, dtype=float)
    for motion in sorted({t[1] for t in trajectories}, key=lambda m: MOTIONS.index(m) if m in MOTIONS else 99):
        episodes = sorted((t for t in trajectories if t[1] == motion), key=lambda t: (t[0], t[2]))
        figure = Figure(figsize=(10, 4.2 * len(episodes)))
        for panel, (policy, _, seed, paths) in zip(np.atleast_1d(figure.subfigures(len(episodes), 1)), episodes):
            draw_episode(panel, paths, fixed, None, config.episode.duration, config, title=f"{policy}, {motion} source, seed {seed}")
        name = f"trajectories_{motion}.png"
        atomic_write(out / name, lambda tmp: figure.savefig(tmp, dpi=80, bbox_inches="tight", format="png"))
        names.append(name)
    return names


def build_jobs(args: argparse.Namespace, config: EnvConfig) -> list[Job]:
    data = to_dict(config)
    if args.reflections is not None:
        data["world"]["reflections"] = args.reflections == "on"
    if args.multipath is not None:
        data["filter"]["multipath"] = args.multipath
    measurement = args.measurement or config.measurement.mode
    jobs = []
    for motion in args.motions:
        filter_model = MATCHED_FILTER[motion] if args.filter_model == "matched" else args.filter_model
        for policy in args.policies:
            for initializer in args.initializers:
                for seed in range(args.seed, args.seed + args.episodes):
                    record = not args.no_plots and initializer == args.initializers[0] and seed < args.seed + args.trajectories
                    jobs.append(Job(policy, initializer, motion, measurement, seed, data, filter_model, record))
    return jobs


def episode_key(job: Job) -> tuple:
    return (job.policy, job.initializer, job.motion, job.measurement, job.seed, job.filter_model)


def read_episode_log(path: Path, header: dict) -> dict[tuple, dict]:
    """The rows of an earlier run's ``episodes.jsonl`` by episode key; a config other than ``header``'s
    is an error. A torn last line (the run killed mid-write) is skipped: that episode runs again."""
    if not path.is_file():
        return {}
    lines = path.read_text().splitlines()
    try:
        written = json.loads(lines[0])["config"]
    except (IndexError, KeyError, TypeError, json.JSONDecodeError):
        raise ConfigError(f"--resume: {path} does not start with a config line; run without --resume or with another --out") from None
    if written != header["config"]:
        sections = sorted(k for k in set(written) | set(header["config"]) if written.get(k) != header["config"].get(k))
        raise ConfigError(f"--resume: {path} was written with another config (sections {sections} differ); "
                          "run without --resume or with another --out")
    done = {}
    for line in lines[1:]:
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        done[tuple(entry["key"])] = entry["row"]
    return done


@contextmanager
def episode_runner(args: argparse.Namespace, needed: bool):
    """A function that runs jobs and yields their rows in the jobs' order: in this process, on a pool of
    ``--workers`` fresh processes, or as Ray tasks (``--backend ray``, on ``--ray-address`` or a local
    Ray with ``--workers`` CPUs). Every episode runs from its own seed, so the rows are the same."""
    if args.backend == "ray" and needed:
        try:
            import ray
        except ImportError:
            print("error: --backend ray needs Ray: pip install -e '.[distributed]'", file=sys.stderr)
            raise SystemExit(2) from None
        started = not ray.is_initialized()
        if started:
            # The workers import this file's module and the project's packages from the project root: a
            # cluster gets a copy of it (Ray's working_dir), a local Ray the path.
            root = str(Path(__file__).resolve().parent)
            if args.ray_address:
                excludes = [".git", ".venv", ".ci-venv", "results", "runs", "reports"]
                options = {"address": args.ray_address, "runtime_env": {"working_dir": root, "excludes": excludes}}
            else:
                options = {"num_cpus": args.workers, "include_dashboard": False, "runtime_env": {"env_vars": {"PYTHONPATH": root}}}
            ray.init(log_to_driver=False, **options)
        task = ray.remote(num_cpus=1)(run_episode)
        try:
            yield lambda jobs: (ray.get(ref) for ref in [task.remote(job) for job in jobs])
        finally:
            if started:
                ray.shutdown()
        return
    # Fresh worker processes, not forks: a fork of a parent that has run torch (the models are loaded
    # here to check them) can hang in torch's thread pool - a recurrent policy's workers never finished.
    pool = ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) if args.workers > 1 and needed else None
    try:
        yield (lambda jobs: pool.map(run_episode, jobs, chunksize=4)) if pool else (lambda jobs: map(run_episode, jobs))
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from tqdm import tqdm

    config_path = args.config or default_config_path()
    try:
        config = load_config(config_path)
    except ConfigError as exc:
        print(f"error: --config: {exc}", file=sys.stderr)
        return 2
    for policy in args.policies:
        if ":" in policy:
            try:
                _model(policy)
            except (ValueError, FileNotFoundError, ImportError) as exc:
                print(f"error: --policies: {exc}", file=sys.stderr)
                return 2
    jobs = build_jobs(args, config)
    try:  # validate the overrides once, before any worker starts
        from aasl_gym.env import resolve_config

        resolve_config(jobs[0].config, measurement=jobs[0].measurement, filter_model=jobs[0].filter_model)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    command = "python evaluate.py " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    args.out.mkdir(parents=True, exist_ok=True)
    # Every finished episode is appended to episodes.jsonl at once, so a long evaluation that is
    # interrupted loses nothing: --resume runs only what is missing.
    log_path = args.out / "episodes.jsonl"
    header = {"config": json.loads(json.dumps(jobs[0].config))}
    try:
        done = read_episode_log(log_path, header) if args.resume else {}
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    todo = [job for job in jobs if episode_key(job) not in done]
    if not done:
        atomic_write_text(log_path, json.dumps(header) + "\n")
    print(f"{len(jobs)} episodes: {len(args.policies)} policies x {len(args.initializers)} initializers x {len(args.motions)} motions x {args.episodes} seeds"
          + (f" ({len(jobs) - len(todo)} from {log_path})" if done else ""))
    with open(log_path, "a") as log, tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="episodes", unit="ep") as progress:
        with episode_runner(args, bool(todo)) as run_all:
            for job, row in zip(todo, run_all(todo)):
                log.write(json.dumps({"key": episode_key(job), "row": row}) + "\n")
                log.flush()
                done[episode_key(job)] = row
                progress.update()
    rows = [done[episode_key(job)] for job in jobs]
    trajectories = [(row["policy"], row["motion"], row["seed"], row.pop("trajectory")) for row in rows if "trajectory" in row]
    summary = summarize(rows, config.episode.duration)
    comparisons = {}
    if len(args.initializers) > 1:
        baseline = "naive" if "naive" in args.initializers else args.initializers[0]
        comparisons["initializer"] = paired_comparisons(rows, config.episode.duration, "initializer", baseline)
    if len(args.policies) > 1:
        baseline = "helix" if "helix" in args.policies else args.policies[0]
        comparisons["policy"] = paired_comparisons(rows, config.episode.duration, "policy", baseline)
    # The config the episodes ran with: the file's, with the command line's world, filter and measurement mode.
    effective = config.replace(world=jobs[0].config["world"], filter=jobs[0].config["filter"], measurement={"mode": jobs[0].measurement})
    plots = [] if args.no_plots else write_plots(args.out, rows, summary) + write_trajectory_plots(args.out, trajectories, effective)
    atomic_write_json(args.out / "results.json", {"command": command, "config": to_dict(effective), "episodes": rows, "summary": summary, "comparisons": comparisons})
    write_report(args.out / "report.md", command, effective, summary, comparisons, plots)
    width = max(len("policy"), *(len(s["policy"]) for s in summary))  # a model's name carries its path
    print(f"\n{'policy':<{width}} {'initializer':<11} {'motion':<7} {'n':>4} {'succ@1m':>8} {'conv (s)':>9} {'RMSE med':>9}")
    for s in summary:
        print(f"{s['policy']:<{width}} {s['initializer']:<11} {s['motion']:<7} {s['n']:>4} {s['success_rate']['1.0']:>8.0%} "
              f"{_fmt(s['mean_convergence_time']):>9} {_fmt(s['rmse_median'], 2):>9}")
    print(f"\nwrote {args.out / 'report.md'}, {args.out / 'results.json'}" + (f" and {len(plots)} plots" if plots else ""))
    return 0


if __name__ == "__main__":
    # Run as the module ``evaluate``, not ``__main__``, so that a Ray worker can unpickle its jobs.
    import evaluate

    sys.exit(evaluate.main())
