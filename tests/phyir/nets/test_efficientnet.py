"""phyir.nets.efficientnet: the pretrained weights are ImageNet's (a stored fingerprint), the padding
is TensorFlow's "same" while wrapping in longitude, and GMNet runs on it."""

from __future__ import annotations

import pytest
import torch

from phyir.nets import ModelConfig, PhyIRModel
from phyir.nets import efficientnet as E


def ramp_image(H: int = 64, W: int = 128) -> torch.Tensor:
    yy, xx = torch.meshgrid(torch.linspace(0, 1, H), torch.linspace(0, 1, W), indexing="ij")
    return torch.stack([xx, yy, 0.5 * (xx + yy)])[None]


@pytest.fixture(scope="module")
def encoder() -> E.EfficientNetLite0Encoder:
    return E.EfficientNetLite0Encoder(pretrained=True).eval()


def test_the_weights_are_the_pretrained_ones(encoder):
    """Features of a fixed ramp, recorded from the package's ImageNet weights (float32 sums of a few
    hundred products: 1e-4 relative covers any CPU's summation order)."""
    with torch.no_grad():
        f = encoder(ramp_image())
    shapes = [(16, 32, 64), (24, 16, 32), (40, 8, 16), (112, 4, 8), (320, 2, 4)]
    assert [tuple(t.shape[1:]) for t in f] == shapes
    stats = [(float(t.mean()), float(t.std())) for t in f]
    want = [(-0.5644, 5.8465), (1.8155, 8.5004), (-0.4614, 7.9341), (-0.0916, 6.1174), (-0.2440, 2.7199)]
    for (m, s), (wm, ws) in zip(stats, want):
        assert m == pytest.approx(wm, abs=2e-3) and s == pytest.approx(ws, rel=1e-3)
    torch.testing.assert_close(f[-1][0, :4, 1, 2], torch.tensor([3.3671, 4.0294, -2.6956, -2.4540]),
                               rtol=1e-3, atol=1e-3)
    random = E.EfficientNetLite0Encoder(pretrained=False).eval()
    with torch.no_grad():
        # the fingerprint tells them apart
        assert float((random(ramp_image())[-1] - f[-1]).abs().mean()) > 0.5


def test_the_encoder_commutes_with_yaw_rolls(encoder):
    """Padding wraps in longitude, so rolling the input by 32 columns rolls the stride-s features by
    32 / s (exactly: the same products in the same order)."""
    x = ramp_image() + 0.3 * torch.rand(1, 3, 64, 128, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        a, b = encoder(x), encoder(torch.roll(x, 32, -1))
    for fa, fb, s in zip(a, b, (2, 4, 8, 16, 32)):
        torch.testing.assert_close(torch.roll(fa, 32 // s, -1), fb, rtol=0, atol=1e-5)


def test_same_padding_is_tensorflows():
    """Stride 2, k 3 on an even size pads 0 before and 1 after (TF "same"), so output pixel i sees
    input pixels 2i..2i+2."""
    conv = E.SameConv2d(1, 1, 3, 2, bias=False)
    torch.nn.init.zeros_(conv.weight)
    with torch.no_grad():
        conv.weight[0, 0, 0, 0] = 1.0  # picks the top-left tap
    x = torch.arange(8 * 16, dtype=torch.float32).view(1, 1, 8, 16)
    y = conv(x)
    assert y.shape == (1, 1, 4, 8)
    torch.testing.assert_close(y[0, 0], x[0, 0, ::2, ::2])


def test_to_pretrained_input_is_an_srgb_image():
    x = torch.tensor([0.0, 0.18, 1.0, 1e6, float("nan"), float("inf"), -1.0]).view(1, 1, 7)
    y = E.to_pretrained_input(x.expand(3, 1, 7))
    assert torch.isfinite(y).all() and float(y.min()) >= 0 and float(y.max()) <= 1
    assert float(y[0, 0, 1]) == pytest.approx(0.4270, abs=1e-4)  # the median grey: sRGB of 0.18 / 1.18
    assert float(y[0, 0, 3]) == pytest.approx(1.0, abs=1e-4)  # 1e6 clamped to 1e4: 1e4 / (1 + 1e4)


def test_gmnet_on_the_pretrained_encoder():
    model = PhyIRModel(ModelConfig.named("effnet", probe_size=(8, 16))).eval()
    assert model.gmnet.load_pretrained()
    assert not PhyIRModel("lite").gmnet.load_pretrained()  # the paper's ResNet starts from scratch
    with torch.no_grad():
        out = model.gmnet(torch.rand(1, 3, 64, 128))
    assert out["depth"].shape == (1, 1, 64, 128) and bool((out["depth"] > 0).all())
    n = out["normal"].norm(dim=1)
    torch.testing.assert_close(n, torch.ones_like(n), rtol=0, atol=1e-5)
