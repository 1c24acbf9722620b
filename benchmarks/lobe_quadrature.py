"""Alternatives to the split sum for the fast path, measured on ``phyir bench render``'s scenes
(128x256, a probe per 2x2 pixels, probes of 16x32; relative RMSE of the image against converged
Monte Carlo, as the bench).  None of them was kept (docs/rendering.md, Findings):

* ``fis K``: filtered importance sampling as the viewer's object shader does it (K GGX directions of
  a Hammersley set, each looked up in the probes' area-downsampled mip chain at the level of its
  solid angle 1 / (K pdf)), trilinear;
* ``quad TxP``: a deterministic product rule in the GGX half-vector warp of the exact lobe: T
  Gauss-Legendre nodes in the warp's first coordinate, P midpoints in its azimuth (periodic), each
  node weighted by f_s cos / pdf and looked up in the bilinear probes (no filtering);
* ``hybrid F``: the split sum, with ``quad`` on the fraction F of shaded pixels whose specular lobe
  sees the most light (DFG albedo x the brighter of the two prefiltered levels the pixel blends, a
  detector that needs no reference), and the same with the F pixels of largest split-sum error
  (``oracle``, the bound for any detector).  Times: median CPU ms of 5 calls, one thread, the
  prefiltered render (prefiltering included) and the quadrature on the hybrid's pixels.

    .venv/bin/python -m benchmarks.lobe_quadrature [--kinds metal glossy] [--seeds 1 3 0]
        [--quad 4x4 4x8 8x8] [--fis 8 16 32] [--hybrid 4x8 8x8] [--fractions 0.05 0.1]
        [--bench benchmarks/results/render.json]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.bench.render_measure import Reference, interp_time, loglog
from phyir.bench.render_scenes import bench_scene, shaded_mask
from phyir.shading import prefilter, render, split_sum
from phyir.shading.brdf import alpha_from_roughness, f0_from_material, fresnel_ue4, ggx_d, visibility
from phyir.shading.pixels import select
from phyir.shading.probe_mixture import unit_uv
from phyir.shading.sampling import ggx_half_vector, local_to_world, point_set, reflect


def _cpu_ms(fn: Callable[[], object], n: int = 5) -> float:
    fn()
    ts = []
    for _ in range(n):
        t0 = time.process_time()
        fn()
        ts.append(time.process_time() - t0)
    return statistics.median(ts) * 1e3


def _pixels(scene, sel: Tensor | None = None):
    """The renderer's flat inputs of the shaded pixels (or of ``sel``, flat pixel indices)."""
    px, light, _, _ = render.scene_inputs(scene)
    idx = (~px.skip).nonzero()[:, 0] if sel is None else sel
    n, v, rough, base, metal = (select(t, idx) for t in (px.n, px.v, px.rough, px.base, px.metal))
    return px, light, idx, n, v, rough, f0_from_material(base, metal), light.index[idx], light.weight[idx]


def _lobe_directions(u: Tensor, n: Tensor, v: Tensor, rough: Tensor):
    """GGX half-vector warp of ``u [p, K, 2]``: l, n.h, v.h and f_s cos / pdf without Fresnel."""
    alpha = alpha_from_roughness(rough)[:, None, :]
    hl = ggx_half_vector(u, alpha)
    h = local_to_world(hl, n[:, None, :])
    l = reflect(v[:, None, :], h)
    nl, nh, vh = (n[:, None] * l).sum(-1), hl[..., 2], (v[:, None] * h).sum(-1)
    nv = (n * v).sum(-1, keepdim=True)
    ok = (nl > 0) & (vh > 0)
    w = torch.where(ok, visibility(nl.clamp(min=1e-6), nv, rough) * 4 * vh * nl / nh.clamp(min=1e-12), 0.0)
    return l, nh, vh, w


def _probe_bag(probes: Tensor, index: Tensor, weight: Tensor, l: Tensor, node_w: Tensor) -> Tensor:
    """``sum_k node_w[p, k, b] L_p(l[p, k])`` ``[B, p, 3]`` over the bilinear probes (level 0), one bag per
    pixel and weight set b."""
    h, w = probes.shape[-2:]
    p, K = l.shape[:2]
    u, v = pano.dir_to_uv(l, h, w, dim=-1)
    tidx, twgt = pano.bilinear_taps(u, v, h, w)  # [p, K, 4]
    rows = (index[:, None, :, None] * (3 * h * w) + tidx[:, :, None, :]).reshape(p, -1)
    tw = weight[:, None, :, None] * twgt[:, :, None, :]  # [p, K, 4 probes, 4 texels]
    B = node_w.shape[-1]
    wts = (tw[None] * node_w.permute(2, 0, 1)[..., None, None]).reshape(B * p, -1)
    planes = probes.reshape(-1).as_strided((probes.numel() - 2 * h * w, 3), (1, h * w))
    return F.embedding_bag(rows.repeat(B, 1), planes, per_sample_weights=wts, mode="sum").reshape(B, p, 3)


