"""Issue 12's point 1 over every held-out set at once: the tracker's successes at 1 m summed over the sets of one
motion, beside an efficient estimator's count over the same episodes (its mean, 90 % range and the chance of as few).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/pooled_bound.py [--motion cv] [--workers 2]

One set alone moves by a few points by luck (``crb_bound.py``'s "chance of as few"); pooled, the episodes say whether
the tracker falls short of what the data allow or only of the bar. The tracker's count comes from each set's committed
report (``heldout_figure.tracker_success``); the bound is recomputed per episode (``crb_bound.episode_covariance``,
the config the sets ran with), an efficient estimator's chance drawn afresh with each set's seed (20,000 draws an
episode: the tables' own chances to about 0.2 %).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from aasl_gym.scenarios import command_line_config
from crb_bound import as_few_chance, bound_env, efficient_count_range, efficient_success, episode_covariance
from heldout_figure import SETS, TARGET, bound_rows, missing_sets, tracker_success

CONFIG = "configs/initializer_study.yaml"


def set_chances(first_seed: int, episodes: int, motion: str) -> list[float]:
    """An efficient estimator's chance of ending within ``TARGET`` in each of the ``episodes`` from ``first_seed``."""
    env = bound_env(command_line_config(None, CONFIG, CONFIG), motion, "helix")
    rng = np.random.default_rng(first_seed)
    seeds = range(first_seed, first_seed + episodes)
    return [efficient_success(episode_covariance(env, seed)[-1], TARGET, rng) for seed in seeds]


def tracker_count(folder: Path, bounds: dict[str, dict[str, float]], motion: str, episodes: int) -> int:
    """The tracker's successes at ``TARGET`` over a set's ``episodes`` of ``motion`` (``bounds`` its bound table)."""
    shares = tracker_success(folder, bounds)
    if motion not in shares:
        raise SystemExit(f"{folder}: no tracker success for {motion} (results.json, or crb_bound.py --tracker)")
    return round(shares[motion] * episodes / 100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--motion", default="cv", choices=["static", "cv", "ca", "ctrv"])
    parser.add_argument("--root", type=Path, default=Path("reports/tracker"), help="folder holding the held-out sets")
    parser.add_argument("--workers", type=int, default=1, help="processes (one set each)")
    args = parser.parse_args()
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if missing := missing_sets(args.root):
        raise SystemExit(f"--root {args.root}: no crb_bound.md in {missing}; run the held-out sets first")
    rows = {name: bound_rows(args.root / name) for name in SETS}
    names = [name for name in SETS if args.motion in rows[name]]
    if not names:
        raise SystemExit(f"--motion {args.motion}: no held-out set under {args.root} ran it")
    episodes = [int(rows[name][args.motion]["episodes"]) for name in names]
    successes = sum(tracker_count(args.root / name, rows[name], args.motion, n) for name, n in zip(names, episodes))
    first_seeds = [int(SETS[name].split("-")[0]) for name in names]
    with ProcessPoolExecutor(args.workers) as pool:
        per_set = pool.map(set_chances, first_seeds, episodes, [args.motion] * len(names))
        chances = [chance for chunk in tqdm(per_set, total=len(names), unit="set", leave=False) for chance in chunk]
    low, high = efficient_count_range(chances)
    count = len(chances)
    print(f"{args.motion}: {len(names)} sets, {count} episodes ({', '.join(str(s) for s in first_seeds)})")
    print(f"  tracker at {TARGET:g} m: {successes} ({successes / count:.1%})")
    print(f"  efficient estimator: {sum(chances):.1f} ({np.mean(chances):.1%}), 90 % range {low}-{high}")
    print(f"  an efficient estimator's chance of as few as the tracker: {as_few_chance(chances, successes):.0%}")


if __name__ == "__main__":
    main()
