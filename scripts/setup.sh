#!/usr/bin/env bash
# Create ./.venv with everything aslexp needs (idempotent; re-running is quick).
# torch is pinned to 2.13.0 (a local CPU wheel here); nothing else may upgrade it.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
. .venv/bin/activate
export PIP_DISABLE_PIP_VERSION_CHECK=1
pip install -q --upgrade pip setuptools wheel 2>&1 | grep -v "is ignored" || true
# torch first, so that every later requirement sees 2.13.0 as satisfied.
pip install -q "torch==2.13.0" 2>&1 | grep -v "is ignored" || true
# The wandb extra too: logger=wandb and its tests (offline unless a W&B key is configured); and mjx
# (engine=mjx: mujoco-mjx and the CPU jax: ~25 s more on a first install, jaxlib ~350 MB on disk; mujoco and torch kept).
pip install -q -e ".[dev,wandb,mjx]" 2>&1 | grep -v "is ignored" || true
# Sweeps use aslexp's own Optuna sweeper (src/hydra_plugins/aslexp_optuna_sweeper), not the stock
# hydra-optuna-sweeper 1.3.0: that one pins optuna<3 and cannot resume to a total budget, prune or
# run asynchronous workers. Nothing here installs it (if present, our plugin hides its configs).
python - <<'PY'
import torch, optuna, hydra, pybullet, mujoco, torchrl, tensorboard, pose_format, wandb  # noqa: F401
assert torch.__version__.startswith("2.13.0"), torch.__version__
print(f"aslexp environment ready: torch {torch.__version__}, optuna {optuna.__version__}, hydra {hydra.__version__}")
PY
