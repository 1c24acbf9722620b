"""ClipNet: the light an 8-bit panorama clipped, predicted from the panorama (LDR -> HDR).

A small U-Net, seamless in longitude, that sees the linearised LDR panorama (log-compressed) and
where it is clipped, and predicts a log gain per pixel. The gain applies only where the input is
at or near clipping (:func:`clip_weight`), so what the camera measured stays as it was:
``hdr = ldr * exp(weight * gain)``. The global context (a pooled feature of the whole panorama, fed
back into the decoder) lets it tell a lamp from a window from the sun by what they light: the
brighter the walls around a clipped region, the more energy it must hold.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from phyir.nets.layers import CircConv2d, circular_upsample2x

CLIP_START, CLIP_FULL = 0.85, 0.99  # linear value where the gain starts to apply and where it applies fully
WIDTHS = (16, 32, 64, 96)
MAX_LOG_GAIN = 12.0  # exp(12) ~ 1.6e5: a sun clipped at 1


def clip_weight(ldr: Tensor) -> Tensor:
    """[B,1,H,W] in [0, 1]: how clipped each pixel is (its brightest channel between CLIP_START and
    CLIP_FULL, a smoothstep), so the gain fades in over the last steps below the clip."""
    m = ldr.amax(-3, keepdim=True)
    t = ((m - CLIP_START) / (CLIP_FULL - CLIP_START)).clamp(0, 1)
    return t * t * (3 - 2 * t)


class Block(nn.Sequential):
    def __init__(self, i: int, o: int, stride: int = 1):
        super().__init__(CircConv2d(i, o, 3, stride), nn.GroupNorm(max(1, o // 8), o), nn.ELU(inplace=True),
                         CircConv2d(o, o, 3), nn.GroupNorm(max(1, o // 8), o), nn.ELU(inplace=True))


class ClipNet(nn.Module):
    """Linear LDR panorama [B,3,H,W] in [0, 1] (H, W multiples of 8) -> log gain [B,1,H,W] >= 0."""

    def __init__(self, widths: tuple[int, ...] = WIDTHS):
        super().__init__()
        w0, w1, w2, w3 = widths
        self.enc0 = Block(5, w0)
        self.enc1 = Block(w0, w1, 2)
        self.enc2 = Block(w1, w2, 2)
        self.enc3 = Block(w2, w3, 2)
        self.context = nn.Linear(w3, w3)
        self.dec2 = Block(w3 + w2, w2)
        self.dec1 = Block(w2 + w1, w1)
        self.dec0 = Block(w1 + w0, w0)
        self.out = CircConv2d(w0, 1, 3)

    def forward(self, ldr: Tensor) -> Tensor:
        ldr = ldr.clamp(0, 1)
        weight = clip_weight(ldr)
        lat = torch.linspace(1, -1, ldr.shape[-2], device=ldr.device, dtype=ldr.dtype)
        x = torch.cat((torch.log(ldr + 1e-3), weight, lat.view(1, 1, -1, 1).expand_as(weight)), 1)
        f0 = self.enc0(x)
        f1 = self.enc1(f0)
        f2 = self.enc2(f1)
        f3 = self.enc3(f2)
        g = F.elu(self.context(f3.mean((-2, -1))))  # the whole panorama's context
        f3 = f3 + g[..., None, None]
        y = self.dec2(torch.cat((circular_upsample2x(f3), f2), 1))
        y = self.dec1(torch.cat((circular_upsample2x(y), f1), 1))
        y = self.dec0(torch.cat((circular_upsample2x(y), f0), 1))
        return F.softplus(self.out(y)).clamp(max=MAX_LOG_GAIN)


def apply_gain(ldr: Tensor, log_gain: Tensor) -> Tensor:
    """``ldr * exp(clip_weight(ldr) * log_gain)``: the gain only where the input is clipped."""
    return ldr * torch.exp(clip_weight(ldr.clamp(0, 1)) * log_gain)
