"""Running a study's episodes (:func:`run_jobs`) in this process, on a pool of fresh processes or as Ray
tasks, each row logged as it arrives.

What runs one episode is given (``episode``: a job -> its row; :func:`agents.study.run_episode` flies
the agents): this package does not import the agents, which are built on it. Every episode runs from its
own seed, so the backend changes no row. Workers unpickle the jobs and ``episode`` by reference to its
module: both must stay at module level.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aasl_gym.study.jobs import Job, episode_key
from aasl_gym.study.log import EpisodeLog, Row

logger = logging.getLogger(__name__)

BACKENDS = ("process", "ray")
# What a Ray cluster is not sent of the code root: history, environments and (large) study outputs.
RAY_EXCLUDES = [".git", ".venv", ".ci-venv", "results", "runs", "reports"]

Episode = Callable[[Job], Row]  # runs one job's episode and returns its row
RunAll = Callable[[list[Job]], Iterable[Row]]


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


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    """The study CLIs' ``--workers``, ``--backend`` and ``--ray-address``."""
    parser.add_argument(
        "--workers", type=int, default=None, help="processes (default: every core this process may use)"
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="process",
        help="process: a local process pool; ray: Ray tasks (pip install -e '.[distributed]')",
    )
    parser.add_argument(
        "--ray-address", default=None, help="a Ray cluster to join (default: start Ray locally with --workers CPUs)"
    )


def check_backend_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Fill in ``--workers`` (the cores this process may use) and reject what cannot run, naming the flag."""
    if args.workers is None:
        args.workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if args.ray_address is not None and args.backend != "ray":
        parser.error("--ray-address needs --backend ray")


def run_jobs(
    jobs: list[Job],
    episode: Episode,
    done: dict[tuple, Row],
    log: EpisodeLog,
    backend: Backend,
    on_row: Callable[[], Any] = lambda: None,
) -> list[Row]:
    """Every job's row, in the jobs' order: from ``done`` (rows by :func:`episode_key`, as an earlier run
    logged them) or run now by ``episode`` on ``backend``, each new row appended to ``log`` and to
    ``done`` as it arrives (then ``on_row()``), so an interrupted study loses nothing."""
    todo = [job for job in jobs if episode_key(job) not in done]
    logger.info("%d of %d episodes to run on the %s backend", len(todo), len(jobs), backend.kind)
    with log.appending() as append, episode_runner(backend, episode, needed=bool(todo)) as run_all:
        for job, row in zip(todo, run_all(todo)):
            append(episode_key(job), row)
            done[episode_key(job)] = row
            on_row()
    return [done[episode_key(job)] for job in jobs]


@contextmanager
def episode_runner(backend: Backend, episode: Episode, needed: bool = True) -> Iterator[RunAll]:
    """A function that runs jobs by ``episode`` and yields their rows in the jobs' order, on ``backend``;
    with nothing ``needed``, no pool or Ray is started. Raises :class:`MissingBackend` when Ray is chosen but absent."""
    if backend.kind == "ray" and needed:
        with _ray_runner(backend, episode) as run_all:
            yield run_all
        return
    if backend.workers == 1 or not needed:
        yield lambda jobs: map(episode, jobs)
        return
    # Fresh worker processes, not forks: a fork of a parent that has run torch (the models are loaded
    # there to check them) can hang in torch's thread pool - a recurrent policy's workers never finished.
    with _single_threaded_workers():
        pool = ProcessPoolExecutor(backend.workers, mp_context=multiprocessing.get_context("spawn"))
        try:
            # One episode at a time: an episode takes seconds, so the hand-over costs nothing, while chunks
            # of several leave a worker idle at the end of a study for up to a chunk's worth of episodes.
            yield lambda jobs: pool.map(episode, jobs)
        finally:
            pool.shutdown(cancel_futures=True)


THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def _single_threaded_workers() -> Iterator[None]:
    """Worker processes spawned meanwhile run their linear algebra on one thread each (unless the user
    set a count): each worker is already one of the pool's cores, and BLAS threads on top oversubscribe
    them - the main job took 3 min 10 s on 2 cores instead of 2 min 59 s, with the same rows. (Ray does
    the same for its tasks.)"""
    unset = [name for name in THREAD_VARIABLES if name not in os.environ]
    os.environ.update({name: "1" for name in unset})
    try:
        yield
    finally:
        for name in unset:
            os.environ.pop(name, None)


@contextmanager
def _ray_runner(backend: Backend, episode: Episode) -> Iterator[RunAll]:
    try:
        import ray
    except ImportError:
        raise MissingBackend("the ray backend needs Ray, which is not installed") from None
    started = not ray.is_initialized()
    if started:
        ray.init(log_to_driver=False, **_ray_options(backend))
    task = ray.remote(num_cpus=1)(episode)
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
