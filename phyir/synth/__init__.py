"""Synthetic indoor panoramas with ground truth: procedural rooms and a path tracer (docs/synthetic-data.md).

Heavy modules load lazily, so ``import phyir.synth`` stays cheap.
"""

from __future__ import annotations

import importlib

# public name -> the module that defines it
_LAZY = {
    "demo_scene_path": "phyir.synth.dataset", "generate_scene": "phyir.synth.dataset",
    "make_tiny_dataset": "phyir.synth.dataset", "generate_dataset": "phyir.synth.dataset",
    "DatasetConfig": "phyir.synth.dataset", "TraceSettings": "phyir.synth.tracer",
    "trace": "phyir.synth.tracer", "generate_room": "phyir.synth.rooms",
}
__all__ = list(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'phyir.synth' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)
