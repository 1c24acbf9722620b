"""Building blocks shared by the PhyIR networks, all seamless in longitude.

Every convolution pads with :func:`phyir.pano.circular_pad` (wrap in longitude, replicate at the
poles) instead of zeros, so the panorama's left and right edges are one continuous surface (the CirP
of the supplement's Table 3).  Upsampling is bilinear with the same wrap.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from phyir.pano import circular_pad


class CircConv2d(nn.Conv2d):
    """``nn.Conv2d`` whose padding wraps in longitude and replicates at the poles.

    Padding is ``(k - 1) // 2`` on the left/top and ``k // 2`` on the right/bottom, so even kernels
    (LNet's k4 s2) halve the size exactly like a zero-padded ``padding=1`` conv would.
    """

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, stride: int = 1, bias: bool = True):
        super().__init__(in_ch, out_ch, kernel_size, stride=stride, padding=0, bias=bias)
        k = kernel_size
        self.circ = ((k - 1) // 2, k // 2, (k - 1) // 2, k // 2)

    def forward(self, x: Tensor) -> Tensor:
        if any(self.circ):
            x = circular_pad(x, self.circ)
        return super().forward(x)


def circular_upsample2x(x: Tensor) -> Tensor:
    """Bilinear 2x upsampling that wraps in longitude (clamps at the poles)."""
    y = F.interpolate(circular_pad(x, (1, 1, 0, 0)), scale_factor=2, mode="bilinear", align_corners=False)
    return y[..., 2:-2]


def group_norm(ch: int, per_group: int = 16) -> nn.GroupNorm:
    """GroupNorm with ``per_group`` channels in each group (one group when ``ch < per_group``)."""
    return nn.GroupNorm(max(1, ch // per_group), ch)


def make_norm(kind: str, ch: int) -> nn.Module:
    if kind == "group":
        return group_norm(ch)
    if kind == "batch":
        return nn.BatchNorm2d(ch)
    raise ValueError(f"unknown norm {kind!r}")


def scaled(ch: int, width: float, minimum: int = 8) -> int:
    """Channel count ``ch`` scaled by ``width``, rounded to a multiple of 8 (at least ``minimum``)."""
    return max(minimum, int(round(ch * width / 8)) * 8)
