"""Start-up of the command line: `aslexp <job> --help`, a job's first import, and with --workers the
start of rollout worker processes.

    python bench/cli_startup.py [--repeats 5] [--hydra] [--workers]

Prints the median wall time of each command (a fresh interpreter each time), so that the help
a newcomer types first stays instant: it is read from the config files, without importing the
job, torch or Hydra. For comparison, Hydra's own help (`python -m aslexp.jobs.JOB --help`)
composes every config group of the search path. ``--workers``: two rollout workers of the hand
(``vector_env=workers``) started and stopped ``--repeats`` + 1 times in one process; the first start
includes the forkserver's imports, the later ones fork from it (aslexp.rl.vector.worker_context).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

JOBS = ("recognize", "imitate", "tune_pd")
WORKERS = """
import functools, statistics, sys, time
from aslexp.data.root import resolve_data_root
from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.policy import ModelSpec
from aslexp.rl.ppo import agent_for_spaces
from aslexp.rl.workers import PolicyWorkers

if __name__ == "__main__":
    motion = resolve_data_root(None) / "motions" / "hand" / "A.txt"
    times = []
    for _ in range(int(sys.argv[1]) + 1):
        start = time.perf_counter()
        workers = PolicyWorkers(functools.partial(ImitationEnv, motion), 2, functools.partial(agent_for_spaces, ModelSpec()))
        times.append(time.perf_counter() - start)
        workers.close()
    print(f"{times[0]:.2f} {statistics.median(times[1:]):.2f}")
"""


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
    parser.add_argument("--workers", action="store_true", help="also time the start of two rollout workers")
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
    if args.workers:
        first, later = subprocess.run([py, "-c", WORKERS, str(args.repeats)], capture_output=True, text=True,
                                      check=True).stdout.split()
        print(f"| two rollout workers, the first start (the forkserver imports) | {first} |")
        print(f"| two rollout workers, each later start (forked from it) | {later} |", flush=True)


if __name__ == "__main__":
    main()
