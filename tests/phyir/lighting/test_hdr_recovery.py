"""HDR from LDR: clipped regions of an 8-bit panorama get their light back, nothing else changes."""

from __future__ import annotations

import math

import torch

from phyir import inference, pano
from phyir.color import luminance
from phyir.lighting.hdr_recovery import GAIN, clipped_regions, recover_clipped

H, W = 32, 64


def ldr_with_lamps() -> torch.Tensor:
    """A grey LDR panorama (0.2) with two clipped lamps: a warm one (1, 1, 0.99) and a white one."""
    img = torch.full((3, H, W), 0.2)
    img[:, 4:7, 10:14] = torch.tensor([1.0, 1.0, 0.995])[:, None, None]
    img[:, 5:8, 40:43] = 1.0
    return img


def test_unclipped_panorama_is_returned_unchanged():
    img = torch.rand(3, H, W) * 0.9
    out, rec = recover_clipped(img)
    assert out is img and rec.regions == 0 and rec.energy_gain == 1.0


def test_each_clipped_region_reaches_the_calibrated_level_and_keeps_its_colour():
    img = ldr_with_lamps()
    clipped, labels, n = clipped_regions(img)
    assert n == 2 and int(clipped.sum()) == 12 + 9
    out, rec = recover_clipped(img)
    assert rec.regions == 2
    omega = pano.solid_angles(H, W)
    med = float(luminance(img).median())
    for k in range(n):
        m = labels == k
        mean = float((luminance(out)[m] * omega[m]).sum() / omega[m].sum())
        assert math.isclose(mean, GAIN * med, rel_tol=1e-5)
        ratio = out[:, m] / img[:, m]  # one factor per region: colour and shape kept
        assert torch.allclose(ratio, ratio[:1, :1].expand_as(ratio), rtol=1e-5)
    assert torch.equal(out[:, ~clipped], img[:, ~clipped])
    assert rec.energy_gain > 1


def test_a_region_bright_enough_already_is_left_alone():
    img = ldr_with_lamps() * 0 + 0.03  # a dark room: its median times GAIN is below the clip level
    img[:, 4:7, 10:14] = 1.0
    out, rec = recover_clipped(img)
    assert 0.03 * GAIN < 1.0 and rec.regions == 0 and torch.equal(out, img)


def test_predict_recovers_only_ldr_inputs(tmp_path):
    from phyir.io import save_panorama

    png, hdr = tmp_path / "pano.png", tmp_path / "pano.hdr"
    save_panorama(ldr_with_lamps(), png)
    save_panorama(ldr_with_lamps(), hdr)
    opts = dict(outputs=(), probes=None)
    ldr_scene, rep = inference.predict_with_report(png, **opts)
    assert rep.hdr_recovery is not None and rep.hdr_recovery.regions == 2
    assert float(ldr_scene.image.max()) > 1.5 and "predict.hdr_recovery" in ldr_scene.meta
    hdr_scene, rep = inference.predict_with_report(hdr, **opts)
    assert rep.hdr_recovery is None and float(hdr_scene.image.max()) <= 1.0 + 1e-3
    off, rep = inference.predict_with_report(png, recover_hdr=False, **opts)
    assert rep.hdr_recovery is None and float(off.image.max()) <= 1.0 + 1e-6
