"""What a study runs for one job: the policy it names, flown on its env from its seed, and the row of
results :mod:`aasl_gym.study` logs and summarizes (:func:`run_episode`, given to
:func:`aasl_gym.study.runner.run_jobs`). Module level, so that pool and Ray workers import it by name."""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np

from aasl_gym import metrics
from aasl_gym.env import AASLEnv
from aasl_gym.facility_env import FacilityEnv
from aasl_gym.registration import ENV_IDS, FACILITY_ID
from aasl_gym.study.array_comparison import array_row, time_calls
from aasl_gym.study.jobs import FACILITY_PATROL, Job
from aasl_gym.study.log import Row
from agents.policies import make_policy
from agents.rollout import play_episode
from agents.scripted import ZeroPolicy


@lru_cache(maxsize=8)
def trained_model(spec: str):
    """The trained policy ``ALGO:PATH``, loaded once per process (:func:`agents.sb3.load_model`, with its
    errors for a missing or corrupt file)."""
    from agents.sb3 import load_model  # torch: only where a trained policy flies

    return load_model(spec)


def _finite_or_none(value) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def run_episode(job: Job) -> Row:
    """One episode; returns its results row. Scripted policies fly ``AASL-v0``; a trained model flies
    the env it was trained on (a residual model needs its patrol's command), with the same source,
    noise and metrics for the same seed."""
    return _play(job)[0]


def run_trial(job: Job) -> Row:
    """One trial of a paper study (:mod:`aasl_gym.study.paper`): :func:`run_episode`'s row with the job's
    ``variant``, the episode's largest position error (m) once the filter had started, ``max_error``, and
    the RMSE (m) over its second half, ``rmse_second_half`` (the tracking once the start is long past)."""
    row, steps = _play(job, keep_errors=True)
    row["variant"] = job.variant
    errors = np.array([error for _, error in steps])
    row["max_error"] = _finite_or_none(errors.max()) if errors.size else None
    row["rmse_second_half"] = _second_half_rmse(steps, job.config["episode"]["duration"])
    return row


def _second_half_rmse(steps: list[tuple[float, float]], duration: float) -> float | None:
    """RMSE (m) of the (time s, error m) ``steps`` in the second half of an episode of ``duration`` s."""
    return _finite_or_none(metrics.rmse(np.array([error for time, error in steps if time >= 0.5 * duration])))


def run_array_trial(job: Job) -> Row:
    """One trial of the fixed-array comparison (:mod:`aasl_gym.study.array_comparison`): the tracker's
    episode (its RMSE, second-half RMSE, median error and ``tracker.step`` times, under ``tracker``) and both
    array baselines on the same source track over the steps the tracker's RMSE counts."""
    env, policy = _episode_env(job)
    seconds = time_calls(env.tracker, "step")
    steps: list[tuple[float, float, np.ndarray]] = []

    def keep(reward: float, info: dict) -> None:
        if info["initialized"]:
            steps.append((float(info["time"]), float(info["position_error"]), info["source_position"]))

    info = play_episode(env, policy, job.seed, on_step=keep)
    env.close()
    row = _episode_row(job, env, info)
    errors = np.array([error for _, error, _ in steps])
    row["tracker"] = {
        "rmse": row["rmse"],
        "rmse_second_half": _second_half_rmse([(t, e) for t, e, _ in steps], job.config["episode"]["duration"]),
        "median_error": _finite_or_none(np.median(errors)) if errors.size else None,
        "ms_mean": 1e3 * float(np.mean(seconds)),
        "ms_median": 1e3 * float(np.median(seconds)),
    }
    sources = np.array([source for _, _, source in steps]).reshape(-1, 3)
    sd = env.config.measurement.range_difference_sd
    row.update(array_row(sources, env.fixed, env.config.wavelength, sd, job.seed))
    return row


def _episode_env(job: Job) -> tuple[AASLEnv, Any]:
    """The job's env and the policy that flies it. Scripted policies fly ``AASL-v0``; a trained model flies
    the env it was trained on (a residual model needs its patrol's command); ``facility`` is the facility's
    own patrol (a zero residual on ``AASL-Facility-v0``), where a model trained on that id flies too."""
    overrides = {
        "source_motion": job.motion,
        "initializer": job.initializer,
        "measurement": job.measurement,
        "filter_model": job.filter_model,
    }
    policy = trained_model(job.policy) if ":" in job.policy else None
    if job.policy == FACILITY_PATROL or (policy is not None and policy.env_id == FACILITY_ID):
        return FacilityEnv(job.config, scenario=None, **overrides), ZeroPolicy() if policy is None else policy
    patrol = ENV_IDS[policy.env_id] if policy is not None else None
    env = AASLEnv(job.config, patrol=patrol, **overrides)
    if policy is None:
        policy = make_policy(job.policy, env.config, seed=job.seed)
    return env, policy


def _play(job: Job, keep_errors: bool = False) -> tuple[Row, list[tuple[float, float]]]:
    """The episode's row and, with ``keep_errors``, (time s, position error m) of each step the filter ran."""
    env, policy = _episode_env(job)
    errors: list[tuple[float, float]] = []

    def keep(reward: float, info: dict) -> None:
        if info["initialized"]:
            errors.append((float(info["time"]), float(info["position_error"])))

    info = play_episode(env, policy, job.seed, on_step=keep if keep_errors else None)
    env.close()
    return _episode_row(job, env, info), errors


def _episode_row(job: Job, env: AASLEnv, info: dict) -> Row:
    """The results row of the job's finished episode on ``env``, ``info`` its last step's."""
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
    if "detection_time" in info:  # the facility's
        row |= {key: info[key] for key in ("pod", "source_pod")}
        row["detection_time"] = _finite_or_none(info["detection_time"])
    if job.record:
        row["trajectory"] = {name: np.asarray(points).tolist() for name, points in env.trajectory.items()}
    return row
