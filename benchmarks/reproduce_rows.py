"""Whether committed study rows still reproduce to the last bit: re-runs some episodes of an ``evaluate.py`` study
- its log (``episodes.jsonl``: its config line, then one row per episode) or, where no log was committed, its
``results.json`` (the config, the command and the rows) - with the code as it is, and compares each row with the
committed one, field by field.

    OPENBLAS_CORETYPE=Haswell python benchmarks/reproduce_rows.py reports/tracker/heldout_free/episodes.jsonl
        reports/patrol/default_world/results.json [--rows 8] [--workers 2]

``--rows`` picks that many rows spread evenly over the log (every motion and policy in it gets its share); ``--rows
0`` takes them all. Exits 1 if any row differs. A refactoring must change none (the project's rule); a change meant to
alter results re-runs the studies instead. The committed rows were written with OpenBLAS's Haswell kernels and one
thread: on a machine with AVX-512, other kernels round differently from about the 12th digit, hence the variable.
Logs of ``paper.py``'s studies (rows with a variant) are not taken: their configs are the variants'.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")


def read_log(path: Path) -> tuple[dict, list[dict]]:
    """The log's config and its entries ({"key": [...], "row": {...}}); a torn last line is skipped, as a resume
    skips it. A ``results.json`` gives its config and its rows, each keyed as the log would key it."""
    if path.suffix == ".json":
        return read_results(path)
    lines = path.read_text().splitlines()
    if not lines:
        raise ValueError(f"{path} is empty")
    try:
        config = json.loads(lines[0])["config"]
    except (KeyError, TypeError, json.JSONDecodeError):
        raise ValueError(f"{path} does not start with a config line (is it an evaluate.py log?)") from None
    entries = []
    for line in lines[1:]:
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return config, entries


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


def rerun(task: tuple[dict, dict]) -> dict:
    """The row the logged ``entry``'s episode gives now, under the log's ``config`` (its paths kept where the logged
    row kept them, for the trajectory plots)."""
    from aasl_gym.study.jobs import Job
    from agents.study import run_episode

    config, entry = task
    policy, initializer, motion, measurement, seed, filter_model = entry["key"]
    record = "trajectory" in entry["row"]
    row = run_episode(Job(policy, initializer, motion, measurement, seed, config, filter_model, record))
    return json.loads(json.dumps(row))  # as the log holds it: tuples as lists, floats through repr


def differences(logged: dict, now: dict) -> list[str]:
    """The fields (dotted for nested ones) whose values differ between the two rows, with both values."""
    found = []
    for name in sorted(set(logged) | set(now)):
        old, new = logged.get(name), now.get(name)
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
    parser.add_argument("logs", type=Path, nargs="+", help="episodes.jsonl of an evaluate.py study")
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
        if any(len(entry["key"]) != 6 for entry in entries):
            print(f"error: {path} holds rows of a paper.py study (keys with a variant): not taken", file=sys.stderr)
            return 2
        entries = [entry for entry in entries if args.policies is None or entry["key"][0] in args.policies]
        if not entries:
            print(f"error: {path} holds no rows" + (f" of {args.policies}" if args.policies else ""), file=sys.stderr)
            return 2
        tasks += [(path, config, entry) for entry in spread(entries, args.rows)]
    start, mismatched = time.perf_counter(), 0
    with Pool(args.workers) as pool:
        rows = pool.imap(rerun, [(config, entry) for _, config, entry in tasks])
        for (path, _, entry), now in zip(tasks, rows):
            found = differences(entry["row"], now)
            mismatched += bool(found)
            print(f"{'DIFFERS' if found else 'same   '} {path.parent.name} {entry['key']}")
            for line in found:
                print(f"        {line}")
    print(f"{len(tasks) - mismatched} of {len(tasks)} rows reproduce ({time.perf_counter() - start:.0f} s)")
    return 1 if mismatched else 0


if __name__ == "__main__":
    sys.exit(main())
