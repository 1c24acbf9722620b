"""Split-sum tables and probe prefiltering (phyir.shading.prefilter), against independent quadratures."""

from __future__ import annotations

import math

import pytest
import torch

from phyir import pano
from phyir.shading import prefilter


def _hemisphere(nt: int = 800, np_: int = 400):
    t = (torch.arange(nt, dtype=torch.float64) + 0.5) * (math.pi / 2 / nt)
    p = (torch.arange(np_, dtype=torch.float64) + 0.5) * (2 * math.pi / np_)
    t, p = torch.meshgrid(t, p, indexing="ij")
    d = torch.stack((t.sin() * p.cos(), t.sin() * p.sin(), t.cos()), -1).reshape(-1, 3)
    return d, (t.sin() * (math.pi / 2 / nt) * (2 * math.pi / np_)).reshape(-1)


def _lobe(l: torch.Tensor, nv: float, R: float) -> tuple[torch.Tensor, torch.Tensor]:
    """D Vis (n.l) and the Schlick factor Fc of directions ``l`` (n = z, v in the xz plane), written
    out from the supplement's formulas: f_s cos = (F0 (1 - Fc) + Fc) D Vis (n.l)."""
    v = torch.tensor([math.sqrt(1 - nv * nv), 0, nv], dtype=torch.float64)
    h = (l + v) / (l + v).norm(dim=-1, keepdim=True)
    nh, vh, nl = h[:, 2], h @ v, l[:, 2]
    a = R * R
    D = a * a / (math.pi * (nh * nh * (a * a - 1) + 1) ** 2)
    k = (R + 1) ** 2 / 8
    vis = 1 / (4 * (nl * (1 - k) + k) * (nv * (1 - k) + k))
    return D * vis * nl, 2 ** ((-5.55473 * vh - 6.98316) * vh)


def test_dfg_table_matches_brute_force_quadrature():
    table = prefilter.dfg_table(dtype=torch.float64)
    n = table.shape[-1]
    l, w = _hemisphere()
    for i, j in ((12, 3), (15, 20), (20, 10), (31, 31), (25, 0)):  # R = (i+.5)/n >= 0.39
        lobe, fc = _lobe(l, (j + 0.5) / n, (i + 0.5) / n)
        A = float(((1 - fc) * lobe * w).sum())
        B = float((fc * lobe * w).sum())
        assert abs(float(table[0, i, j]) - A) < 2e-3 * max(A, 0.1), (i, j, float(table[0, i, j]), A)
        assert abs(float(table[1, i, j]) - B) < 2e-3 * max(B, 0.1), (i, j, float(table[1, i, j]), B)


def _rms(w: torch.Tensor, x: torch.Tensor) -> float:
    return math.sqrt(float((w * x * x).sum() / w.sum()))


def test_lobe_shape_table_matches_hemisphere_quadrature():
    # the lobe f_s cos (explicit formulas, F0 Fresnel) on a polar grid of the hemisphere: its mean
    # direction, RMS widths in and across the plane of n and v; the table's alpha: a kernel that wide
    tables = {f0: prefilter.lobe_shape_table(f0, dtype=torch.float64) for f0 in (0.04, 1.0)}
    n = tables[1.0].shape[-1]
    l, dw = _hemisphere(1200, 600)
    for f0, table in tables.items():
        for i, j in ((9, 6), (12, 3), (15, 20), (20, 10), (25, 30), (28, 16)):  # R = (i+.5)/n in [0.3, 0.9]
            nv = (j + 0.5) / n
            lobe, fc = _lobe(l, nv, (i + 0.5) / n)
            w = (f0 * (1 - fc) + fc) * lobe * dw
            m = (w[:, None] * l).sum(0)
            th = math.atan2(-float(m[0]), float(m[2]))
            f, d, alpha = (float(x) for x in table[:, i, j])
            th_r = math.acos(nv)  # normalize(lerp(n, r, f)) at angle th from n
            th_f = math.atan2(f * math.sin(th_r), 1 - f + f * math.cos(th_r))
            assert abs(th_f - th) < 0.01, (f0, i, j, th_f, th)
            e1 = torch.tensor([math.cos(th), 0.0, math.sin(th)], dtype=torch.float64)
            w1, w2 = _rms(w, l @ e1), _rms(w, l[:, 1])
            assert abs(d - math.sqrt(max(w1 * w1 - w2 * w2, 0))) < 0.01, (f0, i, j, d, w1, w2)
            kh = torch.sqrt((1 + l[:, 2]) / 2)  # the kernel D(h) (r.l) around r = z
            kernel = alpha**2 / (math.pi * (kh * kh * (alpha**2 - 1) + 1) ** 2) * l[:, 2] * dw
            assert abs(_rms(kernel, l[:, 0]) / w2 - 1) < 0.03, (f0, i, j, alpha, _rms(kernel, l[:, 0]), w2)


