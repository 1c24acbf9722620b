"""Fixtures shared by the robustness tests."""

from __future__ import annotations

import pytest
import torch

from phyir.learn.weights import save_weights
from phyir.nets import ModelConfig, PhyIRModel


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    """A freshly initialised lite model (seed 0, 8x16 probes) and its weights file with a 32x64 sidecar."""
    torch.manual_seed(0)
    model = PhyIRModel(ModelConfig.named("lite", probe_size=(8, 16))).eval()
    folder = tmp_path_factory.mktemp("weights")
    path = save_weights(model, folder / "tiny.safetensors", {"data": {"resolution": "32x64"}})
    return model, path
