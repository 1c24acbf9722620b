#!/usr/bin/env bash
# A short GPU lease for the geometry (docs/training.md, "A GPU lease"): rooms of the wider generator
# (seed 100000, geometry only) rendered by every core and CUDA for the first half of the budget, then
# GMNet's decoders (scripts/gpu_effnet.toml) trained from the shipped weights on them; each result is
# shipped with the shipped LNet and GSNet into OUT (weights, logs, summary.json), ready for
# `phyir eval --scans DIR --weights OUT/gpu_effnet.safetensors`.
# Usage (inside the set-up's environment):
#   bash scripts/train_gpu.sh OUT [MINUTES] [more scripts/train_gpu.py options, e.g. --size 32x64]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?usage: bash scripts/train_gpu.sh OUT [MINUTES] [options]}
minutes=${2:-8}
shift $(($# >= 2 ? 2 : 1))
shipped=phyir/assets/weights/phyir-effnet.safetensors
exec "${PYTHON:-python}" scripts/train_gpu.py --minutes "$minutes" --results "$out" --out "$out/runs" \
  --data "${DATA:-data/gpu-geo}" --seed 100000 --probe-grid none --init "$shipped" --rest "$shipped" \
  "$@" scripts/gpu_effnet.toml
