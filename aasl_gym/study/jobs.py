"""The study's grid: one job per policy x initializer x motion x seed, every combination on the same
seeds so that comparisons are paired, and the key that names a job in the resume log."""

from __future__ import annotations

from dataclasses import dataclass

from aasl_gym.config import EnvConfig, to_dict
from aasl_gym.env import resolve_config

MOTIONS = ("static", "cv", "ca", "ctrv", "uturn", "mixed")
FILTER_CHOICES = ("cv", "ca", "ctrv", "matched")
FACILITY_PATROL = "facility"  # a job's policy that flies AASL-Facility-v0's own patrol (a zero residual)
MATCHED_FILTER = {"static": "cv", "cv": "cv", "ca": "ca", "ctrv": "ctrv", "uturn": "ctrv", "mixed": "cv"}


@dataclass(frozen=True)
class Job:
    """One episode: a scripted policy's name or a trained model's ``ALGO:PATH``, the filter's initializer,
    the source's motion, the measurement mode, the seed, and the env config as plain values."""

    policy: str
    initializer: str
    motion: str
    measurement: str
    seed: int
    config: dict
    filter_model: str | None
    record: bool = False  # keep the episode's paths for the trajectory plots
    variant: str = ""  # a study's world or filter variant (aasl_gym.study.paper), whose fields ``config`` holds


@dataclass(frozen=True)
class StudyGrid:
    """What a study runs: each policy x initializer x motion on seeds ``first_seed``, ``first_seed + 1``,
    ... (``episodes`` of them). A ``None`` override keeps the config's value."""

    policies: tuple[str, ...]
    initializers: tuple[str, ...]
    motions: tuple[str, ...]
    episodes: int
    first_seed: int
    measurement: str | None = None  # the measurement mode
    reflections: bool | None = None  # surface and bed paths in the world
    multipath: str | None = None  # the filter's multipath model
    filter_model: str | None = None  # the filter's motion model; "matched" follows MATCHED_FILTER per motion
    trajectories: int = 0  # seeds per policy and motion (first initializer) whose paths are kept for plots

    @property
    def seeds(self) -> range:
        return range(self.first_seed, self.first_seed + self.episodes)


def build_jobs(grid: StudyGrid, config: EnvConfig) -> list[Job]:
    """The grid's jobs, motion by motion, then policy, initializer and seed."""
    data = to_dict(config)
    if grid.reflections is not None:
        data["world"]["reflections"] = grid.reflections
    if grid.multipath is not None:
        data["filter"]["multipath"] = grid.multipath
    measurement = grid.measurement or config.measurement.mode
    jobs = []
    for motion in grid.motions:
        filter_model = MATCHED_FILTER[motion] if grid.filter_model == "matched" else grid.filter_model
        for policy in grid.policies:
            for initializer in grid.initializers:
                for seed in grid.seeds:
                    record = initializer == grid.initializers[0] and seed < grid.first_seed + grid.trajectories
                    jobs.append(Job(policy, initializer, motion, measurement, seed, data, filter_model, record))
    return jobs


def check_overrides(job: Job) -> None:
    """Raise :class:`~aasl_gym.config.ConfigError` if the job's config with its overrides is not a valid
    env config: checked once, before any worker starts, since every job shares them."""
    resolve_config(job.config, measurement=job.measurement, filter_model=job.filter_model)


def effective_config(config: EnvConfig, job: Job) -> EnvConfig:
    """The config the episodes ran with: ``config`` with the job's world, filter and measurement mode."""
    return config.replace(world=job.config["world"], filter=job.config["filter"], measurement={"mode": job.measurement})


def filter_motion_models(jobs: list[Job]) -> dict[str, str]:
    """The filter's motion model the jobs run for each source motion (the config's where no job names one)."""
    return {job.motion: job.filter_model or job.config["filter"]["motion_model"] for job in jobs}


def episode_key(job: Job) -> tuple:
    """What names an episode in the resume log (the config is the log's header: the same for all but a
    variant's own fields, which its name stands for)."""
    key = (job.policy, job.initializer, job.motion, job.measurement, job.seed, job.filter_model)
    return (*key, job.variant) if job.variant else key
