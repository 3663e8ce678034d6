"""Whether committed study rows still reproduce to the last bit: re-runs some episodes of a study - its log
(``episodes.jsonl``: its config line, then one row per episode; ``evaluate.py``'s or ``paper.py``'s) or, where no log
was committed, an ``evaluate.py`` study's ``results.json`` (the config, the command and the rows) - with the code as
it is, and compares each row with the committed one, field by field (but the wall-clock timings ``ms_mean`` and
``ms_median`` of the fixed-array study).

    OPENBLAS_CORETYPE=Haswell python benchmarks/reproduce_rows.py reports/tracker/heldout_free/episodes.jsonl
        reports/patrol/default_world/results.json [--rows 8] [--workers 2]

``--rows`` picks that many rows spread evenly over the log (every motion and policy in it gets its share); ``--rows
0`` takes them all. Exits 1 if any row differs. A refactoring must change none (the project's rule); a change meant to
alter results re-runs the studies instead. The committed rows were written with OpenBLAS's Haswell kernels and one
thread: on a machine with AVX-512, other kernels round differently from about the 12th digit, hence the variable.
A ``paper.py`` log holds its study's scenario config and its variants' changes; a row names its variant, which the
study as ``paper.py`` makes it (its coefficient grid and drift read from the log) maps to those changes.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path
from typing import Any

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

TIMINGS = {"ms_mean", "ms_median"}  # wall-clock fields of a row: never the same twice


def read_log(path: Path) -> tuple[dict, list[dict]]:
    """The log's config and its entries ({"key": [...], "row": {...}}), as a resume reads them
    (:meth:`aasl_gym.study.log.EpisodeLog.read`: a torn last line skipped). A ``results.json`` gives its config and its
    rows, each keyed as the log would key it."""
    from aasl_gym.study.log import EpisodeLog

    if path.suffix == ".json":
        return read_results(path)
    with open(path) as handle:
        first = handle.readline()
    try:
        config = json.loads(first)["config"]
    except (KeyError, TypeError, json.JSONDecodeError):
        raise ValueError(f"{path} does not start with a config line (is it an evaluate.py log?)") from None
    rows = EpisodeLog(path, config).read()
    return config, [{"key": list(key), "row": row} for key, row in rows.items()]


def read_results(path: Path) -> tuple[dict, list[dict]]:
    """A ``results.json``'s config and its rows keyed as in a log: the filter model per motion as its command's
    ``--filter-model`` chose it (the log's key holds the choice; the results hold the command)."""
    from aasl_gym.study.jobs import MATCHED_FILTER

    try:
        results = json.loads(path.read_text())
        config, rows, command = results["config"], results["episodes"], results["command"].split()
    except (KeyError, AttributeError, json.JSONDecodeError):
        raise ValueError(f"{path} is not an evaluate.py results.json (config, command and episodes)") from None
    choice = command[command.index("--filter-model") + 1] if "--filter-model" in command else None

    def filter_model(motion: str) -> str | None:
        return MATCHED_FILTER[motion] if choice == "matched" else choice

    keys = [
        (r["policy"], r["initializer"], r["motion"], r["measurement"], r["seed"], filter_model(r["motion"]))
        for r in rows
    ]
    return config, [{"key": list(key), "row": row} for key, row in zip(keys, rows)]


def spread(entries: list[dict], count: int) -> list[dict]:
    """``count`` of ``entries`` spaced evenly from the first to the last (all of them for 0 or more than there are)."""
    if count <= 0 or count >= len(entries):
        return entries
    if count == 1:
        return entries[:1]
    return [entries[round(i * (len(entries) - 1) / (count - 1))] for i in range(count)]


def jobs_of(config: dict, entries: list[dict]) -> list[tuple[Any, str]]:
    """Each entry's job and how a study runs it (``episode``, a paper study's ``trial`` or ``array`` trial): under the
    log's ``config`` for an ``evaluate.py`` log, under its variant's for a ``paper.py`` one (whose config line is the
    study's header). Paths are kept where the committed row kept them, for the trajectory plots."""
    from aasl_gym.config import from_dict, merge, to_dict
    from aasl_gym.study.jobs import Job

    variants = paper_variants(config) if "variants" in config and "base" in config else None
    jobs = []
    for entry in entries:
        key, record = entry["key"], "trajectory" in entry["row"]
        if variants is None:
            jobs.append((Job(*key[:5], config, key[5], record), "episode"))
            continue
        if len(key) != 7 or key[6] not in variants:
            raise ValueError(f"row {key} names no variant of the {config['study']} study")
        data = to_dict(from_dict(merge(config["base"], variants[key[6]])))
        jobs.append((Job(*key[:5], data, key[5], record, key[6]), "array" if config["study"] == "arrays" else "trial"))
    return jobs


def paper_variants(header: dict) -> dict[str, dict]:
    """A ``paper.py`` log's variants by name: their changes, as the study ``paper.py`` makes holds them (the coefficient
    grid's size and the navigation drift tried until the changes are the log's)."""
    from aasl_gym.study.paper import make_study

    written = header["variants"]
    drifts = {(changes.get("receiver") or {}).get("nav_drift_sd") or 0.0 for changes in written}
    for grid in range(1, 21):
        for drift in sorted(drifts | {0.0}):
            study = make_study(header["study"], grid=grid, drift=drift)
            if json.loads(json.dumps([variant.changes for variant in study.variants])) == written:
                return {variant.name: variant.changes for variant in study.variants}
    raise ValueError(f"the {header['study']} study's variants are none that paper.py makes (grid 1-20, its drifts)")


def rerun(task: tuple[Any, str]) -> dict:
    """The row ``job`` gives now, run as its study runs it (``kind``)."""
    from agents.study import run_array_trial, run_episode, run_trial

    job, kind = task
    run = {"episode": run_episode, "trial": run_trial, "array": run_array_trial}[kind]
    return json.loads(json.dumps(run(job)))  # as the log holds it: tuples as lists, floats through repr


def differences(logged: dict, now: dict) -> list[str]:
    """The fields (dotted for nested ones) whose values differ between the two rows, with both values."""
    found = []
    for name in sorted(set(logged) | set(now)):
        old, new = logged.get(name), now.get(name)
        if name in TIMINGS:
            continue
        if isinstance(old, dict) and isinstance(new, dict):
            found += [f"{name}.{field}" for field in differences(old, new)]
        elif old != new:
            found.append(f"{name}: logged {_short(old)}, now {_short(new)}")
    return found


def _short(value, width: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "logs", type=Path, nargs="+", help="a study's episodes.jsonl (evaluate.py's, paper.py's) or results.json"
    )
    parser.add_argument("--rows", type=int, default=8, help="rows per log, spread over it (0: all)")
    parser.add_argument("--policies", nargs="+", help="only these policies' rows (default: every policy's)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be at least 1, got {args.workers}")
    if "OPENBLAS_CORETYPE" not in os.environ:
        print("note: OPENBLAS_CORETYPE is not set; the committed rows were written with Haswell's kernels")
    tasks = []
    for path in args.logs:
        try:
            config, entries = read_log(path)
        except (OSError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        entries = [entry for entry in entries if args.policies is None or entry["key"][0] in args.policies]
        if not entries:
            print(f"error: {path} holds no rows" + (f" of {args.policies}" if args.policies else ""), file=sys.stderr)
            return 2
        entries = spread(entries, args.rows)
        try:
            jobs = jobs_of(config, entries)
        except (ValueError, KeyError) as exc:
            print(f"error: {path}: {exc}", file=sys.stderr)
            return 2
        if any(kind == "array" for _, kind in jobs) and importlib.util.find_spec("cvxpy") is None:
            print(f"error: {path}: the fixed-array study needs cvxpy: pip install -e '.[arrays]'", file=sys.stderr)
            return 2
        tasks += [(path, entry, job) for entry, job in zip(entries, jobs)]
    start, mismatched = time.perf_counter(), 0
    with Pool(args.workers) as pool:
        rows = pool.imap(rerun, [job for _, _, job in tasks])
        for (path, entry, _), now in zip(tasks, rows):
            found = differences(entry["row"], now)
            mismatched += bool(found)
            print(f"{'DIFFERS' if found else 'same   '} {path.parent.name} {entry['key']}")
            for line in found:
                print(f"        {line}")
    print(f"{len(tasks) - mismatched} of {len(tasks)} rows reproduce ({time.perf_counter() - start:.0f} s)")
    return 1 if mismatched else 0


if __name__ == "__main__":
    sys.exit(main())