def test_lobe_shape_table_limits():
    # near-mirror lobes sit on the mirror direction; at normal incidence the lobe is isotropic
    # (d ~ 0) and a little wider than the n = v = r kernel of its alpha (Schlick's G1(l) falls off
    # slower than the kernel's cosine); rough lobes lean to the normal (f << 1)
    t = prefilter.lobe_shape_table(1.0, dtype=torch.float64)
    n = t.shape[-1]
    assert float(t[0, 0].min()) > 0.99 and float(t[1, 0, n // 4:].max()) < 0.02
    R = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    assert float(t[1, 8:, -1].max()) < 0.05 < 0.2 < float(t[1, 8:24, 0].min())  # n.v 0.984 vs 0.016
    ratio = t[2, 8:24, -1] / R[8:24] ** 2
    assert float(ratio.min()) > 1.0 and float(ratio.max()) < 1.3, ratio
    assert float(t[0, -1].max()) < 0.1


def test_lookup_table_hits_texel_centres_and_clamps():
    t = torch.rand(2, 8, 8, dtype=torch.float64)
    nv = (torch.tensor([2, 5]) + 0.5) / 8
    r = (torch.tensor([7, 0]) + 0.5) / 8
    out = prefilter.lookup_table(t, nv.double(), r.double())
    torch.testing.assert_close(out, torch.stack([t[:, 7, 2], t[:, 0, 5]]))
    out = prefilter.lookup_table(t, torch.tensor([0.0, 1.0], dtype=torch.float64),
                                 torch.tensor([0.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(out, torch.stack([t[:, 0, 0], t[:, 7, 7]]))


def test_lookup_table_is_bilinear_between_texel_centres_with_its_gradient():
    # an explicit bilinear interpolation (texel centres at (i + 1/2) / n, clamped) at random points
    # inside and outside [0, 1], and the gradient in (n.v, R) by central differences
    g = torch.Generator().manual_seed(3)
    t = torch.rand(2, 8, 8, dtype=torch.float64, generator=g)
    nv = torch.rand(200, dtype=torch.float64, generator=g) * 1.3 - 0.15
    r = torch.rand(200, dtype=torch.float64, generator=g) * 1.3 - 0.15
    x, y = (nv * 8 - 0.5).clamp(0, 7), (r * 8 - 0.5).clamp(0, 7)
    x0, y0 = x.floor().clamp(max=6).long(), y.floor().clamp(max=6).long()
    fx, fy = x - x0, y - y0
    want = ((t[:, y0, x0] * (1 - fx) + t[:, y0, x0 + 1] * fx) * (1 - fy)
            + (t[:, y0 + 1, x0] * (1 - fx) + t[:, y0 + 1, x0 + 1] * fx) * fy).T
    torch.testing.assert_close(prefilter.lookup_table(t, nv, r), want, rtol=0, atol=1e-12)
    nv_, r_ = nv.clone().requires_grad_(True), r.clone().requires_grad_(True)
    gn, gr = torch.autograd.grad(prefilter.lookup_table(t, nv_, r_).sum(), (nv_, r_))
    e = 1e-6
    fd_n = (prefilter.lookup_table(t, nv + e, r) - prefilter.lookup_table(t, nv - e, r)).sum(-1) / (2 * e)
    fd_r = (prefilter.lookup_table(t, nv, r + e) - prefilter.lookup_table(t, nv, r - e)).sum(-1) / (2 * e)
    torch.testing.assert_close(gn, fd_n, rtol=0, atol=1e-5)
    torch.testing.assert_close(gr, fd_r, rtol=0, atol=1e-5)


def test_specular_albedo_is_f0_a_plus_b():
    t = prefilter.dfg_table()
    f0 = torch.tensor([[0.04, 0.5, 1.0]])
    e = prefilter.specular_albedo(torch.tensor([(3 + 0.5) / 32]), torch.tensor([(9 + 0.5) / 32]), f0)
    torch.testing.assert_close(e, f0 * t[0, 9, 3] + t[1, 9, 3])


def test_sh_basis_is_orthonormal():
    d = pano.directions(128, 256, dtype=torch.float64).permute(1, 2, 0).reshape(-1, 3)
    w = pano.solid_angles(128, 256, dtype=torch.float64).reshape(-1, 1)
    y = prefilter.sh_basis(d)
    assert y.shape[-1] == 25
    torch.testing.assert_close((y * w).T @ y, torch.eye(25, dtype=torch.float64), atol=2e-3, rtol=0)


def _smooth_env(h: int, w: int) -> torch.Tensor:
    d = pano.directions(h, w, dtype=torch.float64)
    a = torch.tensor([0.3, 0.8, -0.5], dtype=torch.float64)
    a = a / a.norm()
    lobe = torch.exp(3 * ((d * a[:, None, None]).sum(0) - 1))
    return torch.stack((1 + 4 * lobe, 0.5 + 2 * lobe + 0.3 * d[1], 0.8 + d[0] ** 2))


def _bilinear_radiance(env: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    return pano.sample_dir(env, dirs.T, dim=0).T  # [F, 3]


def test_irradiance_sh_matches_brute_force():
    env = _smooth_env(16, 32)
    fine = pano.directions(256, 512, dtype=torch.float64).reshape(3, -1).T
    om = pano.solid_angles(256, 512, dtype=torch.float64).reshape(-1)
    L = _bilinear_radiance(env, fine)
    normals = torch.nn.functional.normalize(torch.randn(20, 3, dtype=torch.float64), dim=-1)
    brute = ((normals @ fine.T).clamp(min=0) * om) @ L / math.pi  # [20, 3]
    c = prefilter.irradiance_sh(env)  # [3, 25]
    sh = prefilter.sh_basis(normals) @ c.T
    torch.testing.assert_close(sh, brute, rtol=1e-2, atol=0)
    img = prefilter.irradiance_map(env, (8, 16))
    assert img.shape == (3, 8, 16)


def test_prefiltered_level_matches_brute_force_convolution():
    env = _smooth_env(16, 32)
    alpha = 0.3
    pf = prefilter.Prefiltered(env[None], (0.0, alpha, 1.0))
    img = pf.image(1)[0]
    hl, wl = img.shape[-2:]
    r = pano.directions(hl, wl, dtype=torch.float64).reshape(3, -1).T
    fine = pano.directions(128, 256, dtype=torch.float64).reshape(3, -1).T
    om = pano.solid_angles(128, 256, dtype=torch.float64).reshape(-1)
    L = _bilinear_radiance(env, fine)
    cos = r @ fine.T
    nh = ((1 + cos) / 2).clamp(min=0).sqrt()
    a2 = alpha * alpha
    k = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2) * cos.clamp(min=0) * om
    brute = (k @ L) / k.sum(-1, keepdim=True)
    got = img.reshape(3, -1).T
    torch.testing.assert_close(got, brute, rtol=3e-3, atol=0)


def test_constant_probe_stays_constant_at_every_level():
    env = torch.full((2, 3, 16, 32), 2.5)
    for lvl in prefilter.prefilter_probe(env):
        torch.testing.assert_close(lvl, torch.full_like(lvl, 2.5), rtol=1e-4, atol=0)
        assert lvl.shape[:2] == (2, 3)
    irr = prefilter.irradiance_map(env)
    torch.testing.assert_close(irr, torch.full((2, 3, 16, 32), 2.5), rtol=1e-4, atol=0)


def test_level_coords_interpolate_in_alpha():
    R = torch.tensor([0.0, math.sqrt(0.3), math.sqrt(0.45), 1.0])
    i0, t = prefilter.level_coords(R, (0.0, 0.3, 0.6, 1.0))
    assert i0.tolist() == [0, 1, 1, 2]
    torch.testing.assert_close(t, torch.tensor([0.001 / 0.3, 0.0, 0.5, 1.0]), atol=1e-5, rtol=0)


def test_cache_reuses_and_invalidates():
    env = torch.rand(4, 3, 16, 32)
    a = prefilter.prefiltered(env)
    assert prefilter.prefiltered(env) is a
    env.mul_(2)  # in-place change bumps the version: recompute
    b = prefilter.prefiltered(env)
    assert b is not a
    torch.testing.assert_close(b.sh, 2 * a.sh)
    g = env.clone().requires_grad_(True)
    c = prefilter.prefiltered(g)
    c.sh.sum().backward()
    assert g.grad is not None and torch.isfinite(g.grad).all()
    assert prefilter.prefiltered(g) is not c  # never cached while it needs gradients


def test_cache_takes_inference_tensors():
    """phyir.predict's probes are inference tensors (no version counter): the viewer re-renders with
    them (this crashed with the shipped weights)."""
    with torch.inference_mode():
        env = torch.rand(4, 3, 16, 32)
    a = prefilter.prefiltered(env)
    assert prefilter.prefiltered(env) is a
    with torch.inference_mode():
        env.mul_(2)
    b = prefilter.prefiltered(env)
    assert b is not a
    torch.testing.assert_close(b.sh, 2 * a.sh)


def _lamp_probes(n: int) -> torch.Tensor:
    """``n`` float32 probes 16 x 32: a smooth sky plus a sub-texel lamp 300x brighter (HDR range)."""
    g = torch.Generator().manual_seed(5)
    d = pano.directions(16, 32, dtype=torch.float64)
    out = []
    for _ in range(n):
        a = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=torch.float64), dim=0)
        lamp = 300 * torch.exp(400 * ((d * a[:, None, None]).sum(0) - 1))
        out.append(torch.stack((0.3 + lamp, 0.25 + 0.1 * d[1] + lamp, 0.2 + 0.05 * d[0] + 0.8 * lamp)))
    return torch.stack(out).float()


def test_bfloat16_levels_match_float32(monkeypatch):
    """The bfloat16 level matmul (CPUs with native bfloat16): per texel within 1.2% of float32 (three
    bfloat16 roundings; 0.3% RMS) on HDR probes, the SH rows exactly the float32 ones, constants kept
    to bfloat16 rounding, gradients close.  Forced on here whatever the CPU (bfloat16 matmul runs
    everywhere, slower)."""
    env = _lamp_probes(6)
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "float32")
    ref = prefilter.Prefiltered(env)
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "auto")
    monkeypatch.setattr(prefilter, "cpu_has_native_bf16", lambda: True)
    monkeypatch.setattr(prefilter, "BF16_MIN_MACS", 0)
    assert prefilter.level_matmul_dtype(env, 1) == torch.bfloat16
    low = prefilter.Prefiltered(env)
    for a, b in zip(ref.maps, low.maps):
        if a is None:
            assert b is None
            continue
        assert b.dtype == torch.float32 and b.shape == a.shape
        rel = (b - a).abs() / a.abs()
        assert float(rel.max()) < 1.2e-2 and float(rel.pow(2).mean().sqrt()) < 3e-3
    torch.testing.assert_close(low.sh, ref.sh, rtol=0, atol=0)
    const = prefilter.Prefiltered(torch.full((2, 3, 16, 32), 2.5))
    for m in const.maps:
        if m is not None:
            torch.testing.assert_close(m, torch.full_like(m, 2.5), rtol=4e-3, atol=0)
    g32 = env.clone().requires_grad_(True)
    g16 = env.clone().requires_grad_(True)
    w = torch.rand(ref.maps[1].shape, generator=torch.Generator().manual_seed(1))
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "float32")
    (prefilter.Prefiltered(g32).maps[1] * w).sum().backward()
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "auto")
    (prefilter.Prefiltered(g16).maps[1] * w).sum().backward()
    assert torch.isfinite(g16.grad).all()
    assert float((g16.grad - g32.grad).norm() / g32.grad.norm()) < 1e-2


