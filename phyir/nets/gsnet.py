"""GSNet: a differentiable guided filter (He et al.) that smooths base colour and roughness, guided
by the image, with a small CNN predicting its per-pixel parameters.

The CNN sees the (log-compressed) image and the coarse materials and predicts, per pixel,
- a one-channel guidance map g in (0, 1) (a learned function of the image, as in Wu et al.'s
  trainable guided filter),
- the regulariser eps > 0 of the local linear model (small eps keeps edges of g, large eps blurs),
- a blend weight lambda in (0, 1) per refined quantity: out = lambda * filtered + (1 - lambda) * input,
  so the network can leave detail that the filter would destroy.
The guided filter uses radius 2 (5x5 windows, supplement B.1) and O(1)-per-pixel box sums from
cumulative sums; windows wrap around in longitude and are truncated (renormalised) at the poles.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from phyir.filters import guided_filter
from phyir.nets.gmnet import prepare_input, world_to_local
from phyir.nets.layers import CircConv2d

EPS_RANGE = (1e-4, 1.0)


class GSNet(nn.Module):
    """Refines ``targets`` (default base colour and roughness) of GMNet's output."""

    def __init__(self, width: int = 32, radius: int = 2, targets: tuple[str, ...] = ("albedo", "roughness")):
        super().__init__()
        self.radius = radius
        self.targets = tuple(targets)
        ch = {"albedo": 3, "roughness": 1, "normal": 3, "metallic": 1}
        in_ch = 3 + sum(ch[t] for t in self.targets)
        self.body = nn.Sequential(
            CircConv2d(in_ch, width, 3), nn.ELU(inplace=True),
            CircConv2d(width, width, 3), nn.ELU(inplace=True),
            CircConv2d(width, width, 3), nn.ELU(inplace=True),
            CircConv2d(width, 2 + len(self.targets), 3),
        )

    def forward(self, image: Tensor, gm: dict[str, Tensor]) -> dict[str, Tensor]:
        """Refined copies of the target layers (others are not returned)."""
        coarse = [gm[t] for t in self.targets]
        seen = [world_to_local(c) if t == "normal" else c for t, c in zip(self.targets, coarse)]
        p = self.body(torch.cat((prepare_input(image), *seen), 1)).float()
        guide = torch.sigmoid(p[:, :1])
        lo, hi = EPS_RANGE
        eps = lo * (hi / lo) ** torch.sigmoid(p[:, 1:2])
        out = {}
        for i, (t, src) in enumerate(zip(self.targets, coarse)):
            lam = torch.sigmoid(p[:, 2 + i: 3 + i])
            q = guided_filter(guide, src.float(), eps, self.radius)
            y = lam * q + (1 - lam) * src
            out[t] = torch.nn.functional.normalize(y, dim=1) if t == "normal" else y.clamp(0, 1)
        return out
