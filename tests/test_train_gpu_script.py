"""scripts/train_gpu.sh, the recipe for a short GPU lease, run as written at a tiny scale on the CPU:
rooms are rendered, GMNet's decoders train from the shipped weights, and the result is a complete
model whose GMNet moved and whose encoder, LNet and GSNet are the shipped ones."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch
from support.paths import REPO

from phyir.learn.weights import default_weights_path, load_model


@pytest.mark.slow
def test_train_gpu_script_trains_the_decoders_and_ships_a_complete_model(tmp_path):
    env = dict(os.environ, PYTHON=sys.executable, DATA=str(tmp_path / "data"), OMP_NUM_THREADS="1")
    r = subprocess.run(["bash", "scripts/train_gpu.sh", str(tmp_path / "out"), "0.8", "--size", "32x64",
                        "--count", "4", "--cuda-procs", "0", "--cpu-procs", "1", "--batch-size", "2",
                        "--workers", "0", "--steps-per-second", "1"],
                       cwd=REPO, env=env, capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["synth"]["scenes"] >= 2 and summary["train"]["variants"]["gpu_effnet"]["steps"] >= 1
    trained = load_model(tmp_path / "out" / "gpu_effnet.safetensors").state_dict()
    shipped = load_model(default_weights_path()).state_dict()
    moved = [k for k in trained if k.startswith("gmnet.decoders") and not torch.equal(trained[k], shipped[k])]
    assert moved, "the decoders did not train"
    for k in trained:
        if k.startswith(("gmnet.encoder", "lnet.", "gsnet.")):
            assert torch.equal(trained[k], shipped[k]), k
