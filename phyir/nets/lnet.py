"""LNet (supplement A.2): an encoder-decoder predicting one HDR light probe per probe-grid cell.

Input: the panorama and GMNet's outputs (image, depth, normal, base colour, roughness, metalness:
12 channels), lifted to 64 channels by a stem conv (the list below starts at i64).  Every conv pads
circularly in longitude and is followed by GroupNorm (16 channels per group) and ReLU.  For
``width=1`` the layers are the supplement's::

    enc: 64->128 k4s2, 128->256 k4s2, 256->256 k4s2, 256->512 k4s2, 512->1024 k3
    dec: 1024->512 k1, (512+512)->256 k3, up, (256+256)->256 k3, up, (256+256)->128 k3, up,
         (128+128)->128 k3
    head (at the probe grid): 128->512 k3, 512->h*w*3 k3

The decoder features (stride 2) are area-resampled to the probe grid (Hp x Wp) before the head, so
the expensive h*w*3-channel conv runs once per probe.  The head predicts each probe in a frame
centred on its block's longitude; :func:`probes_to_world` rolls it into the world frame (for the
same reason GMNet's normals use per-column frames: the network cannot see absolute longitude;
its input normals are likewise turned into the per-column frames).  The head predicts **log
radiance** in the exposure-normalised units of the input; it is clamped to ``LOG_RANGE`` and
exponentiated in float32 at the end, so probes are positive and finite across the whole dynamic
range.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from phyir.nets.gmnet import prepare_input, world_to_local
from phyir.nets.layers import CircConv2d, circular_upsample2x, group_norm, scaled
from phyir.pano import resize_area

LOG_RANGE = (-16.0, 16.0)  # exp(16) ~ 9e6 x the normalised exposure; beyond that is not indoor light
LOG_INIT = math.log(0.5)  # initial probe radiance (normalised units)
IN_CHANNELS = 12


class ConvGN(nn.Sequential):
    def __init__(self, i: int, o: int, k: int, s: int = 1):
        super().__init__(CircConv2d(i, o, k, s, bias=False), group_norm(o, 16), nn.ReLU(inplace=True))


class LNet(nn.Module):
    def __init__(self, width: float = 1.0, probe_size: tuple[int, int] = (16, 32), head_kernel: int = 3):
        super().__init__()
        c = {n: scaled(n, width) for n in (64, 128, 256, 512, 1024)}
        self.probe_size = tuple(probe_size)
        h, w = self.probe_size
        self.stem = ConvGN(IN_CHANNELS, c[64], 3)
        self.enc1 = ConvGN(c[64], c[128], 4, 2)
        self.enc2 = ConvGN(c[128], c[256], 4, 2)
        self.enc3 = ConvGN(c[256], c[256], 4, 2)
        self.enc4 = ConvGN(c[256], c[512], 4, 2)
        self.enc5 = ConvGN(c[512], c[1024], 3)
        self.dec1 = ConvGN(c[1024], c[512], 1)
        self.dec2 = ConvGN(2 * c[512], c[256], 3)
        self.dec3 = ConvGN(2 * c[256], c[256], 3)
        self.dec4 = ConvGN(2 * c[256], c[128], 3)
        self.dec5 = ConvGN(2 * c[128], c[128], 3)
        self.head = nn.Sequential(CircConv2d(c[128], c[512], head_kernel), nn.ReLU(inplace=True),
                                  CircConv2d(c[512], 3 * h * w, head_kernel))
        with torch.no_grad():
            self.head[-1].weight.mul_(0.1)
            self.head[-1].bias.fill_(LOG_INIT)

    def forward(self, image: Tensor, gm: dict[str, Tensor], grid: tuple[int, int]) -> Tensor:
        """Probes [B, Hp, Wp, 3, h, w] for a ``grid`` = (Hp, Wp) probe grid.

        ``image`` [B,3,H,W] exposure-normalised; ``gm`` GMNet's outputs at the same resolution.
        H, W must be multiples of 16.
        """
        x = torch.cat((prepare_input(image), torch.log(gm["depth"]), world_to_local(gm["normal"]),
                       gm["albedo"], gm["roughness"], gm["metallic"]), 1)
        e0 = self.stem(x)
        e1 = self.enc1(e0)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        d = self.dec1(self.enc5(e4))
        up = circular_upsample2x
        d = up(self.dec2(torch.cat((d, e4), 1)))
        d = up(self.dec3(torch.cat((d, e3), 1)))
        d = up(self.dec4(torch.cat((d, e2), 1)))
        d = self.dec5(torch.cat((d, e1), 1))
        d = resize_area(d, *grid)
        log_l = self.head(d)  # [B, 3*h*w, Hp, Wp]
        B, _, Hp, Wp = log_l.shape
        h, w = self.probe_size
        log_l = log_l.float().reshape(B, 3, h, w, Hp, Wp).permute(0, 4, 5, 1, 2, 3)
        return torch.exp(probes_to_world(log_l).clamp(*LOG_RANGE))


def probes_to_world(local: Tensor) -> Tensor:
    """Roll the probes of grid column b [..., Hp, Wp, C, h, w] by ((b + 0.5) Wp^-1 - 1/2) w texels in
    longitude (linear interpolation for fractional shifts): the probe of a block predicted with its
    block's longitude at the probe's centre column, re-expressed in the world frame."""
    Wp, w = local.shape[-4], local.shape[-1]
    off = (torch.arange(Wp, device=local.device, dtype=torch.float64) + 0.5) * (w / Wp) - w / 2
    src = torch.arange(w, device=local.device, dtype=torch.float64)[None] - off[:, None]  # [Wp, w]
    j0 = torch.floor(src)
    f = (src - j0).to(local.dtype)
    i0 = torch.remainder(j0.long(), w)
    i1 = torch.remainder(i0 + 1, w)
    shape = (*local.shape[:-4], Wp, *local.shape[-3:])
    def view(t):
        return t.view(Wp, 1, 1, w).expand(shape)
    out = torch.gather(local, -1, view(i0))
    if bool((f > 0).any()):
        out = (1 - view(f)) * out + view(f) * torch.gather(local, -1, view(i1))
    return out
