"""Where the test suite's time goes, from a timeline tests/conftest.py wrote.

    ASLEXP_TEST_TIMELINE=/tmp/timeline.jsonl bash scripts/test.sh
    python scripts/suite_timeline.py /tmp/timeline.jsonl [--files 25]

Prints the span (first test's start to last test's end), each worker's busy time and when it
finished (the others' wait at the end is the schedule's loss), each xdist group's time and when it
ran (tests/conftest.py's waiting lane among them), and the files by their total time (setup, call
and teardown of every test in them).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("timeline", type=Path)
    parser.add_argument("--files", type=int, default=25, help="how many files to list (slowest first)")
    args = parser.parse_args(argv)
    try:
        lines = [json.loads(line) for line in args.timeline.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as err:
        print(f"suite_timeline: {args.timeline}: expected the JSON lines ASLEXP_TEST_TIMELINE writes ({err})",
              file=sys.stderr)
        return 2
    if not lines:
        print(f"suite_timeline: {args.timeline}: no tests recorded", file=sys.stderr)
        return 2
    first, last = min(r["start"] for r in lines), max(r["stop"] for r in lines)
    busy: dict[str, float] = defaultdict(float)
    end: dict[str, float] = defaultdict(float)
    by_file: dict[str, float] = defaultdict(float)
    groups: dict[str, list] = {}  # xdist_group -> [busy, start, stop, workers] (ids end in "@group" under loadgroup)
    for r in lines:
        took = r["stop"] - r["start"]
        busy[r["worker"]] += took
        end[r["worker"]] = max(end[r["worker"]], r["stop"])
        by_file[r["test"].split("::")[0]] += took
        if r["test"].rfind("@") > r["test"].rfind("]"):  # pytest-xdist's own rule (an id's [..] may hold an @)
            g = groups.setdefault(r["test"].rsplit("@", 1)[1], [0.0, r["start"], r["stop"], set()])
            g[0] += took
            g[1], g[2] = min(g[1], r["start"]), max(g[2], r["stop"])
            g[3].add(r["worker"])
    span = last - first
    print(f"span {span:.0f} s, {len({r['test'] for r in lines})} tests, {sum(busy.values()):.0f} worker-seconds "
          f"in tests on {len(busy)} workers")
    for worker in sorted(busy):
        print(f"  {worker}: busy {busy[worker]:.0f} s, done at {end[worker] - first:.0f} s "
              f"(then waited {last - end[worker]:.0f} s)")
    if groups:  # a group runs on one worker, in turn: the longest bounds the span from below
        print("groups (xdist_group, each on one worker):")
        for name, (took, start, stop, workers) in sorted(groups.items(), key=lambda item: -item[1][0]):
            print(f"  {took:7.1f} s  {name}: from {start - first:.0f} s to {stop - first:.0f} s on "
                  f"{', '.join(sorted(workers))}")
    print(f"files by time (the {args.files} slowest):")
    for path, took in sorted(by_file.items(), key=lambda item: -item[1])[: args.files]:
        print(f"  {took:7.1f} s  {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
