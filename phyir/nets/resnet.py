"""ResNet-18 encoder with circular longitude padding in every convolution and pooling layer.

Written here (no torchvision) so that every conv pads with :func:`phyir.pano.circular_pad`.
``width`` scales every channel count (1.0 = the standard 64/64/128/256/512).  The encoder returns
the five feature maps the GMNet decoders skip from, at strides 2, 4, 8, 16, 32.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from phyir.nets.layers import CircConv2d, make_norm, scaled
from phyir.pano import circular_pad

TOTAL_STRIDE = 32


class BasicBlock(nn.Module):
    def __init__(self, in_ch: int, out_ch: int, stride: int, norm: str):
        super().__init__()
        self.conv1 = CircConv2d(in_ch, out_ch, 3, stride, bias=False)
        self.bn1 = make_norm(norm, out_ch)
        self.conv2 = CircConv2d(out_ch, out_ch, 3, 1, bias=False)
        self.bn2 = make_norm(norm, out_ch)
        self.down = None
        if stride != 1 or in_ch != out_ch:
            self.down = nn.Sequential(nn.Conv2d(in_ch, out_ch, 1, stride, bias=False),
                                      make_norm(norm, out_ch))

    def forward(self, x: Tensor) -> Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return F.relu(y + (x if self.down is None else self.down(x)))


class ResNet18Encoder(nn.Module):
    """ResNet-18 trunk (no pooling head).  ``forward(x) -> [f0, f1, f2, f3, f4]``.

    f0: stem (stride 2), f1..f4: layer1..layer4 (strides 4, 8, 16, 32).  Input H and W must be
    multiples of 32 so the skips line up and rotations by 32 columns commute with the network.
    """

    def __init__(self, in_ch: int = 3, width: float = 1.0, norm: str = "group"):
        super().__init__()
        c = [scaled(n, width) for n in (64, 64, 128, 256, 512)]
        self.channels = c
        self.conv1 = CircConv2d(in_ch, c[0], 7, 2, bias=False)
        self.bn1 = make_norm(norm, c[0])
        self.layer1 = nn.Sequential(BasicBlock(c[0], c[1], 1, norm), BasicBlock(c[1], c[1], 1, norm))
        self.layer2 = nn.Sequential(BasicBlock(c[1], c[2], 2, norm), BasicBlock(c[2], c[2], 1, norm))
        self.layer3 = nn.Sequential(BasicBlock(c[2], c[3], 2, norm), BasicBlock(c[3], c[3], 1, norm))
        self.layer4 = nn.Sequential(BasicBlock(c[3], c[4], 2, norm), BasicBlock(c[4], c[4], 1, norm))
        for m in self.modules():
            # not on the meta device (weights files are checked there): its normal_ imports
            # torch._dynamo, ~1 s
            if isinstance(m, nn.Conv2d) and not m.weight.is_meta:
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
        for m in self.modules():  # zero-init the last norm of each residual branch (stable start)
            if isinstance(m, BasicBlock):
                nn.init.zeros_(m.bn2.weight)

    def forward(self, x: Tensor) -> list[Tensor]:
        f0 = F.relu(self.bn1(self.conv1(x)))
        # max-pool 3x3 s2 with the same seamless padding as the convs
        f1 = self.layer1(F.max_pool2d(circular_pad(f0, (1, 1, 1, 1)), 3, 2))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        f4 = self.layer4(f3)
        return [f0, f1, f2, f3, f4]
