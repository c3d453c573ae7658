#!/bin/bash
# The device check of docs/engines.md ("The thesis' PPO setting on the letters, on a GPU"), one script for
# a lent GPU machine (one command, everything it writes under $OUT):
#   1. bench/engine.py's MuJoCo rows on every core, 2. the hand_thesis learner on the GPU (--ppo),
#   3. experiment=letters_thesis on MuJoCo, letters x seeds all at once, MIN minutes of training each,
#   4. the run folders (no checkpoints) as $OUT/letters_thesis_mujoco.tgz; the table is made afterwards with
#      python -m aslexp.reports.thesis_report <folder>.
# Before: wheels for the machine's Python in outputs/gpu/wheels (mujoco, mujoco-core, hydra-core, omegaconf,
# gymnasium, farama-notifications, tensordict, torchrl, glfw, optuna, colorlog, pyvers), antlr4 (pure Python)
# in outputs/gpu/pylib, ../shared/data/{motions,models} in outputs/gpu/data; carry outputs/gpu.
# On the CPU (its test): OUT=/tmp/x DEV=cpu MIN=0.05 LETTERS=A SEEDS=0 BENCH=0 NOPIP=1 bash bench/gpu_letters_thesis.sh
# All five letters x 3 seeds at 5 M steps each, one command on a 16-core H200 machine:
#   OUT=... BENCH=0 MIN=60 KILL=3900 EXTRA="ppo.total_steps=5000000" bash bench/gpu_letters_thesis.sh
# Estimate (BENCHMARKS.md, 15 runs at once: 1,800-2,600 steps/s per run with evaluations):
# 32-46 minutes per run, the 15 at the same time, so about 50 minutes of machine time with start-up.
# A lease of 15 minutes (10 per call) does not hold it: it needs a longer loan or a node of one's own.
set -u
OUT=${OUT:?set OUT to a folder}
MIN=${MIN:-5.5}; LETTERS=${LETTERS:-A B C D E}; SEEDS=${SEEDS:-0 1 2}
KILL=${KILL:-510}; BENCH=${BENCH:-1}
source bench/gpu_machine.sh
$PY - <<'PY' || { el "SMOKE FAILED"; exit 3; }
import torch, mujoco, torchrl
print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "mujoco", mujoco.__version__, "torchrl", torchrl.__version__)
from aslexp.envs.batched import BatchedImitationEnv
env = BatchedImitationEnv(4, "motions/hand/A.txt", engine="mujoco", env="hand_thesis", reward="hand_thesis"); env.reset(seed=0); print("env ok")
PY
if [ "$BENCH" = 1 ]; then
  el "engine bench"
  timeout 120 $PY bench/engine.py --bodies "hand 240 Hz,hand 30 Hz" --sizes 64,256,1024 --seconds 1.4 --json "$OUT/engine.json" 2>&1 | tail -30
  el "ppo split, learner on $DEV"
  timeout 150 $PY bench/engine.py --bodies none --ppo 256 --ppo-updates 3 --device "$DEV" --rollout-device learner --json "$OUT/ppo_split.json" 2>&1 | tail -12
fi
el "letters_thesis on MuJoCo: letters $LETTERS x seeds $SEEDS at once, learner on $DEV, $MIN min each"
RUNS=${RUNS:-$R/outputs/gpu_runs/letters_thesis_mujoco}; mkdir -p "$RUNS"
SMI=
if command -v nvidia-smi >/dev/null; then
  nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 10 > "$RUNS/nvidia_smi.csv" 2>&1 &
  SMI=$!
fi
PIDS=()
for m in $LETTERS; do for s in $SEEDS; do
  timeout -s INT "$KILL" $PY -m aslexp.cli imitate experiment=letters_thesis engine=mujoco engine.threads=1 motion=$m seed=$s \
    ppo.device=$DEV ppo.rollout_device=learner ppo.vector_env=batched ppo.num_envs=64 ppo.torch_threads=1 \
    ppo.max_minutes=$MIN ppo.eval_interval=256000 ppo.progress_interval=60 render.gif=false render.mp4=false \
    ${EXTRA:-} hydra.run.dir="$RUNS/${m}_s${s}" > "$RUNS/${m}_s${s}.out" 2>&1 &
  PIDS+=($!)
done; done
FAILED=0
for pid in "${PIDS[@]}"; do wait "$pid" || FAILED=$((FAILED + 1)); done
[ -n "$SMI" ] && kill "$SMI" 2>/dev/null
el "runs done, $FAILED failed"
for f in "$RUNS"/*.out; do echo "== $f"; tail -3 "$f"; done
(cd "$(dirname "$RUNS")" && tar czf "$OUT/letters_thesis_mujoco.tgz" --exclude=checkpoints --exclude='tracking*.png' "$(basename "$RUNS")")
ls -la "$OUT"
el "end"
exit $FAILED
