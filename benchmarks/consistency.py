"""Filter consistency on converged episodes: the shares of steps whose position NEES (3 dof) and NIS
(2 dof) lie within their two-sided 95 % chi-square intervals, and their means (3 and 2 expected).

    python benchmarks/consistency.py default:static:10000:10 free:static,cv:1000:10

Each WORLD:MOTIONS:FIRST_SEED:COUNT runs the helix (geometric measurements, the filter's motion model
matched to the source's) and keeps the steps after the episode's convergence time, i.e. while the
error stays below 1 m; episodes that never converge are counted and left out. A consistent filter
has about 95 % of its steps inside each interval.
"""

from __future__ import annotations

import argparse
from multiprocessing import Pool

import numpy as np
from scipy.stats import chi2

from tracker_check import MATCHED, WORLDS, parse_runs

NEES_BOUNDS = chi2.ppf([0.025, 0.975], 3)
NIS_BOUNDS = chi2.ppf([0.025, 0.975], 2)


def episode(job: tuple) -> tuple[str, str, float, list[float], list[float]]:
    import gymnasium as gym

    import aasl_gym  # noqa: F401

    world, motion, seed = job
    env = gym.make("AASL-Helix-v0", config=WORLDS[world], source_motion=motion, filter_model=MATCHED[motion]).unwrapped
    env.reset(seed=seed)
    steps, done = [], False
    while not done:
        _, _, terminated, truncated, info = env.step(np.zeros(3))
        done = terminated or truncated
        if info["initialized"] and not info["reinitialized"]:
            error = info["estimate_position"] - info["source_position"]
            nees = float(error @ np.linalg.solve(info["position_covariance"], error))
            steps.append((info["time"], nees, env.tracker.ukf.nis))
    converged = float(info["convergence_time"])
    kept = [(nees, nis) for time, nees, nis in steps if np.isfinite(converged) and time >= converged]
    return world, motion, converged, [k[0] for k in kept], [k[1] for k in kept]


def share(values: list[float], bounds: np.ndarray) -> float:
    values = np.asarray(values)
    return float(np.mean((values >= bounds[0]) & (values <= bounds[1]))) if values.size else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="WORLD:MOTIONS:FIRST_SEED:COUNT, WORLD in " + ", ".join(WORLDS))
    args = parser.parse_args()
    with Pool(2) as pool:
        rows = pool.map(episode, parse_runs(args.runs), chunksize=1)
    for world in WORLDS:
        for motion in MATCHED:
            group = [row for row in rows if row[0] == world and row[1] == motion]
            if not group:
                continue
            nees = [value for row in group for value in row[3]]
            nis = [value for row in group for value in row[4]]
            converged = sum(np.isfinite(row[2]) for row in group)
            print(
                f"{world:7s} {motion:6s} converged {converged}/{len(group)}, {len(nees)} steps:"
                f" NEES in 95 % interval {share(nees, NEES_BOUNDS):.0%}"
                f" (mean {np.mean(nees) if nees else np.nan:.1f}, 3 expected),"
                f" NIS {share(nis, NIS_BOUNDS):.0%} (mean {np.mean(nis) if nis else np.nan:.1f}, 2 expected)"
            )


if __name__ == "__main__":
    main()
