#!/bin/bash
# Figure 5.9's runs as one program on a lent GPU machine: experiment=letters_thesis (the thesis' hand, PD,
# reward, 240 Hz and PPO) for letters x seeds, all trained together by bench/stacked_letters.py (their
# environments one MuJoCo batch on every core, their policies one stacked network on the GPU), MIN
# minutes; everything it writes under $OUT: log.txt, the run folders without checkpoints as
# $OUT/letters_stacked.tgz ($NAME.tgz), summary.json (per letter: untrained, no-learning baselines, last evaluation
# mean ± std over seeds; steps per run and steps/s of the program).
# Before: the wheels and data of bench/gpu_letters_thesis.sh in outputs/gpu; carry outputs/gpu.
# On the CPU (its test): OUT=/tmp/x DEV=cpu MIN=0.05 LETTERS=A SEEDS=0,1 NOPIP=1 bash bench/gpu_stacked_letters.sh
# The whole figure (5 letters x 10 seeds, 50 runs) in one call of at most 10 minutes:
#   OUT=... MIN=7 bash bench/gpu_stacked_letters.sh
# aslexp's GPU-sized variant beside it (conf/ppo/hand_gpu.yaml: 2,048 environments a run):
#   OUT=... MIN=7 ENVS=2048 EXTRA=ppo=hand_gpu bash bench/gpu_stacked_letters.sh
set -u
OUT=${OUT:?set OUT to a folder}
MIN=${MIN:-7}; LETTERS=${LETTERS:-A,B,C,D,E}; SEEDS=${SEEDS:-0-9}; ENVS=${ENVS:-10}
EXPERIMENT=${EXPERIMENT:-letters_thesis}; NAME=${NAME:-letters_stacked}   # bench/gpu_stacked_signs.sh sets them
source bench/gpu_machine.sh
el "motions $LETTERS x seeds $SEEDS of $EXPERIMENT as one program, learner on $DEV, $MIN min"
RUNS=$OUT/$NAME
# the program stops itself after MIN minutes of training; the kill leaves 4 minutes for set-up and the last evaluations
timeout -s INT $(( ${MIN%.*} * 60 + 240 )) $PY bench/stacked_letters.py --experiment "$EXPERIMENT" --motions "$LETTERS" --seeds "$SEEDS" \
  --minutes "$MIN" --device "$DEV" --out "$RUNS" \
  --set ppo.num_envs=$ENVS engine.threads=$(getconf _NPROCESSORS_ONLN) ppo.progress_interval=30 ${EXTRA:-}
STATUS=$?
(cd "$OUT" && tar czf "$NAME.tgz" --exclude=checkpoints "$NAME")
cp "$RUNS/summary.json" "$OUT/summary.json" 2>/dev/null
el "end (exit $STATUS)"
exit $STATUS
