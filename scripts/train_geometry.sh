#!/usr/bin/env bash
# GMNet on the pretrained EfficientNet-Lite0 encoder, trained on procedural rooms in the background.
# Every step resumes: rooms already rendered are kept, the training continues from its checkpoint.
# Usage (inside the set-up's environment):
#   bash scripts/train_geometry.sh [DATA_DIR] [RUN_DIR] [MINUTES] [ROOMS]
# One core renders rooms while the other trains (both nice'd). CPU-hours: docs/training.md.
set -euo pipefail
data=${1:-data/geo128}
run=${2:-runs/geometry}
minutes=${3:-60}
rooms=${4:-6000}
export OMP_WAIT_POLICY=PASSIVE
mkdir -p "$run"
OMP_NUM_THREADS=1 nice -n 19 phyir synth --out "$data" --count "$rooms" --seed 100000 --size 128x256 \
  --probe-grid none --spp 8 --quiet &
synth=$!
trap 'kill $synth 2>/dev/null || true' EXIT
sleep 5
OMP_NUM_THREADS=1 nice -n 19 phyir train --config scripts/train_geometry.toml --data "$data" --out "$run" \
  --max-minutes "$minutes"
