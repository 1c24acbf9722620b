"""The prefiltered (split-sum) shading path of :mod:`phyir.shading.render`: the specular lobe looked up
twice in the levels of :mod:`phyir.shading.prefilter` around its mean direction (:func:`lobe_taps`,
shaped by :func:`lobe_shape`), the diffuse lobe from the SH irradiance.  No samples; biased
(measured in docs/rendering.md)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.shading import prefilter
from phyir.shading.brdf import f0_from_material
from phyir.shading.pixels import Pixels, assemble, select
from phyir.shading.probe_mixture import Lighting, mix, unit_uv
from phyir.shading.sampling import reflect


def _sh_radiance(sh: Tensor, index: Tensor, weight: Tensor, d: Tensor) -> Tensor:
    """``sum_k c_k Y_k(d)`` with coefficients ``sh [N, 3*K]`` mixed over the pixels' probes; ``[p, 3]``.
    ``d [p, 3]``, or ``[p, T, 3]`` for the mean over T directions (the basis is linear)."""
    c = mix(sh, index, weight)  # [p, 3*K]
    y = prefilter.sh_basis(d)  # [p, K] or [p, T, K]
    y = y.mean(1) if y.dim() == 3 else y
    return torch.bmm(c.reshape(len(y), 3, -1), y[:, :, None])[..., 0]


def lobe_shape(nv: Tensor, rough: Tensor, f0: Tensor) -> Tensor:
    """``[p, 3]`` (f, d, alpha) of :func:`phyir.shading.prefilter.lobe_shape_table`, linear in F0 between
    its tables at :data:`phyir.shading.prefilter.LOBE_SHAPE_F0` (F0: the mean over channels)."""
    both = prefilter.lookup_table(prefilter.lobe_shape_tables(device=nv.device, dtype=nv.dtype), nv, rough)
    lo, hi = prefilter.LOBE_SHAPE_F0
    t = ((f0.mean(-1, keepdim=True) - lo) / (hi - lo)).clamp(0, 1)
    return torch.lerp(both[:, :3], both[:, 3:], t)


def lobe_taps(n: Tensor, v: Tensor, f: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
    """The split sum's two look-up directions: the lobe's mean direction ``normalize(lerp(n, r, f))``
    (r the mirror direction) moved by the tangent offsets ``+-d`` along the lobe's axis in the plane
    of n and v (:func:`phyir.shading.prefilter.lobe_shape_table`; ``f, d [p]``)."""
    mu = F.normalize(torch.lerp(n, reflect(v, n), f[:, None]), dim=-1)
    axis = n - (n * mu).sum(-1, keepdim=True) * mu  # zero at n.v = 1 or R = 1, where d = 0
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp(min=1e-4)
    step = d[:, None] * axis
    return F.normalize(mu + step, dim=-1), F.normalize(mu - step, dim=-1)


def lookup(table: Tensor, h: int, w: int, index: Tensor, weight: Tensor, uv: tuple[Tensor, Tensor],
           scale: Tensor, planes: bool = False) -> Tensor:
    """``scale x`` the mean of bilinear look-ups ``[p, 3]`` at ``uv`` (:func:`unit_uv`, ``[p, T]``
    each: T taps) of the pixels' probe mixtures ``index/weight [p, K]`` in one equirect level ``h x w``.

    ``table`` is texel-major channels-last ``[h*w, N, 3]`` (a prefiltered level) or, with
    ``planes``, the probes ``[N, 3, h, w]``, read through a strided view whose rows are a texel's
    three channel planes (no channels-last copy of the probes, which would cost more than every
    look-up).  Either way one weighted bag of K probes x T taps x 4 texels per pixel.
    """
    tidx, twgt = pano.bilinear_taps(uv[0] * w, uv[1] * h, h, w)  # [p, T, 4]
    p, T = tidx.shape[:2]
    tidx, twgt = tidx.reshape(p, -1), twgt.reshape(p, -1)
    N = table.shape[0] if planes else table.shape[1]
    ind = index.to(torch.int32) if table.numel() < 2**31 else index
    tidx = tidx.to(ind.dtype)
    if planes:
        idx = (ind * (3 * h * w))[:, :, None] + tidx[:, None, :]
    else:
        idx = ind[:, :, None] + (tidx * N)[:, None, :]
    idx = idx.reshape(p, -1)
    wgt = ((weight * (scale / T)[:, None])[:, :, None] * twgt[:, None, :]).reshape(p, -1)
    if not planes:
        return mix(table.reshape(-1, 3), idx, wgt)
    if torch.is_grad_enabled() and table.requires_grad:  # one bag per channel plane
        flat = table.reshape(-1, 1)
        return torch.cat([mix(flat, idx + c * (h * w), wgt) for c in range(3)], 1)
    # row i of this (overlapping) view holds (i, i + h w, i + 2 h w): a texel's three channel planes
    return mix(table.reshape(-1).as_strided((table.numel() - 2 * h * w, 3), (1, h * w)), idx, wgt)


def level_radiance(pf: prefilter.Prefiltered, probes: Tensor, sh: Tensor | None, level: int, index: Tensor,
                   weight: Tensor, taps: Tensor, uv: tuple[Tensor, Tensor], scale: Tensor) -> Tensor:
    """``scale x`` the mean radiance ``[p, 3]`` of prefiltered level ``level`` at the look-up
    directions ``taps [p, T, 3]`` (``uv`` their :func:`unit_uv`) of the pixels' probe mixtures
    ``index/weight``: the probes themselves, a map, or the SH irradiance (``sh [N, 3*K]``)."""
    kind, hl, wl = pf.plan[level]
    if kind == "sh":
        return scale[:, None] * _sh_radiance(sh, index, weight, taps)
    if kind == "probe":
        return lookup(probes, hl, wl, index, weight, uv, scale, planes=True)
    return lookup(pf.maps[level], hl, wl, index, weight, uv, scale)


def shade_prefiltered(px: Pixels, light: Lighting) -> tuple[Tensor, Tensor]:
    """(diffuse, specular) ``[P, 3]`` of the pixels by the split sum (zero where ``px.skip``)."""
    P = px.n.shape[0]
    dev, dt = px.n.device, px.n.dtype
    idx = (~px.skip).nonzero()[:, 0]
    if idx.numel() == 0:  # nothing to shade (all invalid, back-facing or emissive)
        return assemble(P, [], [], [], dev, dt)

    def sel(t: Tensor) -> Tensor:
        return t if idx.numel() == P else select(t, idx)

    n, v, rough, base, metal = (sel(t) for t in (px.n, px.v, px.rough, px.base, px.metal))
    index, weight = sel(light.index), sel(light.weight)
    alphas = prefilter.PREFILTER_ALPHAS
    nv = (n * v).sum(-1)
    f0 = f0_from_material(base, metal)
    shape = lobe_shape(nv, rough[:, 0], f0)
    i0, t = prefilter.level_coords_alpha(shape[:, 2], alphas)
    level_w = [torch.where(i0 == lvl, 1 - t, torch.where(i0 + 1 == lvl, t, torch.zeros_like(t)))
               for lvl in range(len(alphas))]
    rows = [(wl > 0).nonzero()[:, 0] for wl in level_w]
    rho = base * (1 - metal)
    lit = (rho.detach().amax(-1) > 0).nonzero()[:, 0]
    need = tuple(i for i, r in enumerate(rows) if r.numel()) + ((-1,) if lit.numel() else ())
    pf = prefilter.prefiltered(light.probes, alphas, need)
    N = light.probes.shape[0]
    sh = None if pf.sh is None else pf.sh.permute(1, 2, 0).reshape(N, -1)  # [N, 3*K]
    taps = torch.stack(lobe_taps(n, v, shape[:, 0], shape[:, 1]), 1)  # [p, 2, 3]
    uv = unit_uv(taps)  # one direction -> texel mapping for every level

    def look(level: int, rows: Tensor | None) -> Tensor:
        if rows is None:
            return level_radiance(pf, light.probes, sh, level, index, weight, taps, uv, level_w[level])
        return level_radiance(pf, light.probes, sh, level, index[rows], weight[rows], taps[rows],
                              (uv[0][rows], uv[1][rows]), level_w[level][rows])

    diffuse = torch.zeros_like(rho)
    if lit.numel():
        diffuse = diffuse.index_add(0, lit, rho[lit] * _sh_radiance(sh, index[lit], weight[lit], n[lit]))
    pf_rad = torch.zeros_like(diffuse)
    parts_i, parts_v = [], []
    for lvl, r_ in enumerate(rows):
        if r_.numel() == pf_rad.shape[0]:  # every pixel reads this level: no scatter
            pf_rad = pf_rad + look(lvl, None)
        elif r_.numel():
            parts_i.append(r_)
            parts_v.append(look(lvl, r_))
    if parts_i:
        pf_rad = pf_rad.index_add(0, torch.cat(parts_i), torch.cat(parts_v))
    spec = prefilter.specular_albedo(nv, rough[:, 0], f0) * pf_rad
    if idx.numel() == P:
        return diffuse, spec
    return assemble(P, [idx], [diffuse], [spec], dev, dt)
