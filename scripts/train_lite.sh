#!/usr/bin/env bash
# Reproduce the shipped lite weights (phyir/weights/phyir-lite.*) on a CPU: the exact recipe used.
# Usage: bash scripts/train_lite.sh [DATA_DIR] [RUN_DIR]     (inside the set-up's environment)
# The data generator runs in the background while GMNet trains on the scenes already present;
# every stage is resumable (re-run the script after an interruption).
set -euo pipefail
data=${1:-data/s128}
run=${2:-runs/lite}
export OMP_WAIT_POLICY=PASSIVE
common=(--data "$data" --out "$run" --size native --probe-grid native --schedule cosine --workers 0 --no-progress)

mkdir -p "$data"
if [ ! -f "$data/scene_000063.exr" ]; then   # the first 64 scenes before training starts
  phyir synth --out "$data" --count 3000 --seed 0 --size 128x256 --probe-grid 16x32 --spp 8 --quiet &
  synth=$!
  while [ ! -f "$data/scene_000063.exr" ]; do sleep 10; done
else
  nice -n 19 phyir synth --out "$data" --count 3000 --seed 0 --size 128x256 --probe-grid 16x32 --spp 8 \
    --quiet &
  synth=$!
fi
trap 'kill $synth 2>/dev/null || true' EXIT

phyir train "${common[@]}" --stage gm --epochs 120 --lr 3e-4 --max-minutes 50
phyir train "${common[@]}" --stage light --epochs 40 --lr 3e-4 --max-minutes 30
phyir train "${common[@]}" --stage joint --epochs 3 --max-minutes 10
phyir train "${common[@]}" --stage gs --epochs 15 --max-minutes 10
python -m phyir.weights ship "$run/gs/model.safetensors" phyir/weights/phyir-lite.safetensors
