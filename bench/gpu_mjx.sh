#!/bin/bash
# engine=mjx on a lent GPU machine, one command (everything it writes under $OUT; docs/engines.md, "MJX"):
#   1. smoke: jax sees the GPU, mujoco.mjx imports beside mujoco 4.0, an MJX batch steps;
#   2. tests/imitation/test_mjx_engine.py (its CUDA test runs there; the CPU ones too where time allows);
#   3. bench/mjx_engine.py: MJX physics steps/s on the GPU at N = 1k-64k (the device-resident path: step,
#      read, hand-off to torch by DLPack) for the hand and the upper body, and BatchedImitationEnv on mjx
#      (numpy in and out) beside engine=mujoco on the machine's cores;
#   4. the engine agreement table with its MJX column: python -m aslexp.measure.engine_agreement with the
#      columns MuJoCo (the CPU engine) and MJX (the GPU), letters A-E (the thesis PD and the tracking PD)
#      and the four signs, one process per motion at once, merged into $OUT/agreement.md / .json.
# Before, on the CPU machine (pip and the data are there, not on the GPU machine):
#   PREP=1 bash bench/gpu_mjx.sh        # wheels for its Python 3.12 in outputs/gpu/wheels, antlr4 in
#                                       # outputs/gpu/pylib, the motions and models in outputs/gpu/data
# then carry outputs/gpu: run(command="OUT=\$OUT bash bench/gpu_mjx.sh", carry=["outputs/gpu"], timeout_s=590).
# On the CPU (its test, in miniature):
#   PY=.venv/bin/python OUT=/tmp/x NOPIP=1 DEV=cpu SIZES=1,4 ENV_SIZES=1 BENCH_S=0.2 LETTERS=A SIGNS= ROW_S=0.2 TESTS= bash bench/gpu_mjx.sh
# Budget (a 15-minute lease, 10 per call): smoke ~1 min, bench <= BENCH_KILL (200 s), agreement <= KILL (300 s);
# XLA compiles every batch size, substep count and body once per process (on this 2-core machine 1-3 min each),
# so if one call does not hold it, split it: LETTERS= SIGNS= (the bench alone), then SIZES= ENV_SIZES= (the table);
# ROW_S (10 simulated seconds per row, the table's) can be cut to fit; the table's file says what it used.
set -u
if [ -n "${PREP:-}" ]; then
  set -e
  mkdir -p outputs/gpu/wheels outputs/gpu/pylib outputs/gpu/data
  PIP="${PIP:-.venv/bin/python -m pip}"
  $PIP download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d outputs/gpu/wheels \
    mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 glfw==2.11.0 pyopengl==3.1.10 websockets==17.4 \
    hydra-core==1.3.8 omegaconf==2.3.1 gymnasium==1.4.0 farama-notifications==0.0.6 tensordict==0.14.3 torchrl==0.14.1 \
    optuna==5.0.0 colorlog==6.12.0 pyvers==0.2.3 \
    mujoco-mjx==3.17.0 trimesh==5.2.0 2>&1 | grep -v "is ignored" || true
  $PIP install -q --no-deps --target outputs/gpu/pylib antlr4-python3-runtime==4.9.3 2>&1 | grep -v "is ignored" || true
  DATA=${ASLEXP_DATA_ROOT:-../shared/data}
  cp -r "$DATA/motions" "$DATA/models" outputs/gpu/data/
  [ -f "$DATA/README.md" ] && cp "$DATA/README.md" outputs/gpu/data/
  du -sh outputs/gpu/*; ls outputs/gpu/wheels
  exit 0
fi
OUT=${OUT:?set OUT to a folder}
# (an empty SIZES, ENV_SIZES, LETTERS or SIGNS: none of them)
SIZES=${SIZES-1024,4096,16384,65536}; ENV_SIZES=${ENV_SIZES-1024,4096}; BENCH_S=${BENCH_S:-3}
BODIES=${BODIES:-hand,upper}; LETTERS=${LETTERS-A B C D E}; SIGNS=${SIGNS-00433 52861 69318 69546}
ROW_S=${ROW_S:-10}; KILL=${KILL:-300}; BENCH_KILL=${BENCH_KILL:-200}
TESTS=${TESTS-tests/imitation/test_mjx_engine.py}
source bench/gpu_machine.sh
# one GPU shared by the bench's and the agreement's processes (and torch): no JAX preallocation; one
# compilation cache for all of them
export XLA_PYTHON_CLIENT_PREALLOCATE=false JAX_COMPILATION_CACHE_DIR=${JAX_COMPILATION_CACHE_DIR:-/tmp/jax_cache}
# float32 products in full float32 (a GPU's default for them is TF32, 10 mantissa bits): the physics' precision
export JAX_DEFAULT_MATMUL_PRECISION=${JAX_DEFAULT_MATMUL_PRECISION:-highest}
$PY - <<'PY' || { el "SMOKE FAILED"; exit 3; }
import jax, mujoco, torch
from aslexp.sim.mjx_engine import _jax
_, mjx = _jax()
print("jax", jax.__version__, jax.devices(), "mujoco", mujoco.__version__, "torch", torch.__version__,
      "cuda", torch.cuda.is_available())
from aslexp.envs.batched import BatchedImitationEnv
env = BatchedImitationEnv(1, "motions/hand/A.txt", engine="mjx", env="default", reward="hand_thesis")
env.reset(seed=0); env.step(env.action_space.sample() * 0); print("mjx env ok on", env.body.device)
PY
if [ -n "$TESTS" ]; then
  el "tests"
  timeout 240 $PY -m pytest -q -p no:cacheprovider -rfs $TESTS -k "gpu or refuses or reads" 2>&1 | tail -15
fi
el "bench: mjx physics N=$SIZES, env N=$ENV_SIZES, bodies $BODIES"
[ -n "$SIZES$ENV_SIZES" ] && timeout "$BENCH_KILL" $PY bench/mjx_engine.py --sizes "$SIZES" --env-sizes "$ENV_SIZES" --bodies "$BODIES" \
  --seconds "$BENCH_S" --json "$OUT/mjx_bench.json" 2>&1 | grep -v "^W0\|^I0"
el "agreement: MuJoCo (CPU) and MJX ($DEV), letters [$LETTERS], signs [$SIGNS], $ROW_S s per row"
AG=$OUT/agreement; mkdir -p "$AG"
COLUMNS='~columns.pybullet ~columns.mujoco_unclamped +columns.mjx={heading:MJX,engine:mjx} difference=[mjx,mujoco]'
PIDS=()
for m in $LETTERS; do
  timeout "$KILL" $PY -m aslexp.measure.engine_agreement --letters "$m" --signs "" --seconds "$ROW_S" \
    --out "$AG/$m" $COLUMNS > "$AG/$m.out" 2>&1 & PIDS+=($!)
done
for s in $SIGNS; do
  timeout "$KILL" $PY -m aslexp.measure.engine_agreement --letters "" --signs "$s" --seconds "$ROW_S" \
    --out "$AG/$s" $COLUMNS > "$AG/$s.out" 2>&1 & PIDS+=($!)
done
FAILED=0
for pid in "${PIDS[@]}"; do wait "$pid" || FAILED=$((FAILED + 1)); done
el "agreement processes done, $FAILED failed"
$PY - "$AG" "$OUT" "$ROW_S" $COLUMNS <<'PY'
import json, sys
from pathlib import Path
from aslexp.measure.engine_agreement import load_agreement, table
folder, out, seconds, overrides = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3], sys.argv[4:]
rows, missing = [], []
for part in sorted(folder.iterdir()):
    if part.is_dir():
        found = part / "agreement.json"
        rows += json.loads(found.read_text()) if found.is_file() else []
        missing += [] if found.is_file() else [part.name]
for name in (p.stem for p in folder.glob("*.out")):
    if not (folder / name / "agreement.json").is_file() and name not in missing:
        missing.append(name)
rows.sort(key=lambda r: (r["body"] != "hand", r["motion"]))
text = table(rows, load_agreement(overrides))
note = f"{seconds} s per row from phase 0" + (f"; not measured (stopped or failed): {', '.join(missing)}" if missing else "")
(out / "agreement.json").write_text(json.dumps(rows, indent=1))
(out / "agreement.md").write_text(text + "\n" + note + "\n")
print(text); print(note)
worst = max((abs(r["difference"]) for r in rows), default=float("nan"))
print(f"rows {len(rows)}; largest |MJX - MuJoCo| {worst:.4f}; within 0.01: {sum(abs(r['difference']) <= 0.01 for r in rows)}")
PY
for f in "$AG"/*.out; do [ -f "$f" ] && tail -2 "$f" | sed "s|^|$(basename "$f" .out): |"; done > "$OUT/agreement_tails.txt"
rm -rf "$AG"  # its tables are merged above; the files back are few
ls -la "$OUT"
el "end"
exit $FAILED