def test_level_matmul_dtype_policy(monkeypatch):
    big = prefilter.BF16_MIN_MACS
    x = torch.zeros(1)
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "auto")  # whatever PHYIR_LEVEL_PRECISION the run has
    monkeypatch.setattr(prefilter, "cpu_has_native_bf16", lambda: True)
    assert prefilter.level_matmul_dtype(x, big) == torch.bfloat16
    assert prefilter.level_matmul_dtype(x, big - 1) == torch.float32  # small products stay exact
    assert prefilter.level_matmul_dtype(x.double(), big) == torch.float64  # float64 stays float64
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "float32")
    assert prefilter.level_matmul_dtype(x, big) == torch.float32
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "auto")
    monkeypatch.setattr(prefilter, "cpu_has_native_bf16", lambda: False)
    assert prefilter.level_matmul_dtype(x, big) == torch.float32
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "bfloat16")  # forced on: the CPU isn't asked
    assert prefilter.level_matmul_dtype(x, big) == torch.bfloat16
    assert prefilter.level_matmul_dtype(x, big - 1) == torch.float32
    monkeypatch.setattr(prefilter, "LEVEL_PRECISION", "half")
    with pytest.raises(ValueError, match="LEVEL_PRECISION"):
        prefilter.level_matmul_dtype(x, big)


def test_cpu_bf16_detection_reads_the_flags(monkeypatch, tmp_path):
    import builtins

    real_open = builtins.open
    for flags, want in (("fpu avx512f avx512_bf16 sse", True), ("fpu amx_bf16", True), ("fpu avx2", False)):
        info = tmp_path / f"cpuinfo{int(want)}{len(flags)}"
        info.write_text(f"processor\t: 0\nflags\t\t: {flags}\n")
        monkeypatch.setattr(builtins, "open", lambda p, *a, _i=info, **k: real_open(
            _i if p == "/proc/cpuinfo" else p, *a, **k))
        prefilter.cpu_has_native_bf16.cache_clear()
        assert prefilter.cpu_has_native_bf16() is want
    monkeypatch.setattr(builtins, "open", real_open)
    prefilter.cpu_has_native_bf16.cache_clear()
