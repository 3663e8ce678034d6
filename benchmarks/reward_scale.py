"""Scale of each weighted reward term over whole episodes, per policy (the table in ``aasl_gym/rewards.py``).

    python benchmarks/reward_scale.py [--policies helix greedy random] [--seeds 4] [--seed 2000]

Runs every policy on the same seeds for each motion (static, CV, CA, CTRV; the filter matched), in the
free field of ``configs/initializer_study.yaml`` with the signal front end, and prints the mean
[min, max] of each term's episode sum.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # agents/ lives at the repository root

from aasl_gym.env import AASLEnv  # noqa: E402
from aasl_gym.rewards import TERMS  # noqa: E402
from aasl_gym.study.jobs import MATCHED_FILTER  # noqa: E402  (source motion -> the filter model matched to it)
from agents import make_policy  # noqa: E402
from agents.rollout import play_episode  # noqa: E402

MOTIONS = ("static", "cv", "ca", "ctrv")


def episode_sums(policy_name: str, motion: str, seed: int) -> dict[str, float]:
    env = AASLEnv(
        ROOT / "configs" / "initializer_study.yaml",
        source_motion=motion,
        measurement="signal",
        filter_model=MATCHED_FILTER[motion],
    )
    sums = dict.fromkeys(TERMS, 0.0)

    def add(_, info):
        for name, value in info["reward_terms"].items():
            sums[name] += value

    play_episode(env, make_policy(policy_name, env.config, seed=seed), seed, on_step=add)
    return sums


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", default=["helix", "greedy", "random"])
    parser.add_argument("--seeds", type=int, default=4, help="seeds per motion")
    parser.add_argument("--seed", type=int, default=2000, help="first seed")
    args = parser.parse_args()
    columns = {}
    for policy in args.policies:
        jobs = [(motion, seed) for motion in MOTIONS for seed in range(args.seed, args.seed + args.seeds)]
        episodes = [episode_sums(policy, *job) for job in tqdm(jobs, desc=policy, unit="ep", leave=False)]
        columns[policy] = {name: np.array([e[name] for e in episodes]) for name in TERMS}
        print(f"{policy}: {len(episodes)} episodes", file=sys.stderr)
    print("| term | " + " | ".join(args.policies) + " |")
    print("|---|" + "---|" * len(args.policies))
    for name in TERMS:
        cells = [f"{v.mean():.1f} [{v.min():.1f}, {v.max():.1f}]" for v in (columns[p][name] for p in args.policies)]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
