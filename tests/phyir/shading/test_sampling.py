"""Sampling helpers (phyir.shading.sampling): point sets, frames, direction pdfs, MIS weights."""

from __future__ import annotations

import math

import torch

from phyir.shading import sampling as S
from phyir.shading.brdf import ggx_d


def test_radical_inverse_and_hammersley():
    r = S.radical_inverse(torch.arange(8), 2)
    torch.testing.assert_close(r, torch.tensor([0, 0.5, 0.25, 0.75, 0.125, 0.625, 0.375, 0.875],
                                               dtype=torch.float64))
    h = S.hammersley(4, 3)
    torch.testing.assert_close(h[:, 0], torch.tensor([0.125, 0.375, 0.625, 0.875]))
    torch.testing.assert_close(h[:, 2], torch.tensor([0, 1 / 3, 2 / 3, 1 / 9]))


def test_point_sets_are_seeded_and_in_unit_cube():
    a = S.pixel_samples("sobol", 100, 64, 2, seed=3)
    b = S.pixel_samples("sobol", 100, 64, 2, seed=3)
    c = S.pixel_samples("sobol", 100, 64, 2, seed=4)
    assert torch.equal(a, b) and not torch.equal(a, c)
    for kind in S.POINT_SETS:
        u = S.pixel_samples(kind, 50, 33, 2, seed=1)
        assert u.shape == (50, 33, 2) and float(u.min()) >= 0 and float(u.max()) < 1
    assert S.pixel_samples("sobol", 5, 0, 2).shape == (5, 0, 2)


def test_low_discrepancy_beats_iid():
    # variance over pixels (random rotations) of the estimate of a smooth 2D integral
    def f(u):
        return torch.exp(u[..., 0]) * torch.cos(3 * u[..., 1])
    exact = (math.e - 1) * math.sin(3) / 3
    var = {}
    for kind in S.POINT_SETS:
        est = f(S.pixel_samples(kind, 4000, 64, 2, seed=11)).mean(-1)
        assert abs(float(est.mean()) - exact) < 3e-3
        var[kind] = float(est.var())
    assert var["sobol"] < var["random"] / 20
    assert var["hammersley"] < var["random"] / 20


def test_orthonormal_basis_including_the_singular_pole():
    g = torch.Generator().manual_seed(0)
    n = torch.randn(2000, 3, generator=g)
    n[:4] = torch.tensor([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -1.0 + 1e-7], [1.0, 0, 0]])
    n = n / n.norm(dim=-1, keepdim=True)
    t, b = S.orthonormal_basis(n)
    for x in (t, b):
        torch.testing.assert_close(x.norm(dim=-1), torch.ones(2000), atol=1e-5, rtol=0)
    for x, y in ((t, b), (t, n), (b, n)):
        assert float((x * y).sum(-1).abs().max()) < 1e-5
    torch.testing.assert_close(torch.cross(t, b, dim=-1), n, atol=1e-5, rtol=0)
    d = S.local_to_world(torch.tensor([0.3, -0.4, 0.866]).expand(2000, 3), n)
    torch.testing.assert_close(S.world_to_local(d, n), torch.tensor([0.3, -0.4, 0.866]).expand(2000, 3),
                               atol=1e-5, rtol=0)


def _inverse_pdf_mean(d: torch.Tensor, pdf: torch.Tensor) -> float:
    ok = pdf > 0
    return float(torch.where(ok, 1 / pdf.clamp(min=1e-30), 0.0).mean())


def test_pdfs_integrate_to_their_support():
    # E[1/p] over samples drawn from p is the measure of p's support
    u = S.pixel_samples("sobol", 1, 1 << 16, 2, seed=5)[0].double()
    d = S.cosine_hemisphere(u)
    pdf = S.cosine_hemisphere_pdf(d[:, 2])
    assert abs(float((d[:, 2] ** 2 / pdf).mean()) - 2 * math.pi / 3) < 1e-3  # ∫ cos^2 over the hemisphere
    d = S.uniform_hemisphere(u)
    assert abs(_inverse_pdf_mean(d, S.uniform_hemisphere_pdf(d[:, 2])) - 2 * math.pi) < 1e-9
    d = S.uniform_sphere(u)
    assert abs(float(d.norm(dim=-1).mean()) - 1) < 1e-9
    assert abs(float(d[:, 2].mean())) < 1e-3
    # GGX at normal incidence: l = reflect(n, h) covers the whole sphere
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for alpha in (0.05, 0.3, 1.0):
        a = torch.tensor(alpha, dtype=torch.float64)
        h = S.ggx_half_vector(u, a)
        l = S.reflect(n.expand_as(h), h)
        nh, vh = h[:, 2:], h[:, 2:]
        pdf = S.ggx_pdf(nh, vh, a)
        assert abs(_inverse_pdf_mean(l, pdf) / (4 * math.pi) - 1) < 0.02, alpha


def test_ggx_half_vectors_follow_d_cos():
    # histogram of cos(theta_h) against the integral of D(h) (n.h) over each band
    a = torch.tensor(0.4, dtype=torch.float64)
    u = S.pixel_samples("random", 1, 200_000, 2, seed=9)[0].double()
    c = S.ggx_half_vector(u, a)[:, 2]
    edges = torch.linspace(0, 1, 11, dtype=torch.float64)
    hist = torch.histc(c, 10, 0, 1) / len(c)
    fine = torch.linspace(0, 1, 100_001, dtype=torch.float64)
    dens = ggx_d(fine, a) * fine * 2 * math.pi  # per d(cos theta)
    for i in range(10):
        m = (fine >= edges[i]) & (fine <= edges[i + 1])
        want = float(torch.trapezoid(dens[m], fine[m]))
        assert abs(float(hist[i]) - want) < 4e-3, (i, float(hist[i]), want)


def test_mis_weights_and_lobe_selection():
    pa, pb = torch.rand(1000), torch.rand(1000)
    for h in (S.balance_heuristic, S.power_heuristic):
        torch.testing.assert_close(h(3, pa, 5, pb) + h(5, pb, 3, pa), torch.ones(1000))
    assert float(S.balance_heuristic(1, torch.zeros(1), 1, torch.zeros(1))) == 0
    u = (torch.arange(10000, dtype=torch.float64) + 0.5) / 10000
    first, re = S.select_lobe(u, torch.tensor(0.3, dtype=torch.float64))
    assert abs(float(first.double().mean()) - 0.3) < 1e-3
    assert float(re.min()) >= 0 and float(re.max()) < 1
    assert abs(float(re[first].mean()) - 0.5) < 1e-3 and abs(float(re[~first].mean()) - 0.5) < 1e-3


def test_sample_linear_inverts_the_linear_cdf():
    g = torch.Generator().manual_seed(11)
    a, b, u = (torch.rand(1000, generator=g, dtype=torch.float64) for _ in range(3))
    a[:100] = 0.0  # a density that vanishes at one end
    t = S.sample_linear(u, a, b)
    cdf = (a * t + (b - a) * t * t / 2) / ((a + b) / 2)  # integral of lerp(a, b, s) ds, normalised
    torch.testing.assert_close(cdf, u, rtol=0, atol=1e-12)
    us, zero = torch.tensor([0.0, 0.3, 1.0], dtype=torch.float64), torch.zeros(3, dtype=torch.float64)
    torch.testing.assert_close(S.sample_linear(us, zero, zero), us)  # no density: uniform
