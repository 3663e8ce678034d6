"""Running a study's episodes: one from its job (:func:`run_episode`), and many (:func:`run_jobs`) in this
process, on a pool of fresh processes or as Ray tasks, each row logged as it arrives.

Every episode runs from its own seed, so the backend changes no row. Workers unpickle the jobs and
:func:`run_episode` by reference to this module: both must stay at module level.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from aasl_gym.env import AASLEnv
from aasl_gym.registration import ENV_IDS
from aasl_gym.study.jobs import Job, episode_key
from aasl_gym.study.log import EpisodeLog
from agents import make_policy
from agents.rollout import play_episode

logger = logging.getLogger(__name__)

BACKENDS = ("process", "ray")
# What a Ray cluster is not sent of the code root: history, environments and (large) study outputs.
RAY_EXCLUDES = [".git", ".venv", ".ci-venv", "results", "runs", "reports"]

RunAll = Callable[[list[Job]], Iterable[dict[str, Any]]]


class MissingBackend(ImportError):
    """The package a backend needs is not installed."""


@dataclass(frozen=True)
class Backend:
    """Where episodes run. ``process``: in this process with one worker, else on a pool of ``workers``
    fresh processes. ``ray``: as Ray tasks on the cluster at ``ray_address``, or on a local Ray started
    with ``workers`` CPUs. ``code_root`` is the directory Ray's workers import ``aasl_gym`` and ``agents``
    from (a cluster gets a copy of it as Ray's working_dir); ``None`` where they are installed."""

    kind: str = "process"
    workers: int = 1
    ray_address: str | None = None
    code_root: Path | None = None


@lru_cache(maxsize=8)
def trained_model(spec: str):
    """The trained policy ``ALGO:PATH``, loaded once per process (:func:`agents.sb3.load_model`, with its
    errors for a missing or corrupt file)."""
    from agents.sb3 import load_model  # torch: only where a trained policy flies

    return load_model(spec)


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def run_episode(job: Job) -> dict[str, Any]:
    """One episode; returns its results row. Scripted policies fly ``AASL-v0``; a trained model flies
    the env it was trained on (a residual model needs its patrol's command), with the same source,
    noise and metrics for the same seed."""
    policy = trained_model(job.policy) if ":" in job.policy else None
    patrol = ENV_IDS[policy.env_id] if policy is not None else None
    env = AASLEnv(
        job.config,
        source_motion=job.motion,
        initializer=job.initializer,
        measurement=job.measurement,
        filter_model=job.filter_model,
        patrol=patrol,
    )
    if policy is None:
        policy = make_policy(job.policy, env.config, seed=job.seed)
    info = play_episode(env, policy, job.seed)
    env.close()
    row = {
        "policy": job.policy,
        "initializer": job.initializer,
        "motion": job.motion,
        "source_motion": env.source.kind,
        "measurement": job.measurement,
        "seed": job.seed,
        "convergence_time": _finite_or_none(info["convergence_time"]),
        "success": info["success"],
        "rmse": _finite_or_none(info["rmse"]),
        "final_error": _finite_or_none(info["final_error"]),
        "time_to_first_estimate": _finite_or_none(info["time_to_first_estimate"]),
        "reinitializations": int(info["reinitializations"]),
    }
    if job.record:
        row["trajectory"] = {name: np.asarray(points).tolist() for name, points in env.trajectory.items()}
    return row


def run_jobs(
    jobs: list[Job],
    done: dict[tuple, dict],
    log: EpisodeLog,
    backend: Backend,
    on_row: Callable[[], Any] = lambda: None,
) -> list[dict[str, Any]]:
    """Every job's row, in the jobs' order: from ``done`` (rows by :func:`episode_key`, as an earlier run
    logged them) or run now on ``backend``, each new row appended to ``log`` and to ``done`` as it arrives
    (then ``on_row()``), so an interrupted study loses nothing."""
    todo = [job for job in jobs if episode_key(job) not in done]
    logger.info("%d of %d episodes to run on the %s backend", len(todo), len(jobs), backend.kind)
    with log.appending() as append, episode_runner(backend, needed=bool(todo)) as run_all:
        for job, row in zip(todo, run_all(todo)):
            append(episode_key(job), row)
            done[episode_key(job)] = row
            on_row()
    return [done[episode_key(job)] for job in jobs]


@contextmanager
def episode_runner(backend: Backend, needed: bool = True) -> Iterator[RunAll]:
    """A function that runs jobs and yields their rows in the jobs' order, on ``backend``; with nothing
    ``needed``, no pool or Ray is started. Raises :class:`MissingBackend` when Ray is chosen but absent."""
    if backend.kind == "ray" and needed:
        with _ray_runner(backend) as run_all:
            yield run_all
        return
    # Fresh worker processes, not forks: a fork of a parent that has run torch (the models are loaded
    # there to check them) can hang in torch's thread pool - a recurrent policy's workers never finished.
    pool = None
    if backend.workers > 1 and needed:
        pool = ProcessPoolExecutor(backend.workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        yield (lambda jobs: pool.map(run_episode, jobs, chunksize=4)) if pool else (lambda jobs: map(run_episode, jobs))
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


@contextmanager
def _ray_runner(backend: Backend) -> Iterator[RunAll]:
    try:
        import ray
    except ImportError:
        raise MissingBackend("the ray backend needs Ray, which is not installed") from None
    started = not ray.is_initialized()
    if started:
        ray.init(log_to_driver=False, **_ray_options(backend))
    task = ray.remote(num_cpus=1)(run_episode)
    try:
        yield lambda jobs: (ray.get(ref) for ref in [task.remote(job) for job in jobs])
    finally:
        if started:
            ray.shutdown()


def _ray_options(backend: Backend) -> dict[str, Any]:
    """ray.init's options. The workers import this package and ``agents`` from the code root: a cluster
    gets a copy of it (Ray's working_dir), a local Ray the path."""
    root = None if backend.code_root is None else str(backend.code_root)
    if backend.ray_address:
        options: dict[str, Any] = {"address": backend.ray_address}
        if root:
            options["runtime_env"] = {"working_dir": root, "excludes": RAY_EXCLUDES}
        return options
    options = {"num_cpus": backend.workers, "include_dashboard": False}
    if root:
        options["runtime_env"] = {"env_vars": {"PYTHONPATH": root}}
    return options
