#!/usr/bin/env bash
# The device check: Four-Rooms FB and Belief-FB at the paper's sizes, then Belief-FB,
# Rotation-FB and FB at the authors' settings with 3 vmapped seeds, each for as many updates
# as fit its share of 7 minutes: learning curves and updates/s (experiments/gpu_check.py).
# On a machine without a GPU the same path runs at tiny sizes.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
test -x "$PY" || PY=python3
# the JSON summary goes to $GPU_CHECK_OUT, or into $OUT (the device tool's return folder), or /tmp
exec "$PY" experiments/gpu_check.py --budget "${BUDGET:-420}" --out "${GPU_CHECK_OUT:-${OUT:-/tmp}/gpu_check.json}" "$@"
