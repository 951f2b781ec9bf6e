#!/usr/bin/env bash
# Creates the cross-check venv (.venv-crosscheck at the repo root) with the reference evaluator:
# mmdet3d without its dependencies (only two of its files are loaded, by path), numba, numpy<2.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="${CROSSCHECK_VENV:-$ROOT/.venv-crosscheck}"
PY="${PYTHON:-python3}"
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install --quiet --no-cache-dir --upgrade pip
"$VENV/bin/python" -m pip install --quiet --no-cache-dir "numpy<2" numba
"$VENV/bin/python" -m pip install --quiet --no-cache-dir --no-deps "mmdet3d==1.4.0"  # the version the cross-check was written against
echo "reference evaluator: $("$VENV/bin/python" "$ROOT/scripts/crosscheck_eval/reference.py" --locate)"
