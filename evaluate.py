"""Compare patrol policies and initializers on the same seeds; write report.md, results.json and plots.

Each finished episode is also appended to OUT/episodes.jsonl; ``--resume`` continues an interrupted
run from it.

Every policy x initializer x motion combination runs the episodes with seeds S, S+1, ..., so the
comparisons are paired. Example (the reference paper's initializer study):

    python evaluate.py --policies helix --initializers lcmap naive random tdoa-ls \\
        --motions static cv ca ctrv --episodes 100 --reflections off --out reports/initializers

Scripted policies and models trained on a single-pod id fly one pod. A facility (``--scenario facility``) runs on
AASL-Facility-v0: its own patrol is the policy ``facility`` (the default there), and a model trained on that id
flies it too; a policy that does not fit the config's pods is refused by name.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from aasl_gym.config import INITIALIZERS, MEASUREMENT_MODES, MULTIPATH_MODELS, ConfigError, EnvConfig
from aasl_gym.registration import FACILITY_ID, check_env_fits
from aasl_gym.scenarios import add_scenario_arguments, command_line_config
from aasl_gym.study.jobs import (
    FACILITY_PATROL,
    FILTER_CHOICES,
    MOTIONS,
    Job,
    StudyGrid,
    build_jobs,
    check_overrides,
    effective_config,
    episode_key,
    filter_motion_models,
)
from aasl_gym.study.log import EpisodeLog, LogMismatch
from aasl_gym.study.plots import pop_trajectories, write_plots, write_trajectory_plots
from aasl_gym.study.report import console_table, write_report, write_results
from aasl_gym.study.runner import (
    Backend,
    MissingBackend,
    add_backend_arguments,
    check_backend_arguments,
    run_jobs,
)
from aasl_gym.study.stats import study_comparisons, summarize
from agents import POLICIES as SCRIPTED_POLICIES  # what agents.make_policy builds by name
from agents.study import run_episode, trained_model

ROOT = Path(__file__).resolve().parent
SINGLE_POD_POLICIES = ["helix", "spiral", "greedy"]  # the default policies of a single-pod world
POLICY_NAMES = (*SCRIPTED_POLICIES, FACILITY_PATROL)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add = parser.add_argument
    add(
        "--policies",
        nargs="+",
        default=None,
        help=f"{' '.join(POLICY_NAMES)}, or ALGO:PATH (default: {' '.join(SINGLE_POD_POLICIES)}; "
        f"in a facility, {FACILITY_PATROL})",
    )
    add("--motions", nargs="+", default=["static", "cv", "ca", "ctrv"], choices=MOTIONS)
    add("--initializers", nargs="+", default=["lcmap"], choices=INITIALIZERS)
    add("--episodes", type=int, default=10, help="episodes per combination (seeds S .. S+N-1)")
    add("--seed", type=int, default=1000, help="first seed")
    add("--measurement", choices=MEASUREMENT_MODES, default=None, help="default: the config's")
    add("--reflections", choices=("on", "off"), default=None, help="surface/bed paths in the world")
    add("--multipath", choices=MULTIPATH_MODELS, default=None, help="the filter's multipath model")
    add(
        "--filter-model",
        choices=FILTER_CHOICES,
        default=None,
        help="filter motion model; 'matched' uses cv for static/cv, ca for ca, ctrv for ctrv",
    )
    add_scenario_arguments(parser)
    add_backend_arguments(parser)
    add("--out", type=Path, default=Path("results/evaluation"))
    add("--no-plots", action="store_true")
    add("--trajectories", type=int, default=2, help="episodes per policy and motion drawn in top and depth views")
    add(
        "--resume",
        action="store_true",
        help="reuse the episodes already in OUT/episodes.jsonl (an interrupted run with the same config; "
        "models are trusted to be unchanged at their paths)",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.seed < 0:
        parser.error(f"--seed must be >= 0 (Gymnasium's seeds), got {args.seed}")
    if args.trajectories < 0:
        parser.error(f"--trajectories must be >= 0, got {args.trajectories}")
    check_backend_arguments(parser, args)
    for policy in args.policies or ():
        if ":" not in policy and policy not in POLICY_NAMES:
            parser.error(f"--policies: unknown policy {policy!r}; allowed: {' '.join(POLICY_NAMES)}, or ALGO:PATH")
    return args


def default_config_path() -> Path:
    return ROOT / "configs" / "default.yaml"


def study_grid(args: argparse.Namespace) -> StudyGrid:
    reflections = None if args.reflections is None else args.reflections == "on"
    return StudyGrid(
        tuple(args.policies),
        tuple(args.initializers),
        tuple(args.motions),
        args.episodes,
        args.seed,
        measurement=args.measurement,
        reflections=reflections,
        multipath=args.multipath,
        filter_model=args.filter_model,
        trajectories=0 if args.no_plots else args.trajectories,
    )


def policy_env(policy: str) -> str:
    """The env id ``policy`` flies: a trained model's own (loaded here, its errors named), the facility's for its
    patrol, AASL-v0 for the scripted ones (:func:`agents.study.run_episode`)."""
    if ":" in policy:
        try:
            return trained_model(policy).env_id
        except (ValueError, FileNotFoundError, ImportError) as exc:
            raise ConfigError(f"--policies: {exc}") from exc
    return FACILITY_ID if policy == FACILITY_PATROL else "AASL-v0"


def prepare(args: argparse.Namespace) -> tuple[EnvConfig, list[Job]]:
    """The config and the jobs; a :class:`ConfigError` carries the message for bad input."""
    config = command_line_config(args.scenario, args.config, default_config_path())
    if args.policies is None:
        args.policies = [FACILITY_PATROL] if config.facility.pods > 1 else list(SINGLE_POD_POLICIES)
    remedy = f" (--policies {FACILITY_PATROL}, or a model trained on it)"
    for policy in args.policies:
        check_env_fits(policy_env(policy), config, f"--policies {policy}", remedy)
    jobs = build_jobs(study_grid(args), config)
    check_overrides(jobs[0])  # once, before any worker starts: the error names the override
    return config, jobs


def run(args: argparse.Namespace, jobs: list[Job]) -> list[dict]:
    """Every job's row: from the log of an earlier run with ``--resume``, the rest run now."""
    from tqdm import tqdm

    args.out.mkdir(parents=True, exist_ok=True)
    log = EpisodeLog(args.out / "episodes.jsonl", jobs[0].config)
    done = log.open(args.resume)
    reused = sum(episode_key(job) in done for job in jobs)
    print(
        f"{len(jobs)} episodes: {len(args.policies)} policies x {len(args.initializers)} initializers x "
        f"{len(args.motions)} motions x {args.episodes} seeds" + (f" ({reused} from {log.path})" if done else "")
    )
    backend = Backend(args.backend, args.workers, args.ray_address, code_root=ROOT)
    with tqdm(total=len(jobs), initial=reused, desc="episodes", unit="ep") as progress:
        return run_jobs(jobs, run_episode, done, log, backend, on_row=progress.update)


