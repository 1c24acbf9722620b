"""``gmnet``: the shipped model's GMNet (:class:`phyir.nets.PhyIRModel`'s ``gmnet``), trained on the
synthetic rooms with the rest of the model."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from phyir.estimators import register_geometry

if TYPE_CHECKING:
    from torch import Tensor


def load(model: Any, device: Any) -> Callable[[Tensor], dict[str, Tensor]]:
    return model.gmnet  # already on the device with the model


NETWORK = register_geometry("gmnet", "GMNet of the loaded weights, trained with LNet and GSNet on the "
                            "synthetic rooms", load)
