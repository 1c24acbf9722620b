"""phyir.lighting.fusion: the geometric-mean shape with the mean energy, exposure-equivariant, and
why it is there: two estimates with independent multiplicative errors fuse to a better one."""

from __future__ import annotations

import pytest
import torch

from phyir import pano
from phyir.color import luminance
from phyir.lighting.fusion import fuse_probes


def energy(x: torch.Tensor) -> torch.Tensor:
    """Luminous energy per probe, [N]."""
    return (luminance(x) * pano.solid_angles(*x.shape[-2:], dtype=x.dtype)).sum((-2, -1))


def probes(seed: int, n: int = 6) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.exp(torch.randn(n, 3, 8, 16, generator=g, dtype=torch.float64))


def test_equal_estimates_are_kept():
    a = probes(0)
    torch.testing.assert_close(fuse_probes(a, a.clone()), a)


def test_shape_is_the_geometric_mean_and_energy_the_mean():
    a, b = probes(1), probes(2)
    for w in (0.5, 0.3):
        f = fuse_probes(a, b, w)
        torch.testing.assert_close(energy(f), w * energy(a) + (1 - w) * energy(b))
        ratio = f / (a ** w * b ** (1 - w))  # one factor per probe, every channel (to the log's floor)
        torch.testing.assert_close(ratio, ratio[:, :1, :1, :1].expand_as(ratio), rtol=1e-4, atol=0)


def test_exposure_equivariant():
    a, b = probes(3), probes(4)
    torch.testing.assert_close(fuse_probes(8 * a, 8 * b), 8 * fuse_probes(a, b))
    torch.testing.assert_close(fuse_probes(a / 1e4, b / 1e4), fuse_probes(a, b) / 1e4)


def test_the_colour_is_the_geometric_mean_of_the_colours():
    """A firelit room: the projection has almost no blue, LNet's probe is neutral. Every texel keeps the
    geometric mean's chromaticity (no channel gets another's energy)."""
    lnet = probes(8)
    proj = lnet * torch.tensor([1.6, 0.8, 0.01], dtype=lnet.dtype)[:, None, None]
    f = fuse_probes(lnet, proj)
    expected = torch.sqrt(lnet * proj)
    chroma = f / f.sum(-3, keepdim=True)
    torch.testing.assert_close(chroma, expected / expected.sum(-3, keepdim=True), rtol=1e-2, atol=1e-5)


def test_a_black_estimate_leaves_the_mean():
    b = probes(5)
    f = fuse_probes(torch.zeros_like(b), b)
    assert bool(torch.isfinite(f).all())
    torch.testing.assert_close(f, 0.5 * b)


def test_independent_multiplicative_errors_partly_cancel():
    truth = probes(6, n=64)
    g = torch.Generator().manual_seed(7)
    noise = [0.5 * torch.randn(truth.shape, generator=g, dtype=truth.dtype) for _ in range(2)]
    a, b = (truth * torch.exp(n) for n in noise)

    def log_mse(x):
        return float(((torch.log1p(x) - torch.log1p(truth)) ** 2).mean())

    assert log_mse(fuse_probes(a, b)) < 0.7 * min(log_mse(a), log_mse(b))


def test_shapes_must_match():
    with pytest.raises(ValueError, match="differ"):
        fuse_probes(probes(0), probes(0)[:, :, :4])
