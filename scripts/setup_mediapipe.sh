#!/usr/bin/env bash
# Create ./.venv-mediapipe: the extraction worker's own environment (idempotent, quick on re-runs).
#
# Why a second venv: mediapipe 0.10.21 (the last release whose legacy `mp.solutions` API ships
# its models inside the wheel and runs offline) needs numpy<2, while the main stack (torch 2.13,
# scipy, ...) is on numpy 2. The main process never imports mediapipe: it starts
# `.venv-mediapipe/bin/python src/aslexp/pose/mediapipe_worker.py ...` and exchanges .npy files.
# Override the location with ASLEXP_MEDIAPIPE_VENV (the extractor reads the same variable).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${ASLEXP_MEDIAPIPE_VENV:-.venv-mediapipe}
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3
STAMP="$VENV/.aslexp-mediapipe-ready"
REQS='mediapipe==0.10.21 numpy<2'
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$REQS" ] && "$VENV/bin/python" -c "import mediapipe, cv2" 2>/dev/null; then
  echo "mediapipe environment ready (cached): $VENV"
  exit 0
fi
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
export PIP_DISABLE_PIP_VERSION_CHECK=1
"$VENV/bin/pip" install -q --upgrade pip wheel 2>&1 | grep -v "is ignored" || true
# shellcheck disable=SC2086
"$VENV/bin/pip" install -q $REQS 2>&1 | grep -v "is ignored" || true
"$VENV/bin/python" - <<'PY'
import cv2, mediapipe as mp, numpy as np
assert np.__version__.startswith("1."), np.__version__
assert hasattr(mp, "solutions"), "mediapipe without the legacy solutions API"
print(f"mediapipe environment ready: mediapipe {mp.__version__}, numpy {np.__version__}, opencv {cv2.__version__}")
PY
echo "$REQS" > "$STAMP"
