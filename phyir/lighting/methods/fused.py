"""``fused``: LNet's probes and the projected ones combined (:mod:`phyir.lighting.fusion`): with the
shipped weights the best on the synthetic split and the real panoramas (README, "The model").
``phyir eval --data data/h128 --split train`` (24 held-out rooms), probe log-MSE fused 0.0418, lnet
0.0516, projection 0.0543; relighting (diffuse / matte / mirror sphere) fused 0.0134 / 0.0178 /
0.0359, lnet 0.0179 / 0.0251 / 0.0472; on the real panoramas' protocol the fused grid lights the
diffuse sphere 0.31 off the panorama, LNet's 0.38 (README, "Real panoramas")."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from phyir.estimators import register_lighting

if TYPE_CHECKING:
    from torch import Tensor


def estimate(lnet: Tensor, projected: Callable[[], Tensor]) -> Tensor:
    from phyir.lighting.fusion import fuse_probes

    return fuse_probes(lnet, projected())


METHOD = register_lighting("fused", "the geometric mean of LNet's and the projected probes, the best on "
                           "the synthetic split", estimate, projects=True)
