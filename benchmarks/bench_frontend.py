"""Cost of the acoustic front end per 0.2 s frame, on one core: synthesis, filtering, estimation, for the
hardware-rate path (real, 200 kHz) and the fast path (complex baseband), free field and with reflections.

    python benchmarks/bench_frontend.py [--repeats 7] [--episodes 1]

Prints the median over repeats in ms (a tone's correlation and TDOA / FDOA stages are one compiled pass, timed as
one), and the hardware path's filtering cost against the FFTs it cannot avoid (one real FFT of the frame per
channel), so the ratio holds however fast the machine is;
then env steps per second in signal mode, over whole episodes and for the typical step (the median:
front end + UKF bank; LC-MAP's start and re-seeds, a dozen steps an episode, are the rest). Goals
(issue 3): the full env step (front end + UKF) >= 1,000 steps/s on the fast path, the hardware path
within 2x of its FFTs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from aasl_gym import frontend, synthesis
from aasl_gym.config import SignalConfig
from bench_speed import env_step_rates  # run as a script: benchmarks/ is on sys.path

FIXED = np.array([0.0, 0.0, -0.96])
SOURCE, SOURCE_VELOCITY = np.array([8.0, -6.0, -12.0]), np.array([0.5, 0.2, 0.0])
MOBILE, MOBILE_VELOCITY = np.array([14.0, 4.0, -8.0]), np.array([0.0, 1.0, 0.0])
FRAME, GUARD = 0.2, 0.02
ENVELOPE_RATE = SignalConfig().envelope_rate  # Hz, the shipped fast path's


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
    waveform = synthesis.Waveform.random("tone", rng)
    for reflections in (False, True):
        paths = synthesis.path_sources(SOURCE, SOURCE_VELOCITY, reflections, 60.0, -0.9, 0.3)
        for label, baseband, rate in (
            (f"fast (baseband, {ENVELOPE_RATE / 1e3:g} kHz)", True, ENVELOPE_RATE),
            ("hardware (real, 200 kHz)", False, 200_000.0),
        ):

            def synthesize():
                return synthesis.synthesize(
                    waveform,
                    3.0,
                    FRAME + 2 * GUARD,
                    rate,
                    baseband,
                    paths,
                    MOBILE,
                    MOBILE_VELOCITY,
                    FIXED,
                    1500.0,
                    140.0,
                    80.0,
                    rng,
                )

            channel = synthesize()
            envelope = frontend.envelopes(channel, waveform, ENVELOPE_RATE, GUARD)
            costs = {
                "synthesis": median_ms(synthesize, args.repeats),
                "filtering": median_ms(
                    lambda: frontend.envelopes(channel, waveform, ENVELOPE_RATE, GUARD), args.repeats
                ),
                # A tone's correlation and TDOA / FDOA stages run as one compiled pass (kernels.tone_estimate).
                "correlation + TDOA / FDOA": median_ms(
                    lambda: frontend.estimate(envelope, waveform, 1500.0, 0.03, noise_level_db=80.0), args.repeats
                ),
            }
            line = ", ".join(f"{name} {cost:.2f} ms" for name, cost in costs.items())
            print(f"reflections {'on ' if reflections else 'off'} {label}: {line}, total {sum(costs.values()):.2f} ms")
            if not baseband:
                rows = np.array([channel.mobile, channel.fixed])  # laid out as the filtering lays them out
                # Timed in alternation, so that both see the machine in the same state; the median ratio.
                pairs = [
                    (
                        median_ms(lambda: frontend.envelopes(channel, waveform, ENVELOPE_RATE, GUARD), 1),
                        median_ms(lambda: [np.fft.rfft(row) for row in rows], 1),
                    )
                    for _ in range(5 * args.repeats)
                ]
                ratio = statistics.median(filtering / ffts for filtering, ffts in pairs)
                ffts = statistics.median(ffts for _, ffts in pairs)
                print(f"    hardware filtering / its unavoidable FFTs ({ffts:.2f} ms): {ratio:.1f}x   [goal <= 2]")
    print(
        "env steps/s in signal mode (cv source, helix): all steps | the typical step (median: front end + UKF bank, "
        "without the steps that run LC-MAP)"
    )
    for label, kwargs in (
        ("free field, fast path", dict(reflections=False, multipath="none", config={"signal": {"path": "fast"}})),
        (
            "free field, fast path, one UKF, no re-seeding",
            dict(
                reflections=False, multipath="none", config={"initializer": {"hypotheses": 1, "reseed_interval": 0.0}}
            ),
        ),
        (
            "free field, hardware path",
            dict(reflections=False, multipath="none", config={"signal": {"path": "hardware"}}),
        ),
        ("reflections on, phasor filter, fast path (default world)", dict(config={"signal": {"path": "fast"}})),
    ):
        rates = [
            env_step_rates("AASL-Helix-v0", args.episodes, source_motion="cv", measurement="signal", **kwargs)
            for _ in range(max(1, args.repeats // 3))
        ]
        overall, typical = (statistics.median(rate[i] for rate in rates) for i in (0, 1))
        print(f"  {label}: {overall:,.0f} | {typical:,.0f}   [goal >= 1,000 on the fast path]")


if __name__ == "__main__":
    main()
