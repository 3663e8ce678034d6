"""Instructions per front-end frame or per env step, counted by Valgrind: a speed figure the machine cannot move.

    python benchmarks/bench_instructions.py [--stage frontend|episode] [--world default|free] [--counts 50 250]

This machine's speed drifts by a third within an hour (``bench_speed.py``'s reference step), so an A/B of a change
worth a few per cent cannot be timed. Valgrind's cachegrind counts the instructions a run executes, the same on
every run. The script runs itself under cachegrind twice - ``--counts`` frames (or whole episodes) after a warm-up -
and prints the difference over the extra frames (steps): imports, compilation and warm-up cancel. An instruction is
not a fixed time (a cache miss or a branch costs more in Python's interpreter than in an FFT), so a count that falls
says less is done, not by how much the time falls; time whole episodes with ``bench_speed.py`` for the bar.

``--stage frontend``: the signal sensor alone on a robot circling the pod (the default world's or the free field's
front end). ``--stage episode``: whole episodes of ``AASL-Helix-v0`` with a CV source in signal mode, seeds 0 on
(about two minutes per episode under Valgrind). Needs ``valgrind`` on the PATH. The compiled kernels are cached per
processor, and Valgrind's is another one: the first run compiles them for it (about 20 s, then cached). After a change
to the kernels, count twice and keep the second: a kernel first reached after the warm-up (one that only some frames
take) is compiled inside the counted steps of one run and not the other (session 44's first count read 368 million
instructions a step against 7.4 million).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

WARM_UP = 20  # frames (or steps) before the counted ones: the first loads the kernels


def _env(world: str):
    import gymnasium as gym

    import aasl_gym  # noqa: F401

    free = dict(reflections=False, multipath="none") if world == "free" else {}
    return gym.make("AASL-Helix-v0", measurement="signal", source_motion="cv", **free)


def run_frontend(world: str, frames: int) -> int:
    """``frames`` frames of the signal sensor, the robot circling at 20 m and 7 m depth, the source drifting."""
    import numpy as np

    env = _env(world).unwrapped
    env.reset(seed=0)
    rng, source = np.random.default_rng(0), env.source
    for k in range(WARM_UP + frames):
        angle = 0.02 * k
        mobile = np.array([20 * np.cos(angle), 20 * np.sin(angle), -7.0])
        mobile_velocity = np.array([-0.4 * np.sin(angle), 0.4 * np.cos(angle), 0.0])
        env.sensor.measure(rng, 0.2 * (k + 1), source.position, source.velocity, mobile, mobile_velocity, env.fixed)
    return frames


def run_episodes(world: str, episodes: int) -> int:
    """Whole episodes (seeds 0 on, zero action) after a few steps of seed 99; the steps they took."""
    import numpy as np

    env = _env(world)
    env.reset(seed=99)
    for _ in range(WARM_UP):
        env.step(np.zeros(3))
    steps = 0
    for seed in range(episodes):
        env.reset(seed=seed)
        done = False
        while not done:
            *_, terminated, truncated, _ = env.step(np.zeros(3))
            done, steps = terminated or truncated, steps + 1
    return steps


def count_instructions(stage: str, world: str, count: int) -> tuple[int, int]:
    """(instructions, frames or steps) of the child run of ``count`` frames or episodes, from cachegrind's summary
    and the child's own count."""
    command = ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null"]
    command += [sys.executable, __file__, "--child", str(count), "--stage", stage, "--world", world]
    # Python's own allocator hides its frees from Valgrind; the system's keeps the count honest and stable.
    result = subprocess.run(command, capture_output=True, text=True, env=os.environ | {"PYTHONMALLOC": "malloc"})
    match = re.search(r"I\s+refs:\s+([\d,]+)", result.stderr)
    if result.returncode or not match:
        raise RuntimeError(f"valgrind run failed (exit {result.returncode}):\n{result.stderr[-2000:]}")
    return int(match.group(1).replace(",", "")), int(result.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--stage", choices=("frontend", "episode"), default="frontend")
    parser.add_argument("--world", choices=("default", "free"), default="default")
    parser.add_argument("--counts", type=int, nargs=2, metavar=("FEW", "MORE"), help="frames (or episodes) per run")
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print((run_frontend if args.stage == "frontend" else run_episodes)(args.world, args.child))
        return
    few, more = args.counts or ((50, 250) if args.stage == "frontend" else (1, 2))
    if not 0 <= few < more:
        parser.error(f"--counts must be two numbers with 0 <= FEW < MORE, got {few} {more}")
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not on the PATH (e.g. apt install valgrind)")
    count_instructions(args.stage, args.world, few)  # compiles the kernels for Valgrind's processor, once
    (many, units), (some, fewer_units) = (count_instructions(args.stage, args.world, n) for n in (more, few))
    per_unit = (many - some) / (units - fewer_units)
    world = {"default": "default world", "free": "free field"}[args.world]
    if args.stage == "frontend":
        print(f"{world}, front end: {per_unit:,.0f} instructions per frame")
    else:
        seeds = f"seed {few}" if more - few == 1 else f"seeds {few}-{more - 1}"
        print(f"{world}, whole episodes ({seeds}): {per_unit:,.0f} instructions per step")


if __name__ == "__main__":
    main()
