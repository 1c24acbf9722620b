#!/usr/bin/env bash
# The fine-tune of the shipped GMNet on the wider generator (issue 19): halls up to 30 m and 8 m
# ceilings, white studios, dark ceilings, cameras 1.0-2.0 m high; the light-colour and camera-pipeline
# augmentations; log-depth L2 (the paper's L2 in metres is dominated by a hall's far walls) and the
# depth-normal consistency term. Starts from the weights of scripts/train_lite.sh; LNet and GSNet
# are kept. CPU time and results (tried, not shipped): docs/training.md ("Fine-tune on wider rooms").
# Usage (inside the set-up's environment): bash scripts/finetune_rooms.sh [DATA_DIR] [RUN_DIR] [MINUTES]
# Every step resumes after an interruption: run the script again.
set -euo pipefail
data=${1:-data/n128}
run=${2:-runs/rooms}
minutes=${3:-45}
export OMP_WAIT_POLICY=PASSIVE
phyir synth --out "$data" --count 200 --seed 20000 --size 128x256 --probe-grid 16x32 --spp 8 --quiet
phyir train --config scripts/finetune_rooms.toml --data "$data" --out "$run" \
  --init checkpoints/phyir-lite.safetensors --max-minutes "$minutes"
# (not shipped: see docs/training.md; to ship: python -m phyir.learn.weights ship "$run/gm/model.safetensors" checkpoints/phyir-lite.safetensors)
