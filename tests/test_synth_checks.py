"""Small, fast versions of the generator's physical-consistency and noise checks (phyir.synth.checks)."""

from __future__ import annotations

from phyir.synth.checks import consistency, rel_l1
from phyir.synth.dataset import generate_scene, tiny_settings

TINY = tiny_settings(size=(32, 64), probe_grid=(8, 16), probe_size=(8, 16), spp=8)


def test_rendering_layer_reproduces_ground_truth():
    """The rendering layer on GT layers + probes gives back the GT image: no energy bias, and the
    per-pixel error stays bounded even with these coarse 8x16 probes and few samples."""
    res = [consistency(generate_scene(5, i, TINY), spp=64) for i in (0, 1)]
    ratio = sum(r["brightness_ratio"] for r in res) / len(res)
    assert 0.92 < ratio < 1.08
    assert sum(r["all"] for r in res) / len(res) < 0.3


def _noise(spp: int) -> tuple[float, float]:
    st = tiny_settings(size=(32, 64), probe_grid=(8, 16), probe_size=(8, 16), spp=spp)
    a = generate_scene(5, 1, st, sampler_seed=1)
    b = generate_scene(5, 1, st, sampler_seed=2)
    ka, kb = float(a.meta["exposure"]), float(b.meta["exposure"])
    nonem = a.masks["emission"] < 0.5
    return rel_l1(a.image / ka, b.image / kb, nonem), rel_l1(a.probes / ka, b.probes / kb)


def test_sampler_noise_is_small_and_shrinks_with_samples():
    img4, probes4 = _noise(4)
    img32, probes32 = _noise(32)
    assert img32 < 0.75 * img4
    assert img32 < 0.12 and probes32 < 0.3
