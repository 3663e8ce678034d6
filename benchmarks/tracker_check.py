"""Quick tracker check: success at 1 m, lost tracks, re-initializations and seconds per episode of a
scripted patrol (the helix unless ``--patrol`` says otherwise) on a few seeds: ``signal`` is the default
world as shipped, ``default`` the same world and ``free`` the free field with geometric measurements (as in
the tracker issue).

    python benchmarks/tracker_check.py default:static,cv:10000:16 free:cv,ca:1000:20 [--set filter.window_fit=false]
        [--patrol spiral]

Each WORLD:MOTIONS:FIRST_SEED:COUNT runs COUNT seeds per motion, the filter's motion model matched to
the source's; ``--set SECTION.KEY=JSON`` overrides a config field. Runs on two processes. For tuning on
your own seeds; a target's verdict belongs to held-out seeds and ``evaluate.py``.
"""

from __future__ import annotations

import argparse
import json
import time
from multiprocessing import Pool

import numpy as np
from tqdm import tqdm

from aasl_gym.patrols import REFERENCES
from aasl_gym.registration import ENV_IDS

WORLDS = {
    "signal": {},  # the default world as shipped: the acoustic front end, reflections, the phasor filter
    "default": {"measurement": {"mode": "geometric"}},
    "free": {"world": {"reflections": False}, "filter": {"multipath": "none"}, "measurement": {"mode": "geometric"}},
}
PATROL_IDS = {pattern: env_id for env_id, pattern in ENV_IDS.items() if pattern in REFERENCES}  # scripted patrols
MATCHED = {"static": "cv", "cv": "cv", "ca": "ca", "ctrv": "ctrv"}


def episode(job: tuple) -> dict:
    import gymnasium as gym

    import aasl_gym  # noqa: F401  (registers the ids in a spawned worker)

    world, motion, seed, overrides, patrol = job
    config = {section: dict(fields) for section, fields in WORLDS[world].items()}
    for section, fields in overrides.items():
        config.setdefault(section, {}).update(fields)
    env = gym.make(PATROL_IDS[patrol], config=config, source_motion=motion, filter_model=MATCHED[motion])
    start = time.perf_counter()
    env.reset(seed=seed)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(np.zeros(3))
        done = terminated or truncated
    return {
        "world": world,
        "motion": motion,
        "seed": seed,
        "success": bool(info["success"]["1.0"]),
        "final_error": float(info["final_error"]),
        "reinitializations": int(info["reinitializations"]),
        "seconds": time.perf_counter() - start,
        "convergence_time": float(info["convergence_time"]),
    }


def parse_runs(runs: list[str]) -> list[tuple[str, str, int]]:
    """(world, motion, seed) for each WORLD:MOTIONS:FIRST_SEED:COUNT."""
    jobs = []
    for run in runs:
        parts = run.split(":")
        if len(parts) != 4 or not (parts[2].isdigit() and parts[3].isdigit()):
            raise SystemExit(f"{run!r}: expected WORLD:MOTIONS:FIRST_SEED:COUNT, e.g. free:static,cv:1000:6")
        world, motions, first, count = parts
        if world not in WORLDS:
            raise SystemExit(f"{run!r}: unknown world {world!r}; allowed: {list(WORLDS)}")
        unknown = sorted(set(motions.split(",")) - set(MATCHED))
        if unknown:
            raise SystemExit(f"{run!r}: unknown motion(s) {unknown}; allowed: {list(MATCHED)}")
        jobs += [
            (world, motion, seed)
            for motion in motions.split(",")
            for seed in range(int(first), int(first) + int(count))
        ]
    return jobs


def parse_overrides(pairs: list[str]) -> dict:
    overrides: dict = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        section, _, field = key.partition(".")
        if not (section and field and value):
            raise SystemExit(f"--set {pair!r}: expected SECTION.KEY=JSON, e.g. filter.window_fit=false")
        overrides.setdefault(section, {})[field] = json.loads(value)
    return overrides


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="WORLD:MOTIONS:FIRST_SEED:COUNT, WORLD in " + ", ".join(WORLDS))
    parser.add_argument("--set", nargs="*", default=[], help="SECTION.KEY=JSON config overrides")
    parser.add_argument("--patrol", default="helix", choices=sorted(PATROL_IDS), help="the scripted patrol")
    args = parser.parse_args()
    overrides = parse_overrides(args.set)
    jobs = [(*job, overrides, args.patrol) for job in parse_runs(args.runs)]
    with Pool(2) as pool:
        rows = list(tqdm(pool.imap(episode, jobs, chunksize=1), total=len(jobs), unit="ep", leave=False))
    for world in WORLDS:
        for motion in MATCHED:
            group = [row for row in rows if row["world"] == world and row["motion"] == motion]
            if not group:
                continue
            converged = [row["convergence_time"] for row in group if np.isfinite(row["convergence_time"])]
            print(
                f"{args.patrol} {world:7s} {motion:6s} success {sum(row['success'] for row in group)}/{len(group)}"
                f"  lost (>5 m) {sum(row['final_error'] > 5 for row in group)}"
                f"  median re-inits {np.median([row['reinitializations'] for row in group]):.0f}"
                f"  mean convergence {np.mean(converged) if converged else float('nan'):.1f} s"
                f"  {np.mean([row['seconds'] for row in group]):.1f} s/episode"
            )


if __name__ == "__main__":
    main()