def write_outputs(
    args: argparse.Namespace, command: str, config: EnvConfig, jobs: list[Job], rows: list[dict]
) -> tuple[list[dict], list[str]]:
    """The plots, results.json and report.md; returns the summary and the plots' names."""
    trajectories = pop_trajectories(rows)
    summary = summarize(rows, config.episode.duration)
    comparisons = study_comparisons(rows, config.episode.duration, args.policies, args.initializers)
    effective = effective_config(config, jobs[0])
    plots = []
    if not args.no_plots:
        plots = write_plots(args.out, rows, summary) + write_trajectory_plots(args.out, trajectories, effective)
    write_results(args.out / "results.json", command, effective, rows, summary, comparisons)
    models = filter_motion_models(jobs)
    write_report(args.out / "report.md", command, effective, models, summary, comparisons, plots, rows)
    return summary, plots


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        config, jobs = prepare(args)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    command = "python evaluate.py " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    try:
        rows = run(args, jobs)
    except LogMismatch as exc:
        print(f"error: --resume: {exc}; run without --resume or with another --out", file=sys.stderr)
        return 2
    except MissingBackend:
        print("error: --backend ray needs Ray: pip install -e '.[distributed]'", file=sys.stderr)
        return 2
    summary, plots = write_outputs(args, command, config, jobs, rows)
    print("\n" + "\n".join(console_table(summary)))
    print(
        f"\nwrote {args.out / 'report.md'}, {args.out / 'results.json'}" + (f" and {len(plots)} plots" if plots else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
