"""PhyIR: physics-based inverse rendering of indoor 360° panoramas (library; never imports OpenGL).

Heavy members (anything that imports torch) load lazily so ``phyir --help`` starts fast.
"""

from __future__ import annotations

import importlib

from phyir.errors import InputError, PhyIRError

__version__ = "0.1.0"

_LAZY = {
    "PanoScene": "phyir.scene",
    "SceneError": "phyir.scene",
    "predict": "phyir.inference",
}
__all__ = ["PanoScene", "SceneError", "InputError", "PhyIRError", "predict", "__version__"]


def __getattr__(name: str):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'phyir' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
