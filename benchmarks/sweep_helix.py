"""Choose the helix geometry by the Cramer-Rao bound, once (SPEC section 6: give the baseline its best chance).

For each helix (radius x depth period) and each seeded source, the bound of ``crb_bound.py`` (Fisher
information of the source's motion parameters and b_p along the flown path at the *true* state,
whole-period offset known to ``initializer.range_bias_sd``, the initializer's priors) gives the first
time the bound on the position error, sqrt(trace(P_pos)), falls below ``--target`` metres. No filter
is involved, so this ranks geometries, not estimators. Prints a table and writes it as markdown to ``--out``.

    python benchmarks/sweep_helix.py --radii 5 10 15 20 --depth-periods 40 80 --episodes 20
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from aasl_gym.config import EnvConfig
from aasl_gym.env import AASLEnv
from crb_bound import episode_bound, print_table


def time_to_bound(env: AASLEnv, seed: int, target: float) -> float:
    """Seconds until the CRB on the source position first falls below ``target`` m (inf if never)."""
    below = np.nonzero(episode_bound(env, seed) < target)[0]
    return (below[0] + 1) * env.dt if len(below) else np.inf


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radii", type=float, nargs="+", default=[5.0, 10.0, 15.0, 20.0])
    parser.add_argument("--depth-periods", type=float, nargs="+", default=[40.0, 80.0])
    parser.add_argument("--motions", nargs="+", default=["static", "cv"], choices=["static", "cv", "ca", "ctrv"])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--target", type=float, default=0.5, help="bound on the position error, m")
    parser.add_argument("--out", default=None, help="markdown file for the table")
    args = parser.parse_args(argv)
    header = [
        f"| radius (m) | depth period (s) | motion | median time to CRB < {args.target} m (s)"
        " | reached within the episode |",
        "|---|---|---|---|---|",
    ]

    def rows():
        for radius, period, motion in itertools.product(args.radii, args.depth_periods, args.motions):
            config = EnvConfig().replace(
                patrol={"radius": radius, "depth_period": period},
                receiver={"start_position": [radius, 0.0, -7.0]},
                source={"motion": motion},
                world={"reflections": False},
                measurement={"mode": "geometric"},
                filter={"multipath": "none"},
                initializer={"name": "naive"},
            )
            env = AASLEnv(config, patrol="helix")
            times = np.array([time_to_bound(env, seed, args.target) for seed in range(args.episodes)])
            yield f"| {radius:g} | {period:g} | {motion} | {np.median(times):.1f} | {np.mean(np.isfinite(times)):.0%} |"

    print_table(header, rows(), args.out)


if __name__ == "__main__":
    main()
