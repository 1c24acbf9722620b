"""Small, fast versions of the generator's physical-consistency and noise checks (phyir.synth.checks)."""

from __future__ import annotations

import pytest
import torch

from phyir.synth.checks import consistency, consistency_summary, rel_l1
from phyir.synth.dataset import generate_scene, tiny_settings

TINY = tiny_settings(size=(32, 64), probe_grid=(8, 16), probe_size=(8, 16), spp=8)


def test_rendering_layer_reproduces_ground_truth():
    """The rendering layer on GT layers + probes gives back the GT image: no energy bias, and the
    per-pixel error stays bounded even with these coarse 8x16 probes and few samples."""
    res = [consistency(generate_scene(5, i, TINY), spp=64) for i in range(5)]  # (a sunny room: 0.49)
    ratio = sum(r["brightness_ratio"] for r in res) / len(res)
    assert 0.92 < ratio < 1.08
    assert sum(r["all"] for r in res) / len(res) < 0.3
    # the summary splits rooms by their sun, which the generator records in meta["source_radiance"]
    summary = consistency_summary(res + [dict(res[0], sun=1.0, all=0.5)])
    assert summary["all_sun"] == pytest.approx((0.5 + sum(r["all"] for r in res if r["sun"]))
                                               / (1 + sum(r["sun"] for r in res)))
    assert summary["rooms_sun"] + summary.get("rooms_no_sun", 0) == 6


def _noise(spp: int, rooms=(1, 2, 3)) -> tuple[float, float]:
    """Mean relative L1 between two sampler seeds of the same rooms (a sunny one, a dark-ceilinged
    one, a small one), image and probes."""
    st = tiny_settings(size=(32, 64), probe_grid=(8, 16), probe_size=(8, 16), spp=spp)
    img, probes = [], []
    for i in rooms:
        a = generate_scene(5, i, st, sampler_seed=1)
        b = generate_scene(5, i, st, sampler_seed=2)
        ka, kb = float(a.meta["exposure"]), float(b.meta["exposure"])
        nonem = a.masks["emission"] < 0.5
        img.append(rel_l1(a.image / ka, b.image / kb, nonem))
        probes.append(rel_l1(a.probes / ka, b.probes / kb))
    return sum(img) / len(img), sum(probes) / len(probes)


def test_sampler_noise_is_small_and_shrinks_with_samples():
    # 1 vs 32 camera samples (each with TraceSettings.nee_samples light samples): beyond ~4 the
    # tiny settings' coarse light map (16 gather rays) is the noise floor
    img1, _ = _noise(1)
    img32, probes32 = _noise(32)
    assert img32 < 0.6 * img1
    assert img32 < 0.12 and probes32 < 0.3


def _cosine_error(probe, d: torch.Tensor, normals: list) -> float:
    """Worst relative error of the irradiance of ``probe [3,h,w]`` (bilinear reconstruction, fine
    quadrature over the sphere) against a unit-energy source in direction ``d [3]``."""
    from phyir.pano import dir_to_uv, directions, sample_bilinear, solid_angles

    fine = directions(128, 256).reshape(3, -1).T
    fine_w = solid_angles(128, 256).reshape(-1)
    u, v = dir_to_uv(fine, *probe.shape[-2:], dim=1)
    rad = sample_bilinear(probe, u, v)[0]
    worst = 0.0
    for n in normals:
        e = float((rad * (fine @ n).clamp(min=0) * fine_w).sum())
        exact = float((d @ n).clamp(min=0))
        worst = max(worst, abs(e - exact) / max(exact, 0.2))
    return worst


def test_probe_splat_keeps_energy_and_direction_of_small_sources():
    """A source smaller than a probe texel (the sun, a bulb) splatted into a 16x32 probe gives the
    rendering layer's bilinear reconstruction the right irradiance on surfaces of any orientation;
    putting its energy at the texel centre (a box filter) is far worse."""
    from phyir.pano import dir_to_uv, solid_angles
    from phyir.synth.tracer import splat

    h, w = 16, 32
    omega = solid_angles(h, w).reshape(-1)
    g = torch.Generator().manual_seed(3)
    worst_splat = worst_box = 0.0
    for _ in range(10):
        d = torch.randn(3, generator=g)
        d[1] = d[1].abs() + 0.3  # above the horizon, like the sun through a window
        d = d / d.norm()
        up = torch.tensor([0.0, 1.0, 0.0])
        normals = [up, d, torch.nn.functional.normalize(d - 0.9 * up, dim=0)]  # floor, facing, grazing
        out = torch.zeros(h * w, 3)
        splat(out, torch.zeros(1, dtype=torch.long), d[None], torch.ones(1, 3), h, w, omega)
        assert float((out[:, 0] * omega).sum()) == pytest.approx(1.0, rel=1e-4)  # energy
        worst_splat = max(worst_splat, _cosine_error(out.T.reshape(3, h, w), d, normals))
        u, v = dir_to_uv(d[None], h, w, dim=1)
        box = torch.zeros(h * w, 3)
        t = int(v.long().clamp(0, h - 1)) * w + int(u.long().clamp(0, w - 1))
        box[t] = 1 / omega[t]
        worst_box = max(worst_box, _cosine_error(box.T.reshape(3, h, w), d, normals))
    assert worst_splat < 0.05 and worst_box > 2 * worst_splat
