#!/usr/bin/env bash
# GMNet's depth decoder alone fine-tuned on the wider generator (issue 19): the encoder, the normal
# head and the material heads stay the shipped ones, so real rooms keep the normals they get; the
# depth learns the rooms (log-depth L2) and to agree with the shipped normal head (depth-normal term).
# CPU time and results: docs/training.md ("The depth decoder alone").
# Usage (inside the set-up's environment): bash scripts/finetune_depth.sh [DATA_DIR] [RUN_DIR] [MINUTES]
# Every step resumes after an interruption: run the script again.
set -euo pipefail
data=${1:-data/n128}
run=${2:-runs/depth}
minutes=${3:-35}
export OMP_WAIT_POLICY=PASSIVE
phyir synth --out "$data" --count 160 --seed 20000 --size 128x256 --probe-grid 16x32 --spp 8 --quiet
phyir train --config scripts/finetune_depth.toml --data "$data" --out "$run" \
  --init checkpoints/phyir-lite.safetensors --max-minutes "$minutes"
python -m phyir.learn.weights ship "$run/gm/checkpoint.pt" "$run/depth.safetensors"
