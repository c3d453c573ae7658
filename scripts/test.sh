#!/usr/bin/env bash
# Set up everything the test suite needs, then run it. `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# Optional services and worker environments used by some tests (each script is idempotent).
[ -f scripts/setup_mediapipe.sh ] && bash scripts/setup_mediapipe.sh
[ -f scripts/ci_postgres.sh ] && bash scripts/ci_postgres.sh
# A real single-node Slurm on loopback for tests/platform/test_slurm.py (as root). If it cannot
# start, the Slurm tests fail under CI=true and skip elsewhere (they say why).
[ -f scripts/ci_slurm.sh ] && { bash scripts/ci_slurm.sh || echo "test.sh: scripts/ci_slurm.sh failed (see above)"; }
export MPLBACKEND=Agg
# One process per core and one more (pytest-xdist; at most 8; ASLEXP_TEST_WORKERS=N to choose): the
# extra worker runs the lane of tests that mostly wait (Slurm, sweeps whose trials sleep or are
# signalled) while the others keep every core busy (tests/conftest.py; on 2 cores, 2 workers left a
# fifth of the CPU idle: 407 s against 338 s with 3). Tests sharing a service or a fixture's files
# stay on one worker. `-n 0` runs in one process.
# The 20 slowest tests and the suite's wall time are printed at the end (the suite's budget: 15 minutes).
# (the cores this process may use, as `-n auto` counts them; nproc would read OMP_NUM_THREADS)
workers=${ASLEXP_TEST_WORKERS:-$(.venv/bin/python -c 'import os; print(len(os.sched_getaffinity(0)) + 1)')}
start=$(date +%s)
status=0
.venv/bin/python -m pytest -q -n "$workers" --maxprocesses 8 --dist loadgroup \
  --durations=20 --durations-min=1 "$@" || status=$?
echo "test.sh: the suite took $(( $(date +%s) - start )) s"
exit $status
