"""Sweep overhead: trials per minute for a near-empty objective, and storage cost per trial.

    python bench/sweep_overhead.py                      # journal file, 1 and 2 workers
    python bench/sweep_overhead.py --trials 60 --postgres postgresql://aslexp:aslexp@127.0.0.1/aslexp_test

Part 1 runs the real thing: ``python -m aslexp.jobs.quadratic -m +sweeps=quadratic`` (Hydra,
the aslexp sweeper, the basic launcher, run directories), with 1 and 2 workers, and reports
trials per minute measured between the first trial's start and the last trial's end (so the
~2 s of interpreter and Hydra start-up is not counted), plus the command's wall time.
Part 2 runs the worker loop in-process with a launch that does nothing, so what is left is the
storage's cost per trial (budget lock, stale check, ask, attributes, tell).
The machine has 2 cores: 2 workers cannot double the rate of a CPU-bound trial.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import optuna
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState

from aslexp.tuning.algorithms import make_pruner, make_sampler
from aslexp.tuning.storage import open_storage, redact, silence_optuna
from aslexp.tuning.study import create_or_resume_study
from aslexp.tuning.worker import Outcome, WorkerSettings, run_worker


def sweep_rate(workers: int, trials: int, storage: str | None, root: Path) -> tuple[float, float]:
    sweep = root / f"sweep_w{workers}_{'pg' if storage else 'journal'}"
    name = f"bench_{os.getpid()}_{workers}_{int(time.time())}"
    cmd = [sys.executable, "-m", "aslexp.jobs.quadratic", "-m", "+sweeps=quadratic",
           f"hydra.sweep.dir={sweep}", f"hydra.sweeper.n_trials={trials}",
           f"hydra.sweeper.n_workers={workers}", "hydra/sweeper/sampler=random",
           "hydra.sweeper.sampler.seed=0", "hydra/sweeper/pruner=none"]
    if storage:
        cmd += [f"hydra.sweeper.storage='{storage}'", f"hydra.sweeper.study_name={name}"]
    started = time.perf_counter()
    subprocess.run(cmd, cwd=root, check=True, capture_output=True)
    wall = time.perf_counter() - started
    study = optuna.load_study(study_name=name if storage else "quadratic",
                              storage=open_storage(storage or str(sweep / "optuna.journal")))
    done = [t for t in study.trials if t.state == TrialState.COMPLETE]
    assert len(done) == trials, f"{len(done)} of {trials} trials completed"
    span = (max(t.datetime_complete for t in done) - min(t.datetime_start for t in done))
    return trials / span.total_seconds() * 60.0, wall


def storage_cost(spec: str, trials: int) -> float:
    """Milliseconds of sweep bookkeeping per trial when the job itself takes no time."""
    name = f"cost_{os.getpid()}_{int(time.time() * 1000)}"
    study = create_or_resume_study(spec, name, "maximize", pruner=make_pruner({"name": "none"}))
    study.sampler = make_sampler({"name": "random", "seed": 0})
    settings = WorkerSettings(storage_spec=spec, study_name=name, n_trials=trials,
                              heartbeat_interval=0)
    started = time.perf_counter()
    run_worker(study, {"x": FloatDistribution(-1, 1)}, settings,
               lambda trial: Outcome("complete", value=trial.params["x"]))
    return (time.perf_counter() - started) / trials * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--postgres", default=os.environ.get("ASLEXP_TEST_POSTGRES_URL"),
                        help="also measure a PostgreSQL storage at this URL")
    args = parser.parse_args()
    silence_optuna()
    import logging

    logging.getLogger("aslexp.tuning.worker").setLevel(logging.WARNING)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        print(f"near-empty objective (aslexp.jobs.quadratic), {args.trials} trials, "
              f"basic launcher, {os.cpu_count()} cores")
        storages = [("journal file", None)]
        if args.postgres:
            storages.append((f"postgresql ({redact(args.postgres)})", args.postgres))
        for label, storage in storages:
            for workers in (1, 2):
                rate, wall = sweep_rate(workers, args.trials, storage, root)
                print(f"  {label:<45} {workers} worker(s): {rate:7.1f} trials/min "
                      f"({60.0 / rate * 1000:6.0f} ms/trial; command wall {wall:5.1f} s)")
        print(f"storage overhead per trial (ask + bookkeeping + tell, no job), {args.trials} trials:")
        specs = [("journal file", str(root / "cost.journal")),
                 ("sqlite", f"sqlite:///{root / 'cost.db'}")]
        if args.postgres:
            specs.append(("postgresql", args.postgres))
        for label, spec in specs:
            print(f"  {label:<14} {storage_cost(spec, args.trials):7.1f} ms/trial")


if __name__ == "__main__":
    main()
