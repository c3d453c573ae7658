"""Start-up of the command line: `aslexp <job> --help` and a job's first import.

    python bench/cli_startup.py [--repeats 5]

Prints the median wall time of each command (a fresh interpreter each time), so that the help
a newcomer types first stays instant: it is read from the config files, without importing the
job, torch or Hydra. For comparison, Hydra's own help (`python -m aslexp.jobs.JOB --help`)
composes every config group of the search path.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

JOBS = ("recognize", "imitate", "tune_pd")


def _seconds(argv: list[str], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--hydra", action="store_true", help="also time Hydra's own --help (slow)")
    args = parser.parse_args()
    py = sys.executable
    rows = [("aslexp --help", [py, "-m", "aslexp.cli", "--help"])]
    for job in JOBS:
        rows.append((f"aslexp {job} --help", [py, "-m", "aslexp.cli", job, "--help"]))
        rows.append((f"import aslexp.jobs.{job}", [py, "-c", f"import aslexp.jobs.{job}"]))
        if args.hydra:
            rows.append((f"Hydra's help of {job}", [py, "-m", f"aslexp.jobs.{job}", "--help"]))
    print(f"load average {os.getloadavg()[0]:.1f}, {args.repeats} repeats, median wall time")
    print("| command | s |")
    print("|---|---|")
    for name, argv in rows:
        print(f"| `{name}` | {_seconds(argv, args.repeats):.2f} |", flush=True)


if __name__ == "__main__":
    main()
