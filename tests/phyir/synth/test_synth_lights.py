"""Light sources of the synthetic rooms: unbiased next-event estimation and the dynamic range."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from phyir.shading import sampling as S
from phyir.synth import geometry as G
from phyir.synth.dataset import tiny_settings
from phyir.synth.lights import (
    AREA,
    SUN,
    _area_pdf,
    _bilinear_pdf,
    _bilinear_warp,
    _rect_corner_dirs,
    _rect_invert,
    _rect_sample,
    _rect_solid_angle,
)
from phyir.synth.paths import SPAWN, visible
from phyir.synth.rooms import generate_room
from phyir.synth.sources import SOURCE_RATIO
from phyir.synth.tracer import trace


def _room_with(seed: int, want_sun: bool):
    for i in range(60):
        sc = generate_room(np.random.default_rng([seed, i])).build()
        if sc.lights.has_sun == want_sun and (want_sun or AREA in sc.lights.kind.tolist()):
            return sc
    raise AssertionError("no such room")


def _floor_points(sc, n: int) -> torch.Tensor:
    """Floor points seen straight down-ish from the camera, lifted off the surface."""
    g = torch.Generator().manual_seed(0)
    d = torch.randn(n, 3, generator=g) * torch.tensor([0.4, 0.0, 0.4]) + torch.tensor([0.0, -1.0, 0.0])
    d = d / d.norm(dim=1, keepdim=True)
    t, pid = G.intersect(sc.prims, torch.zeros_like(d), d)
    return t[:, None] * d + torch.tensor([0.0, SPAWN, 0.0])


def test_rect_sampling_covers_the_solid_angle_uniformly():
    """Spherical-rectangle sampling: its solid angle equals the area integral of cos/d^2, the
    sampled points lie on the quad, and an integral over the quad agrees with area sampling."""
    g = torch.Generator().manual_seed(1)
    N = 100000
    c, ex, ey = torch.tensor([[0.3, 2.5, -0.4]]), torch.tensor([[1.0, 0, 0]]), torch.tensor([[0, 0, 1.0]])
    n = torch.linalg.cross(ex, ey)  # (0,-1,0): emits downward, like a ceiling panel
    h = torch.tensor([[0.6, 0.3]])
    for x0 in ([0.0, 1.0, 0.0], [2.0, 2.3, 1.0], [0.5, 2.2, -0.2]):
        x = torch.tensor([x0]).expand(N, 3)
        u = torch.rand(N, 2, generator=g)
        def E(t):
            return t.expand(N, t.shape[1])
        w, dist, pdf = _rect_sample(x, E(c), E(ex), E(ey), E(n), E(h), u[:, 0], u[:, 1])
        y = c + ex * ((2 * u[:, :1] - 1) * h[:, :1]) + ey * ((2 * u[:, 1:] - 1) * h[:, 1:])
        wa, _, pa = _area_pdf(x, y, E(n), 4 * h.prod(), one_sided=True)
        inv_pa = torch.where(pa > 0, 1 / pa.clamp(min=1e-30), 0.0)
        omega = float(_rect_solid_angle(x[:1], c, ex, ey, n, h))
        assert omega == pytest.approx(float(inv_pa.mean()), rel=0.02)
        assert torch.allclose(pdf, torch.full_like(pdf, 1 / omega), rtol=1e-4)
        p = x + w * dist[:, None]
        assert float(((p - c) @ n[0]).abs().max()) < 1e-4
        assert float(((p - c) @ ex[0]).abs().max()) < 0.6 + 1e-4
        def f(v):
            return v[:, 0] ** 2 + (v[:, 1] > 0.9).float()
        assert float((f(w) / pdf).mean()) == pytest.approx(float((f(wa) * inv_pa).mean()), rel=0.03)


def _lambert_irradiance(x, n, corners) -> float:
    """Irradiance at ``x`` (normal ``n``) from a unit-radiance polygon above its horizon (Lambert)."""
    v = [(c - x) / (c - x).norm() for c in corners]
    e = 0.0
    for a, b in zip(v, v[1:] + v[:1]):
        g = torch.acos((a @ b).clamp(-1, 1))
        cr = torch.linalg.cross(a, b)
        e += float(g * (cr / cr.norm()) @ n)
    return abs(e) / 2


def test_cosine_warp_of_quads_is_unbiased_and_cuts_variance():
    """The bilinear cosine warp of spherical-rectangle sampling (Lights.quad_weights): irradiance
    from a window-like quad at floor points matches Lambert's closed form, with less variance than
    plain solid-angle sampling; _rect_invert inverts _rect_sample and the warp's density is the
    density of its samples."""
    g = torch.Generator().manual_seed(3)
    N = 200000
    c, ex, ey = torch.tensor([[2.0, 1.6, 0.0]]), torch.tensor([[0, 0, 1.0]]), torch.tensor([[0, 1.0, 0]])
    n = torch.linalg.cross(ex, ey)  # (-1,0,0): a window in the wall x = 2 facing the room
    h = torch.tensor([[0.7, 0.6]])
    def E(t):
        return t.expand(N, t.shape[1])
    corners = [c[0] + sx * h[0, 0] * ex[0] + sy * h[0, 1] * ey[0]
               for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    up = torch.tensor([0.0, 1.0, 0.0])
    for x0 in ([0.5, 0.0, 0.3], [1.5, 0.0, -1.0], [-1.0, 0.0, 0.5]):
        x = torch.tensor([x0]).expand(N, 3)
        u = torch.rand(N, 2, generator=g)
        ref = _lambert_irradiance(torch.tensor(x0), up, corners)
        cd = _rect_corner_dirs(x[:1], c, ex, ey, n, h)
        wq = E((cd @ up).clamp(min=0.01))
        est = []
        for warp in (False, True):
            a, b = (u[:, 0], u[:, 1]) if not warp else _bilinear_warp(u[:, 0], u[:, 1], wq)
            w, dist, pdf = _rect_sample(x, E(c), E(ex), E(ey), E(n), E(h), a, b)
            if warp:
                pdf = pdf * _bilinear_pdf(a, b, wq)
                y = x + w * dist[:, None]
                ia, ib = _rect_invert(x, E(c), E(ex), E(ey), E(n), E(h), y)
                assert float((ia - a).abs().max()) < 1e-3 and float((ib - b).abs().max()) < 1e-3
            f = (w @ up).clamp(min=0) / pdf
            est.append((float(f.mean()), float(f.std())))
        for mean, _ in est:
            assert mean == pytest.approx(ref, rel=0.01)
        assert est[1][1] < 0.7 * est[0][1]


@pytest.mark.parametrize("want_sun", [True, False])
def test_light_sampling_agrees_with_cosine_sampling(want_sun):
    """Direct irradiance at floor points: next-event estimation (power/distance selection, the sun
    only where it can pass a window, spherical-rectangle panels and windows with the cosine warp)
    against plain cosine
    sampling of the hemisphere; and Lights.pdf / pdf_sun give back the sampling densities."""
    sc = _room_with(2022 if want_sun else 7, want_sun)
    L = sc.lights
    pts = _floor_points(sc, 3)
    nrm = torch.tensor([[0.0, 1.0, 0.0]])
    g = torch.Generator().manual_seed(2)
    K = 240000  # cosine sampling of small bright lamps is noisy: ~1-2 % at this count
    for q in pts:
        x = q.expand(K, 3).contiguous()
        u = torch.rand(K, 3, generator=g)
        nx = nrm.expand(K, 3)
        li, w, dist, le, pdf, is_sun = L.sample(x, u, nx)
        cos = w[:, 1]
        ok = (pdf > 0) & (cos > 0)
        vis = visible(sc, x, w, dist, is_sun, ok, li)
        contrib = le * (cos / pdf.clamp(min=1e-30))[:, None]
        e_nee = float(torch.where((ok & vis)[:, None], contrib, 0.0).mean())
        # densities: the area lights' by Lights.pdf, the sun's by pdf_sun
        m = ok & ~is_sun
        y = x[m] + w[m] * dist[m, None]
        rel = (L.pdf(x[m], li[m], y, w[m], nx[m]) / pdf[m] - 1).abs()  # float32 round trip of y: grazing
        assert float((rel < 1e-2).float().mean()) > 0.999  # cylinder samples differ a little
        if bool(is_sun.any()):
            assert torch.allclose(L.pdf_sun(x[is_sun], w[is_sun]), pdf[is_sun], rtol=1e-4)
        # cosine sampling: pdf cos/pi, so E = pi * mean(radiance of what the ray hits)
        u2 = torch.rand(4 * K, 2, generator=g)
        wc = S.local_to_world(S.cosine_hemisphere(u2), nrm.expand(4 * K, 3))
        xc = q.expand(4 * K, 3).contiguous()
        t, pid = G.intersect(sc.prims, xc, wc)
        lid = L.prim_light[pid.clamp(min=0)]
        hit = torch.nonzero((pid >= 0) & (lid >= 0)).squeeze(1)
        le_c, sun_c = L.emitted(lid[hit], wc[hit])
        # one-sided panels emit only from their front
        front = torch.ones(len(hit), dtype=torch.bool)
        quad = L.gkind[lid[hit]] == G.QUAD
        front[quad] = (wc[hit][quad] * L.nq[lid[hit]][quad]).sum(1) < 0
        e_cos = math.pi * float(torch.where(front[:, None], le_c + sun_c, 0.0).sum()) / (4 * K) / 3
        assert e_nee == pytest.approx(e_cos, rel=0.06, abs=1e-3 * max(e_cos, e_nee))
    if want_sun:  # most floor points cannot see the sun: it gets only the uniform share there
        probs = L.select_probs(pts)
        through = L.sun_through_window(pts)
        share = 0.1 / L.n
        assert torch.allclose(probs[~through, L.sun_index], torch.full_like(probs[~through, 0], share))
        assert bool((L.kind == SUN).any())


def test_lamps_are_1e2_to_1e4_times_the_walls():
    """The brightest panel or lamp of each room (the sun and the sky apart) is 10^2-10^4 times the
    median non-emissive pixel of a (coarse) render of the room; in a white studio 10^1.7 (its walls
    bounce ~4x the light of a room's, and a lamp's shade, unlike a panel, is not made smaller)."""
    st = tiny_settings(size=(32, 64), probe_grid=None, spp=4)
    ratios, lows = [], []
    for i in range(8):
        room = generate_room(np.random.default_rng([31, i]))
        sc = room.build()
        area = sc.lights.kind == AREA
        if not bool(area.any()):
            continue
        r = trace(sc, st, seed=1)
        med = float(r.image.mean(0)[r.emission[0] < 0.5].median())
        ratios.append(float(sc.lights.radiance[area].mean(1).max()) / med)
        lows.append(10 ** 1.7 if room.style == "studio" else 1e2)
    assert len(ratios) >= 5
    assert all(lo <= r <= 1e4 for r, lo in zip(ratios, lows)), ratios
    # the drawn targets spread over the range, not one value
    assert max(ratios) / min(ratios) > 2
    assert SOURCE_RATIO[0] >= 2 and SOURCE_RATIO[1] <= 4


def test_light_samples_per_camera_sample_keep_the_image_unbiased():
    """The camera pass with 4 light samples per camera sample (multi-sample MIS weights, the
    cosine warp's density on BSDF hits of windows) has the same mean as with 1, and less noise."""
    from dataclasses import replace

    from phyir.synth.checks import rel_l1
    from phyir.synth.paths import build_lightmap
    from phyir.synth.tracer import render_camera

    sc = _room_with(2022, True)
    st = tiny_settings(size=(32, 64), probe_grid=None, spp=16)
    def g(s):
        return torch.Generator().manual_seed(s)
    lm = build_lightmap(sc, st, g(0))
    img = {}
    for k in (1, 4):
        sk = replace(st, nee_samples=k)
        img[k] = [render_camera(sc, lm, sk, s, g(s)) for s in (1, 2)]
    nonem = img[1][0][1]["emission"] < 0.5
    mean = {k: float(sum(im[nonem].sum() for im, _ in img[k])) for k in img}
    assert mean[4] == pytest.approx(mean[1], rel=0.004)  # MIS with count 1 for the light samples: -0.6 %
    noise = {k: rel_l1(img[k][0][0][nonem], img[k][1][0][nonem]) for k in img}
    assert noise[4] < 0.7 * noise[1]
