#!/usr/bin/env bash
# The recipe of the lite weights (checkpoints/phyir-lite.*), as it was run on a 2-core CPU
# in ~2 hours: 290 synthetic scenes at 128x256, then the paper's four stages, each cut short where
# the CPU budget ran out (the --max-steps below are the steps each stage reached), then a fine-tune
# of the metalness head alone (session 3).
# Usage (inside the set-up's environment): bash scripts/train_lite.sh [DATA_DIR] [RUN_DIR]
# Every step resumes after an interruption: run the script again.
set -euo pipefail
data=${1:-data/s128}
run=${2:-runs/lite}
export OMP_WAIT_POLICY=PASSIVE
# the dataset (the generator of commit 5065998; newer generators make different rooms)
if [ ! -f "$data/scene_000289.exr" ]; then
  phyir synth --out "$data" --count 3000 --seed 0 --size 128x256 --probe-grid 16x32 --spp 8 --quiet &
  synth=$!
  trap 'kill $synth 2>/dev/null || true' EXIT
  while [ ! -f "$data/scene_000289.exr" ]; do sleep 10; done
  kill $synth
fi
# the first five steps ran before metalness got its cross-entropy (the paper's L2 left the head dead)
c=(--data "$data" --size native --probe-grid native --schedule cosine --workers 0 --no-progress
   --loss metallic_loss=l2)
stage() {  # stage out train-scenes max-steps export-epochs [args] (the train scenes present when it ran): train, then export at the epoch reached
  local st=$1 out=$2 lim=$3 steps=$4 ep=$5; shift 5
  phyir train "${c[@]}" --out "$out" --stage "$st" --limit-train "$lim" --max-steps "$steps" "$@"
  [ -f "$out/$st/model.safetensors" ] || phyir train "${c[@]}" --out "$out" --stage "$st" \
    --limit-train "$lim" "$@" --epochs "$ep"
}
stage gm "$run-gm1" 64 472 59 --epochs 120 --lr 3e-4                 # GMNet on the first 64 scenes
stage gm "$run" 102 140 11 --epochs 12 --lr 1e-4 --init "$run-gm1/gm/model.safetensors"
stage light "$run" 142 502 14 --epochs 30 --lr 3e-4                   # LNet, GMNet frozen
stage joint "$run" 203 73 1 --epochs 3                                  # both, lr 1e-5
stage gs "$run" 224 168 12 --epochs 12                                  # GSNet (ran to the end)
# session 3: the metalness head, re-initialised and trained alone with the cross-entropy (everything
# else frozen), then all of GMNet with it (LNet and GSNet kept as they were)
c[-1]=metallic_loss=bce
phyir train "${c[@]}" --out "$run-metal" --stage gm --init "$run/gs/model.safetensors" --limit-train 231 \
  --limit-val 16 --epochs 12 --lr 1e-3 --batch-size 8 --train-only gmnet.decoders.metallic \
  --reinit gmnet.decoders.metallic.out
phyir train "${c[@]}" --out "$run-metal2" --stage gm --init "$run-metal/gm/model.safetensors" \
  --limit-train 231 --limit-val 16 --epochs 8 --lr 1e-4 --batch-size 8
python -m phyir.learn.weights ship "$run-metal2/gm/model.safetensors" checkpoints/phyir-lite.safetensors
