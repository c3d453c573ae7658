#!/bin/bash
# The GPU code paths on a lent GPU machine, one command (everything it writes under $OUT):
#   1. the imitation tests that need CUDA or MuJoCo (tests/imitation/test_engines.py: the batched PPO learner
#      on the GPU among them) and the PPO device tests; tests that need PyBullet fail there where it has no
#      wheel (Python 3.12): they are listed, not counted (grep "No module named 'pybullet'" in the log);
#   2. the imitate job end to end on MuJoCo with its learner on the GPU (ppo=hand_thesis, 2 minutes).
# Before: outputs/gpu/wheels (bench/gpu_letters_thesis.sh says which), outputs/gpu/testwheels (pytest, pluggy,
# iniconfig, scikit-learn, threadpoolctl, joblib for the machine's Python), outputs/gpu/pylib, outputs/gpu/data;
# carry outputs/gpu. On the CPU (its test, with one test and no baselines):
#   OUT=/tmp/x NOPIP=1 DEV=cpu MIN=0.02 TESTS=tests/imitation/test_assembly.py \
#     EXTRA="report.baselines=[] ppo.hidden_sizes=[32,32] ppo.eval_steps=30" bash bench/gpu_check.sh
set -u
OUT=${OUT:?set OUT to a folder}
MIN=${MIN:-2}
TESTS=${TESTS:-tests/imitation/test_engines.py tests/imitation/test_ppo_vector.py::test_device_switch}
WHEELS="$PWD/outputs/gpu/wheels/*.whl $PWD/outputs/gpu/testwheels/*.whl"
source bench/gpu_machine.sh
$PY -c "import torch, mujoco; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'mujoco', mujoco.__version__)"
el "tests"
timeout 300 $PY -m pytest -q -p no:cacheprovider -rfs $TESTS 2>&1 | tail -40
el "imitate on MuJoCo, learner on $DEV, $MIN min"
timeout 200 $PY -m aslexp.cli imitate experiment=letters_thesis engine=mujoco motion=B seed=0 ppo.device=$DEV \
  ppo.rollout_device=learner ppo.num_envs=64 ppo.max_minutes=$MIN ppo.eval_interval=102400 render.gif=false \
  render.mp4=false plots=false ${EXTRA:-} hydra.run.dir="$OUT/imitate_B" 2>&1 | tail -8
$PY -c "import json; m = json.load(open('$OUT/imitate_B/metrics.json')); print({k: m.get(k) for k in ('steps', 'last_eval', 'baselines', 'last_eval_diverged', 'device')})"
STATUS=0; [ -f "$OUT/imitate_B/metrics.json" ] || STATUS=1
el "end"
exit $STATUS
