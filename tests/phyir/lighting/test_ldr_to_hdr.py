"""ClipNet (phyir.nets.clipnet), its training pairs and loss (phyir.learn.ldr_pairs, train_clipnet) and
its use on full-size panoramas (phyir.lighting.ldr_to_hdr): the clip weight, the gain touching only
clipped pixels, exact pairs from a simulated camera, the held-out split, losses on a hand-made case."""

from __future__ import annotations

import math

import pytest
import torch

from phyir import pano
from phyir.color import luminance
from phyir.learn import ldr_pairs as P
from phyir.learn.camera import AUTO_EXPOSURE_KEY
from phyir.learn.train_clipnet import clipped_losses, energy_ratios
from phyir.lighting import ldr_to_hdr as L
from phyir.nets.clipnet import CLIP_FULL, CLIP_START, ClipNet, apply_gain, clip_weight

pytestmark = pytest.mark.usefixtures("one_thread")


def lamp_panorama(H: int = 32, W: int = 64, lamp: float = 20.0) -> torch.Tensor:
    """Walls at 0.4 and a 4x4 lamp of ``lamp`` (clips at 1)."""
    x = torch.full((3, H, W), 0.4)
    x[:, 6:10, 20:24] = lamp
    return x


def test_clip_weight_ramps_over_the_last_steps_below_the_clip():
    v = torch.tensor([0.0, 0.5, CLIP_START, (CLIP_START + CLIP_FULL) / 2, CLIP_FULL, 1.0])
    w = clip_weight(torch.stack([v, v * 0.1, v * 0.1])[None, :, None, :])[0, 0, 0]
    # the brightest channel counts
    torch.testing.assert_close(w, torch.tensor([0.0, 0.0, 0.0, 0.5, 1.0, 1.0]))


def test_the_gain_touches_only_clipped_pixels():
    ldr = lamp_panorama().clamp(0, 1)[None]
    out = apply_gain(ldr, torch.full((1, 1, 32, 64), 3.0))
    assert torch.equal(out[..., :6, :], ldr[..., :6, :])  # unclipped walls unchanged, bit for bit
    torch.testing.assert_close(out[..., 6:10, 20:24], torch.full((1, 3, 4, 4), math.exp(3.0)))


def test_clipnet_is_non_negative_and_commutes_with_yaw():
    torch.manual_seed(0)
    net = ClipNet().eval()
    ldr = (lamp_panorama() * torch.rand(3, 32, 64)).clamp(0, 1)[None]
    with torch.no_grad():
        g, gr = net(ldr), net(torch.roll(ldr, 8, -1))
    assert g.shape == (1, 1, 32, 64) and float(g.min()) >= 0
    torch.testing.assert_close(torch.roll(g, 8, -1), gr, rtol=0, atol=1e-5)


def test_a_plain_camera_photographs_exactly():
    hdr = lamp_panorama()
    cam = P.Camera(exposure_stops=0.0, white_balance_stops=0.0, curves=("clip",), clip_gamma=(1.0, 1.0),
                   p_jpeg=0)
    ldr, target = P.photograph(hdr, torch.Generator().manual_seed(3), cam)
    assert float(luminance(target).median()) == pytest.approx(AUTO_EXPOSURE_KEY, rel=1e-5)  # auto-exposed
    torch.testing.assert_close(ldr, target.clamp(0, 1), rtol=0, atol=0.01)  # 8-bit quantisation only
    fixed, t2 = P.fixed_photograph(hdr)
    torch.testing.assert_close(t2, target)
    torch.testing.assert_close(fixed, ldr)


def test_the_validation_split_is_never_among_the_training_files(tmp_path):
    for name in (*P.HDRI_VALIDATION, "attic_1k", "hangar_1k"):
        (tmp_path / f"{name}.hdr").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("x")
    train, val = P.hdr_files(tmp_path, "train"), P.hdr_files(tmp_path, "val")
    assert [p.stem for p in train] == ["attic_1k", "hangar_1k"]
    assert sorted(p.stem for p in val) == sorted(P.HDRI_VALIDATION)


def test_losses_on_a_hand_made_lamp():
    hdr = lamp_panorama(lamp=20.0)[None]
    ldr = hdr.clamp(0, 1)
    exact = torch.log(hdr[:, :1] / ldr[:, :1]) * (clip_weight(ldr) > 0)
    pixel, energy, has = clipped_losses(ldr, exact, hdr)
    assert bool(has.all()) and float(pixel) < 1e-5 and float(energy) < 1e-5
    pixel0, energy0, _ = clipped_losses(ldr, torch.zeros_like(exact), hdr)
    assert float(energy0) == pytest.approx(math.log(20.0), rel=1e-4)  # the naive LDR: 1/20 of the lamp
    assert float(energy_ratios(ldr, torch.zeros_like(exact), hdr)) == pytest.approx(1 / 20, rel=1e-4)
    dark = torch.full_like(hdr, 0.3)
    assert not bool(clipped_losses(dark, exact, dark)[2].any())  # nothing clipped: left out


def test_recover_at_full_size_and_weights_round_trip(tmp_path):
    torch.manual_seed(1)
    net = ClipNet().eval()
    path = L.save_clipnet(net, tmp_path / "clipnet.safetensors", {"steps": 0})
    loaded = L.load_clipnet(path)
    ldr = lamp_panorama(256, 512).clamp(0, 1)
    hdr, sr, gain = L.recover(ldr, loaded)
    unclipped = ldr.amax(0) < CLIP_START
    assert torch.equal(hdr[:, unclipped], ldr[:, unclipped])  # kept bit for bit
    assert float(hdr[:, 6:10, 20:24].min()) >= 1.0 and gain >= 1.0
    assert sr == pytest.approx(float(pano.solid_angles(256, 512)[6:10, 20:24].sum()), rel=1e-5)
    assert L.load_clipnet(tmp_path / "missing.safetensors") is None
    const = L.upsample_wrapped(torch.full((1, 1, 8, 16), 2.0), 24, 48)
    torch.testing.assert_close(const, torch.full((1, 1, 24, 48), 2.0))


def test_predict_uses_clipnet_where_its_weights_are(tmp_path, monkeypatch):
    import phyir
    from phyir.nets import ModelConfig, PhyIRModel

    torch.manual_seed(2)
    model = PhyIRModel(ModelConfig.named("lite", probe_size=(8, 16))).eval()
    ldr = lamp_panorama(64, 128).clamp(0, 1)
    regions = phyir.predict(ldr, model=model, hdr=False, outputs=("depth",), probes=None)
    assert regions.meta["predict.hdr_recovery"].startswith("regions: 1 clipped regions")
    monkeypatch.setattr(L, "WEIGHTS", L.save_clipnet(ClipNet().eval(), tmp_path / "c.safetensors", {}))
    learned = phyir.predict(ldr, model=model, hdr=False, outputs=("depth",), probes=None)
    assert learned.meta["predict.hdr_recovery"].startswith("clipnet: 1 clipped regions")
    unclipped = ldr.amax(0) < CLIP_START
    assert torch.equal(learned.image[:, unclipped], ldr[:, unclipped])
    assert float(learned.image[:, 6:10, 20:24].min()) >= 1.0
