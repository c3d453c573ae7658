# Sourced by the lent GPU machine's scripts (bench/gpu_*.sh), from the repository root, with OUT set:
# the log under $OUT, the paths, the carried data and wheels (outputs/gpu: bench/gpu_letters_thesis.sh
# says which), `el` for timed log lines, and the machine's description. WHEELS: the wheel folders to install.
exec > >(tee "$OUT/log.txt") 2>&1
date; uptime
START=$(date +%s)
el() { echo "[$(( $(date +%s) - START )) s] $*"; }
R=$PWD
export PYTHONPATH=$R/src:$R/outputs/gpu/pylib${PYTHONPATH:+:$PYTHONPATH}
# MuJoCo renders nothing here (GIFs are drawn by PyBullet, and off): no OpenGL, whose EGL import fails without libEGL
export MUJOCO_GL=disable OMP_NUM_THREADS=1 MPLBACKEND=Agg
# The data: ASLEXP_DATA_ROOT, else the carried copy, else the configs' default (../shared/data).
if [ -z "${ASLEXP_DATA_ROOT:-}" ] && [ -d "$R/outputs/gpu/data" ]; then export ASLEXP_DATA_ROOT=$R/outputs/gpu/data; fi
PY=${PY:-python3}; DEV=${DEV:-cuda}
if [ -z "${NOPIP:-}" ]; then
  el "install"
  $PY -m pip install --no-index --no-deps -q ${WHEELS:-"$R"/outputs/gpu/wheels/*.whl} > "$OUT/pip.log" 2>&1 \
    || { el "pip failed"; tail -5 "$OUT/pip.log"; }
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null
echo "cores: $(getconf _NPROCESSORS_ONLN)"; $PY -V
