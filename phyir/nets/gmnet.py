"""GMNet (supplement A.1): a ResNet-18 encoder and five decoders for depth, normal, base colour,
roughness and metalness.

Each decoder is the supplement's 11-layer list (UniFuse-style), channel counts for ``width=1``::

    upconv5 512->256 | iconv4 (256+256)->256, upconv4 256->128 | iconv3 (128+128)->128,
    upconv3 128->64  | iconv2 (64+64)->64,    upconv2 64->32   | iconv1 (32+64)->32,
    upconv1 32->16   | iconv0 16->16,         out 16->3|1

Every ``upconv`` is followed by a 2x (seamless) upsampling and concatenation with the encoder skip
of that stride.  All 3x3 convs pad circularly in longitude; each is followed by ELU except the
output conv, whose activation maps to the quantity's range:
depth = exp(clamped log-depth) > 0, normal = x / |x| (unit), materials = sigmoid in (0, 1).

Normals are predicted in a **per-column frame** that turns with the pixel's longitude and are then
rotated into the world frame.  A network with circular padding cannot tell one longitude from
another (it commutes with yaw rotations of the input), whereas world-frame normals of the same
wall differ with longitude; the per-column frame makes "rotate the input" rotate the predicted
normals as :func:`phyir.transforms.rotate_yaw` does.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from phyir.nets.efficientnet import EfficientNetLite0Encoder, pretrained_state_dict, to_pretrained_input
from phyir.nets.layers import CircConv2d, circular_upsample2x, scaled
from phyir.nets.resnet import ResNet18Encoder
from phyir.pano import pixel_lonlat

HEADS: dict[str, int] = {"depth": 1, "normal": 3, "albedo": 3, "roughness": 1, "metallic": 1}
LOG_DEPTH_RANGE = (-5.0, 5.0)  # exp -> 7 mm .. 148 m
DEPTH_INIT = 3.0  # metres: initial output of the depth head (bias of its last conv)


class ConvELU(nn.Sequential):
    def __init__(self, i: int, o: int):
        super().__init__(CircConv2d(i, o, 3), nn.ELU(inplace=True))


class Decoder(nn.Module):
    """One GMNet decoder; ``skips`` are the encoder's channel counts at strides 2..32."""

    def __init__(self, skips: list[int], out_ch: int, width: float):
        super().__init__()
        d = [scaled(n, width) for n in (256, 128, 64, 32, 16)]
        s0, s1, s2, s3, s4 = skips
        self.upconv5 = ConvELU(s4, d[0])
        self.iconv4 = ConvELU(d[0] + s3, d[0])
        self.upconv4 = ConvELU(d[0], d[1])
        self.iconv3 = ConvELU(d[1] + s2, d[1])
        self.upconv3 = ConvELU(d[1], d[2])
        self.iconv2 = ConvELU(d[2] + s1, d[2])
        self.upconv2 = ConvELU(d[2], d[3])
        self.iconv1 = ConvELU(d[3] + s0, d[3])
        self.upconv1 = ConvELU(d[3], d[4])
        self.iconv0 = ConvELU(d[4], d[4])
        self.out = CircConv2d(d[4], out_ch, 3)

    def forward(self, f: list[Tensor]) -> Tensor:
        up = circular_upsample2x
        x = self.iconv4(torch.cat((up(self.upconv5(f[4])), f[3]), 1))
        x = self.iconv3(torch.cat((up(self.upconv4(x)), f[2]), 1))
        x = self.iconv2(torch.cat((up(self.upconv3(x)), f[1]), 1))
        x = self.iconv1(torch.cat((up(self.upconv2(x)), f[0]), 1))
        x = self.iconv0(up(self.upconv1(x)))
        return self.out(x)


ENCODERS = ("resnet18", "efficientnet-lite0")


class GMNet(nn.Module):
    """Image [B,3,H,W] (exposure-normalised, linear) -> dict of depth/normal/albedo/roughness/metallic.

    H and W must be multiples of 32.  ``encoder``: the paper's ResNet-18 (``enc_width`` scales its
    channels; trained from scratch here) or the ImageNet-pretrained EfficientNet-Lite0
    (:mod:`phyir.nets.efficientnet`; its weights are loaded by :meth:`load_pretrained`, a fresh
    training run's start).  ``dec_width`` scales the decoders' channels.
    """

    def __init__(self, enc_width: float = 1.0, dec_width: float = 1.0, norm: str = "group",
                 encoder: str = "resnet18"):
        super().__init__()
        if encoder not in ENCODERS:
            raise ValueError(f"unknown GMNet encoder {encoder!r} (choose from {', '.join(ENCODERS)})")
        self.encoder_name = encoder
        if encoder == "resnet18":
            self.encoder = ResNet18Encoder(3, enc_width, norm)
        else:
            self.encoder = EfficientNetLite0Encoder(pretrained=False)
        self.decoders = nn.ModuleDict({k: Decoder(self.encoder.channels, c, dec_width)
                                       for k, c in HEADS.items()})
        with torch.no_grad():
            self.decoders["depth"].out.bias.fill_(math.log(DEPTH_INIT))

    def load_pretrained(self) -> bool:
        """Load the encoder's ImageNet weights, where it has them; returns whether it did."""
        if self.encoder_name != "efficientnet-lite0":
            return False
        self.encoder.load_state_dict(pretrained_state_dict())
        return True

    def forward(self, image: Tensor) -> dict[str, Tensor]:
        x = prepare_input(image) if self.encoder_name == "resnet18" else to_pretrained_input(image)
        f = self.encoder(x)
        raw = {k: dec(f) for k, dec in self.decoders.items()}
        return {
            "depth": torch.exp(raw["depth"].clamp(*LOG_DEPTH_RANGE)),
            "normal": local_to_world(F.normalize(raw["normal"], dim=1, eps=1e-6)),
            "albedo": torch.sigmoid(raw["albedo"]),
            "roughness": torch.sigmoid(raw["roughness"]),
            "metallic": torch.sigmoid(raw["metallic"]),
        }


def local_to_world(n: Tensor, inverse: bool = False) -> Tensor:
    """Vectors [B,3,H,W] in each column's frame to the world frame: the rotation about +y taking the
    view direction of longitude 0 (-z) to the column's longitude, x' = x cos(lon) - z sin(lon),
    z' = x sin(lon) + z cos(lon) (so the centre column's frame is the world frame)."""
    lon, _ = pixel_lonlat(*n.shape[-2:], device=n.device, dtype=n.dtype)
    c, s = torch.cos(lon[:1]), torch.sin(lon[:1])
    if inverse:
        s = -s
    x, y, z = n.unbind(1)
    return torch.stack((x * c - z * s, y, x * s + z * c), 1)


def world_to_local(n: Tensor) -> Tensor:
    """Inverse of :func:`local_to_world`."""
    return local_to_world(n, inverse=True)


def prepare_input(image: Tensor) -> Tensor:
    """Compress exposure-normalised linear radiance into a range convs like: log(1 + x), finite.

    Very bright or non-finite pixels (a 1e5 sun, a stray Inf) are clamped first so the features
    stay finite for any input.
    """
    x = torch.nan_to_num(image.float(), nan=0.0, posinf=1e6, neginf=0.0).clamp(0, 1e6)
    return torch.log1p(x)
