"""PhyIR: physics-based inverse rendering of indoor 360° panoramas (library; never imports OpenGL)."""

from phyir.errors import InputError, PhyIRError
from phyir.scene import PanoScene, SceneError

__version__ = "0.1.0"
__all__ = ["PanoScene", "SceneError", "InputError", "PhyIRError", "__version__"]
