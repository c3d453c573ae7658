#!/bin/bash
# Table 6.7's runs as one program on a lent GPU machine: experiment=signs_thesis_run$RUN (the thesis'
# standing upper body, PD, reward of Table 6.4 Run 3, 240 Hz and the PPO of Table 6.3, Run 1 or 2) for the
# four signs x seeds, all trained together (bench/gpu_stacked_letters.sh's machinery: one MuJoCo batch, one
# stacked network), MIN minutes; under $OUT: log.txt, signs_run$RUN.tgz (run folders, no checkpoints) and
# summary.json (per sign: untrained, no-learning baselines, last evaluation mean ± std over seeds).
# On the CPU (its test): OUT=/tmp/x DEV=cpu MIN=0.05 SIGNS=00433 SEEDS=0,1 NOPIP=1 bash bench/gpu_stacked_signs.sh
# The whole column (4 signs x 10 seeds, 40 runs) in one call of at most 10 minutes:
#   OUT=... RUN=1 MIN=7 bash bench/gpu_stacked_signs.sh      # and RUN=2
set -u
RUN=${RUN:-1}
export EXPERIMENT=signs_thesis_run$RUN NAME=signs_run$RUN LETTERS=${SIGNS:-00433,52861,69318,69546}
exec bash bench/gpu_stacked_letters.sh
