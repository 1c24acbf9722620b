"""PhyIR networks: GMNet (geometry + material), LNet (light probes), GSNet (guided smoothing) and the
composed :class:`PhyIRModel` in two sizes (``full``, ``lite``)."""

from phyir.nets.gmnet import GMNet
from phyir.nets.gsnet import GSNet
from phyir.nets.lnet import LNet
from phyir.nets.model import ModelConfig, PhyIRModel

__all__ = ["GMNet", "GSNet", "LNet", "ModelConfig", "PhyIRModel"]
