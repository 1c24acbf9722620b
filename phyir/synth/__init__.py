"""Synthetic indoor panoramas with ground truth: procedural rooms and a path tracer (docs/synthetic-data.md).

Heavy modules load lazily, so ``import phyir.synth`` stays cheap.
"""

from __future__ import annotations

__all__ = ["demo_scene_path", "generate_scene", "make_tiny_dataset", "generate_dataset", "DatasetConfig",
           "TraceSettings", "trace", "generate_room"]


def __getattr__(name: str):
    if name in __all__[:5]:
        from phyir.synth import dataset

        return getattr(dataset, name)
    if name in ("TraceSettings", "trace"):
        from phyir.synth import tracer

        return getattr(tracer, name)
    if name == "generate_room":
        from phyir.synth.rooms import generate_room

        return generate_room
    raise AttributeError(f"module 'phyir.synth' has no attribute {name!r}")
