"""``lnet``: LNet's probes as they come (the baseline; no projection, the fastest)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from phyir.estimators import register_lighting

if TYPE_CHECKING:
    from torch import Tensor


def estimate(lnet: Tensor, projected: Callable[[], Tensor]) -> Tensor:
    return lnet


METHOD = register_lighting("lnet", "LNet's probes", estimate, projects=False)
