"""``projection``: each probe re-read from the panorama where the camera saw the surface its texels
look at, LNet's probe elsewhere (:mod:`phyir.lighting.projection`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from phyir.estimators import register_lighting

if TYPE_CHECKING:
    from torch import Tensor


def estimate(lnet: Tensor, projected: Callable[[], Tensor]) -> Tensor:
    return projected()


METHOD = register_lighting("projection", "probes re-read from the panorama where the camera saw, LNet "
                           "elsewhere", estimate, projects=True)
