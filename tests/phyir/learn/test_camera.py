"""phyir.learn.camera (the random LDR camera) and the light-colour augmentation."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from support.tiny_scenes import tiny_scene

from phyir.learn.camera import CameraPipeline, jpeg_round_trip, simulate_ldr, tone_curve
from phyir.learn.datasets import Augment, augment_scene


@pytest.mark.parametrize("curve", ["aces", "reinhard", "clip"])
def test_tone_curves_are_monotone_from_black_to_white(curve):
    x = torch.logspace(-4, 4, 400)
    y = tone_curve(x, curve, gamma=1.1).clamp(0, 1)
    assert float(y[0]) < 1e-3
    assert bool((y[1:] >= y[:-1] - 1e-7).all())
    assert float(y[-1]) > 0.99  # bright light clips


def test_ldr_is_8_bit_monotone_and_reproducible():
    ramp = torch.logspace(-3, 2, 256).expand(3, 8, 256).contiguous()
    cam = CameraPipeline(p_jpeg=0.0)
    y = simulate_ldr(ramp, 1.0, torch.Generator().manual_seed(3), cam)
    assert y.shape == ramp.shape and float(y.min()) >= 0 and float(y.max()) <= 1
    for c in range(3):
        assert y[c].unique().numel() <= 256
        assert bool((y[c, 0, 1:] >= y[c, 0, :-1]).all())
    again = simulate_ldr(ramp, 1.0, torch.Generator().manual_seed(3), cam)
    assert torch.equal(y, again)
    # white balance: over many draws the red/blue gains spread around 1 within +-0.3 stops
    g = torch.Generator().manual_seed(0)
    grey = torch.full((3, 4, 8), 0.05)
    ratios = [float(y[0].mean() / y[1].mean()) for y in (simulate_ldr(grey, 1.0, g, cam) for _ in range(40))]
    # (the tone curves bend the ratio a little: bounds a little beyond the gains')
    assert min(ratios) < 0.95 and max(ratios) > 1.05
    assert 2 ** -0.5 < min(ratios) and max(ratios) < 2 ** 0.5


def test_jpeg_round_trip_is_close_on_smooth_images():
    yy, xx = np.mgrid[0:32, 0:64]
    img = np.stack([xx * 3, yy * 6, (xx + yy) * 2], -1).clip(0, 255).astype(np.uint8)
    out = jpeg_round_trip(img, 95)
    assert out.shape == img.shape
    assert np.abs(out.astype(float) - img).mean() < 2.0
    err95 = np.abs(out.astype(float) - img).mean()
    assert np.abs(jpeg_round_trip(img, 60).astype(float) - img).mean() > err95


def test_light_colour_augmentation_scales_image_and_probes_alike():
    s = tiny_scene(1, grid=(4, 8), probe_size=(8, 16))
    aug = Augment(p_ldr=0.0, exposure_stops=0.0, light_colour_stops=1.0, rotate=False, mirror=False)
    gains = []
    for seed in range(6):
        a = augment_scene(s, aug, torch.Generator().manual_seed(seed))
        gi = (a.image / s.image).flatten(1)
        gp = (a.probes / s.probes).movedim(-3, 0).flatten(1)
        assert torch.allclose(gi, gi[:, :1].expand_as(gi), rtol=1e-5)  # one gain per channel
        assert torch.allclose(gp[:, 0], gi[:, 0], rtol=1e-5)  # the same for the light
        assert float(gi[1, 0]) == pytest.approx(1.0)  # green is the reference
        assert torch.equal(a.albedo, s.albedo) and torch.equal(a.normal, s.normal)
        gains.append(float(gi[0, 0] / gi[2, 0]))
    assert min(gains) < 0.8 and max(gains) > 1.25 and all(0.25 <= g <= 4 for g in gains)
