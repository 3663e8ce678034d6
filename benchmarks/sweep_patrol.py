"""Choose a patrol's geometry by the Cramer-Rao bound, once (SPEC section 6: give the baseline its best chance).

For each geometry and each seeded source, the bound of ``crb_bound.py`` (Fisher information of the source's motion
parameters and b_p along the flown path at the *true* state, whole-period offset known to
``initializer.range_bias_sd``, the initializer's priors) gives the first time the bound on the position error,
sqrt(trace(P_pos)), falls below ``--target`` metres. No filter is involved, so this ranks geometries, not
estimators. The free field with geometric measurements, as the helix was chosen. Prints a table and writes it as
markdown to ``--out``.

    python benchmarks/sweep_patrol.py --radii 5 10 15 20 --depth-periods 40 80 --episodes 20   # the helix
    python benchmarks/sweep_patrol.py --pattern spiral --grid spiral_radius_max=15,25,35 spiral_period=60,120,240 \\
        --episodes 16

The helix flies from [radius, 0, -7] (on its circle); every other pattern from the config's start, as the env
flies it.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from aasl_gym.config import EnvConfig, PatrolConfig
from aasl_gym.env import AASLEnv
from aasl_gym.patrols import REFERENCES
from crb_bound import bound_env, episode_bound, print_table
from tracker_check import WORLDS  # run as a script: benchmarks/ is on sys.path


def time_to_bound(env: AASLEnv, seed: int, target: float) -> float:
    """Seconds until the CRB on the source position first falls below ``target`` m (inf if never)."""
    below = np.nonzero(episode_bound(env, seed) < target)[0]
    return (below[0] + 1) * env.dt if len(below) else np.inf


def parse_grid(pairs: list[str]) -> dict[str, list[float]]:
    """``FIELD=V1,V2,...`` of :class:`~aasl_gym.config.PatrolConfig`'s fields, each with its values."""
    grid = {}
    for pair in pairs:
        name, _, values = pair.partition("=")
        if name not in PatrolConfig.__dataclass_fields__ or not values:
            raise SystemExit(f"--grid {pair!r}: expected FIELD=V1,V2 of a patrol field, e.g. spiral_period=60,120")
        try:
            grid[name] = [float(value) for value in values.split(",")]
        except ValueError:
            raise SystemExit(f"--grid {pair!r}: the values must be numbers") from None
    return grid


def geometries(args: argparse.Namespace) -> list[tuple[dict, dict]]:
    """(patrol fields, receiver fields) of every geometry the sweep flies."""
    if args.pattern == "helix" and not args.grid:
        return [
            ({"radius": radius, "depth_period": period}, {"start_position": [radius, 0.0, -7.0]})
            for radius, period in itertools.product(args.radii, args.depth_periods)
        ]
    grid = parse_grid(args.grid)
    return [(dict(zip(grid, values)), {}) for values in itertools.product(*grid.values())]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pattern", default="helix", choices=sorted(REFERENCES))
    parser.add_argument("--radii", type=float, nargs="+", default=[5.0, 10.0, 15.0, 20.0], help="the helix's")
    parser.add_argument("--depth-periods", type=float, nargs="+", default=[40.0, 80.0], help="the helix's")
    parser.add_argument("--grid", nargs="*", default=[], help="FIELD=V1,V2,... patrol fields (any pattern)")
    parser.add_argument("--motions", nargs="+", default=["static", "cv"], choices=["static", "cv", "ca", "ctrv"])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--target", type=float, default=0.5, help="bound on the position error, m")
    parser.add_argument("--out", default=None, help="markdown file for the table")
    args = parser.parse_args(argv)
    chosen = geometries(args)
    names = list(chosen[0][0])
    labels = {"radius": "radius (m)", "depth_period": "depth period (s)"}
    columns = " | ".join(labels.get(name, name) for name in names)
    header = [
        f"| {columns} | motion | median time to CRB < {args.target} m (s) | reached within the episode |",
        "|" + "---|" * (len(names) + 3),
    ]

    def rows():
        for (patrol, receiver), motion in itertools.product(chosen, args.motions):
            flown = EnvConfig().replace(patrol=patrol, receiver=receiver, **WORLDS["free"])
            env = bound_env(flown, motion, args.pattern)
            times = np.array([time_to_bound(env, seed, args.target) for seed in range(args.episodes)])
            cells = " | ".join(f"{value:g}" for value in patrol.values())
            yield f"| {cells} | {motion} | {np.median(times):.1f} | {np.mean(np.isfinite(times)):.0%} |"

    print_table(header, rows(), args.out)


if __name__ == "__main__":
    main()
