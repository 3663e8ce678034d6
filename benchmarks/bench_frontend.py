"""Cost of the acoustic front end per 0.2 s frame, on one core: synthesis, filtering, estimation, for the
hardware-rate path (real, 200 kHz) and the fast path (complex baseband), free field and with reflections.

    python benchmarks/bench_frontend.py [--repeats 7] [--episodes 1]

Prints the median over repeats in ms, and the hardware path's filtering cost against the FFTs it
cannot avoid (one real FFT of the frame per channel), so the ratio holds however fast the machine is, then env steps per second in signal mode. Goals (issue 3): the full env
step >= 1,000 steps/s on the fast path, the hardware path within 2x of its FFTs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from aasl_gym import acoustics  # noqa: E402
from bench_speed import env_steps_per_second  # noqa: E402  (run from the repository root as a script)

FIXED = np.array([0.0, 0.0, -0.96])
SOURCE, SOURCE_VELOCITY = np.array([8.0, -6.0, -12.0]), np.array([0.5, 0.2, 0.0])
MOBILE, MOBILE_VELOCITY = np.array([14.0, 4.0, -8.0]), np.array([0.0, 1.0, 0.0])
FRAME, GUARD = 0.2, 0.02


def median_ms(function, repeats: int, number: int = 5) -> float:
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            function()
        samples.append((time.perf_counter() - start) / number)
    return 1e3 * statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--episodes", type=int, default=1, help="episodes per env timing")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    waveform = acoustics.Waveform.random("tone", rng)
    for reflections in (False, True):
        paths = acoustics.path_sources(SOURCE, SOURCE_VELOCITY, reflections, 60.0, -0.9, 0.3)
        for label, baseband, rate in (("fast (baseband, 10 kHz)", True, 10_000.0), ("hardware (real, 200 kHz)", False, 200_000.0)):
            def synthesize():
                return acoustics.synthesize(waveform, 3.0, FRAME + 2 * GUARD, rate, baseband, paths, MOBILE, MOBILE_VELOCITY,
                                            FIXED, 1500.0, 140.0, 80.0, rng)

            channel = synthesize()
            envelope = acoustics.envelopes(channel, waveform, 10_000.0, GUARD)
            costs = {
                "synthesis": median_ms(synthesize, args.repeats),
                "filtering": median_ms(lambda: acoustics.envelopes(channel, waveform, 10_000.0, GUARD), args.repeats),
                "correlation + FDOA": median_ms(lambda: acoustics.estimate(envelope, waveform, 1500.0, 0.03), args.repeats),
            }
            line = ", ".join(f"{name} {cost:.2f} ms" for name, cost in costs.items())
            print(f"reflections {'on ' if reflections else 'off'} {label}: {line}, total {sum(costs.values()):.2f} ms")
            if not baseband:
                samples = channel.mobile
                ffts = 2 * median_ms(lambda: np.fft.rfft(samples), args.repeats)
                print(f"    hardware filtering / its unavoidable FFTs ({ffts:.2f} ms): {costs['filtering'] / ffts:.1f}x   [goal <= 2]")
    for label, kwargs in (
        ("free field, fast path, cv source", dict(reflections=False, multipath="none", config={"signal": {"path": "fast"}})),
        ("free field, hardware path, cv source", dict(reflections=False, multipath="none", config={"signal": {"path": "hardware"}})),
        ("reflections on, phasor filter, fast path (default world)", dict(config={"signal": {"path": "fast"}})),
    ):
        rate = statistics.median(env_steps_per_second("AASL-Helix-v0", args.episodes, source_motion="cv", measurement="signal", **kwargs)
                                 for _ in range(max(1, args.repeats // 3)))
        print(f"env steps/s, signal mode, {label}: {rate:,.0f}   [goal >= 1,000 on the fast path]")


if __name__ == "__main__":
    main()