def gauss_nodes(nt: int, nphi: int, dtype=torch.float32) -> tuple[Tensor, Tensor]:
    """Product rule on [0, 1)^2: Gauss-Legendre in the first coordinate, midpoints in the second."""
    x, wx = np.polynomial.legendre.leggauss(nt)
    ut = torch.tensor((x + 1) / 2, dtype=dtype)
    wt = torch.tensor(wx / 2, dtype=dtype)
    up = (torch.arange(nphi, dtype=dtype) + 0.5) / nphi
    uu = torch.stack(torch.meshgrid(ut, up, indexing="ij"), -1).reshape(-1, 2)
    return uu, (wt[:, None] / nphi).expand(nt, nphi).reshape(-1)


def quadrature_specular(scene, nt: int, nphi: int, sel: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Flat pixel indices and their specular radiance ``[p, 3]`` by the ``nt x nphi`` product rule."""
    px, light, idx, n, v, rough, f0, index, weight = _pixels(scene, sel)
    u, wq = gauss_nodes(nt, nphi, n.dtype)
    l, _, vh, w = _lobe_directions(u[None].expand(len(idx), -1, 2), n, v, rough)
    s = fresnel_ue4(vh, torch.zeros_like(vh))  # F = F0 (1 - s) + s
    w = w * wq
    a, b = _probe_bag(light.probes, index, weight, l, torch.stack((w * (1 - s), w * s), -1))
    return idx, f0 * a + b


def fis_specular(scene, K: int) -> tuple[Tensor, Tensor]:
    """Filtered importance sampling over area-downsampled mips (the viewer's object shader)."""
    px, light, idx, n, v, rough, f0, index, weight = _pixels(scene)
    probes = light.probes
    h, w0 = probes.shape[-2:]
    mips = [probes]
    while mips[-1].shape[-2] > 2:
        mips.append(pano.resize_area(mips[-1], mips[-1].shape[-2] // 2, mips[-1].shape[-1] // 2))
    u = point_set("hammersley", K, 2, dtype=n.dtype)[None].expand(len(idx), K, 2)
    l, nh, vh, wgt = _lobe_directions(u, n, v, rough)
    pdf = ggx_d(nh, alpha_from_roughness(rough)) * nh / (4 * vh.clamp(min=1e-12))
    texel = 2 * math.pi**2 / (h * w0) * torch.sqrt(l[..., 0] ** 2 + l[..., 2] ** 2).clamp(min=1 / h)
    lod = (0.5 * torch.log2(1 / (K * pdf.clamp(min=1e-12) * texel))).clamp(0, len(mips) - 1).reshape(-1)
    i0 = lod.floor().long().clamp(max=len(mips) - 2)
    t = lod - i0
    uv = unit_uv(l)
    uv = (uv[0].reshape(-1, 1), uv[1].reshape(-1, 1))
    ii, ww = index.repeat_interleave(K, 0), weight.repeat_interleave(K, 0)
    rad = torch.zeros(len(idx) * K, 3, dtype=n.dtype)
    for lvl, m in enumerate(mips):
        share = torch.where(i0 == lvl, 1 - t, torch.where(i0 + 1 == lvl, t, torch.zeros_like(t)))
        r = (share > 0).nonzero()[:, 0]
        if r.numel():
            hl, wl = m.shape[-2:]
            table = m.permute(2, 3, 0, 1).reshape(hl * wl, -1, 3).contiguous()
            look = split_sum.lookup(table, hl, wl, ii[r], ww[r], (uv[0][r], uv[1][r]), share[r])
            rad.index_add_(0, r, look)
    fr = fresnel_ue4(vh[..., None], f0[:, None, :])
    return idx, (fr * wgt[..., None] * rad.reshape(len(idx), K, 3)).mean(1)


def light_in_lobe(scene) -> tuple[Tensor, Tensor]:
    """The hybrid's detector per shaded pixel: DFG albedo x the brighter (luminance) of the two
    prefiltered levels the split sum blends, at its two look-up directions."""
    px, light, idx, n, v, rough, f0, index, weight = _pixels(scene)
    nv = (n * v).sum(-1)
    shape = split_sum.lobe_shape(nv, rough[:, 0], f0)
    alphas = prefilter.PREFILTER_ALPHAS
    i0, _ = prefilter.level_coords_alpha(shape[:, 2], alphas)
    pf = prefilter.prefiltered(light.probes, alphas)
    taps = torch.stack(split_sum.lobe_taps(n, v, shape[:, 0], shape[:, 1]), 1)
    uv = unit_uv(taps)
    ones = torch.ones(len(idx), dtype=n.dtype)
    sh = pf.sh.permute(1, 2, 0).reshape(light.probes.shape[0], -1)
    lv = torch.stack([split_sum.level_radiance(pf, light.probes, sh, lvl, index, weight, taps, uv, ones)
                      for lvl in range(len(pf.plan))], 1).mean(-1)  # [p, levels]
    ar = torch.arange(len(idx))
    alb = prefilter.specular_albedo(nv, rough[:, 0], f0).mean(-1)
    return idx, alb * torch.maximum(lv[ar, i0], lv[ar, i0 + 1])


def _image(scene, out: dict[str, Tensor], idx: Tensor, spec: Tensor) -> Tensor:
    H, W = scene.size
    flat = out["specular"].permute(1, 2, 0).reshape(-1, 3).clone()
    flat[idx] = spec
    return out["diffuse"] + flat.T.reshape(3, H, W)


def _pattern(s: str) -> tuple[int, int]:
    a, b = s.split("x")
    return int(a), int(b)


def measure(kind: str, seed: int, args: argparse.Namespace) -> str:
    """One scene's line of the printout."""
    scene = bench_scene(kind, seed=seed)
    ref = Reference(scene, args.ref_spp, shaded_mask(scene))

    def err(img: Tensor) -> str:
        return f"{100 * ref.errors({'image': img, 'diffuse': img, 'specular': img})['err_image']:.2f}%"

    def split_sum() -> dict[str, Tensor]:
        prefilter.clear_cache()
        return render.render_scene(scene, method="prefiltered")

    out = split_sum()
    cells = [f"split sum {err(out['image'])}"]
    for nt, nphi in args.quad:
        cells.append(f"quad {nt}x{nphi} {err(_image(scene, out, *quadrature_specular(scene, nt, nphi)))}")
    for K in args.fis:
        cells.append(f"fis {K} {err(_image(scene, out, *fis_specular(scene, K)))}")
    idx, score = light_in_lobe(scene)
    e2 = ((out["image"] - ref.layers["image"]) ** 2).sum(0).reshape(-1)[idx]
    split_ms = _cpu_ms(split_sum)
    cells[0] += f" {split_ms:.0f} ms"
    for frac in args.fractions:
        k = int(frac * len(idx))
        for nt, nphi in args.hybrid:
            found = {}
            for name, s in (("light", score), ("oracle", e2)):
                sel = idx[s.topk(k).indices]
                found[name] = err(_image(scene, out, *quadrature_specular(scene, nt, nphi, sel)))
                cells.append(f"hybrid {frac:g} {nt}x{nphi} {name} {found[name]}")
            sel = idx[score.topk(k).indices]
            ms = _cpu_ms(lambda sel=sel, nt=nt, nphi=nphi: quadrature_specular(scene, nt, nphi, sel))
            cells.append(f"(quad {nt}x{nphi} on {k} px {ms:.0f} ms)")
            if args.bench:  # the detector's hybrid against importance sampling of equal error
                cells.append(_against_importance(args.bench, kind, seed, float(found["light"][:-1]),
                                                 split_ms + ms))
    return f"{kind} seed {seed}: " + " | ".join(cells)


def _against_importance(path: str, kind: str, seed: int, err_pct: float, ms: float) -> str:
    """Importance sampling of ``err_pct`` on that seed of a ``phyir bench render`` run (its error
    curve; CPU time at that spp from its seed-0 timing curve) against ``ms``."""
    import json

    res = json.loads(open(path).read())["scenes"][kind]
    row = next((r for r in res["seeds"]["rows"] if r["seed"] == seed), None)
    if row is None:
        return "(seed not in the bench run)"
    spp = [int(k) for k in row["is_errors"]]
    need = loglog(spp, list(row["is_errors"].values()), err_pct / 100)
    isr = [r for r in res["rows"] if r["method"] == "importance"]
    t = 1e3 * interp_time([r["spp"] for r in isr], [r["cpu_s"] for r in isr], need)
    return f"(= importance {need:.0f} spp, {t:.0f} ms: {t / ms:.1f}x)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["metal", "glossy"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 3, 0])
    ap.add_argument("--quad", type=_pattern, nargs="*", default=[(4, 4), (4, 8), (8, 8)])
    ap.add_argument("--fis", type=int, nargs="*", default=[8, 16, 32])
    ap.add_argument("--hybrid", type=_pattern, nargs="*", default=[(4, 8), (8, 8)])
    ap.add_argument("--fractions", type=float, nargs="*", default=[0.05, 0.1])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--bench", help="a `phyir bench render` render.json: the hybrids' speed-up over "
                    "importance sampling of equal error, as the bench measures it")
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.set_grad_enabled(False)
    for kind in args.kinds:
        for seed in args.seeds:
            print(measure(kind, seed, args), flush=True)


if __name__ == "__main__":
    main()
