"""Paths through the synthetic rooms: hit records, the BRDF at hits, the light map of emitters, next-event
estimation with multiple importance sampling and the path loop (used by :mod:`phyir.synth.tracer`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from phyir.shading import brdf, prefilter
from phyir.shading import sampling as S
from phyir.synth import geometry as G
from phyir.synth.lights import PORTAL
from phyir.synth.materials import evaluate

if TYPE_CHECKING:
    from phyir.synth.trace_settings import TraceSettings

SPAWN = 5e-4  # ray origin offset from surfaces


@dataclass
class Hits:
    """Surface hits (non-emitters) with everything shading needs; [N] rows."""

    p: Tensor
    n: Tensor  # shading normal, facing the incoming ray
    face: Tensor
    st: Tensor
    pid: Tensor
    base: Tensor
    rough: Tensor
    metal: Tensor


def make_hits(sc, pid: Tensor, p: Tensor, w: Tensor) -> Hits:
    surf = G.surface_at(sc.prims, pid, p)
    n = torch.where(((surf.n * w).sum(1) > 0)[:, None], -surf.n, surf.n)
    base, rough, metal = evaluate(sc.materials, sc.prim_mat[pid], surf.uv)
    return Hits(p, n, surf.face, surf.st, pid, base, rough, metal)


def cos(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(1, keepdim=True)


def eval_brdf(h: Hits, v: Tensor, l: Tensor) -> tuple[Tensor, Tensor]:
    """(f_d, f_s) ``[N,3]`` of the shared UE4 BRDF (phyir.shading.brdf) at hits."""
    return brdf.brdf_vectors(h.n, v, l, h.base, h.rough[:, None], h.metal[:, None], dim=1)


def spec_pdf(h: Hits, v: Tensor, l: Tensor) -> Tensor:
    """GGX (D(h) n.h / 4 v.h) density of light direction ``l`` [N]."""
    hv = v + l
    hv = hv / hv.norm(dim=1, keepdim=True).clamp(min=1e-12)
    alpha = brdf.alpha_from_roughness(h.rough)
    return S.ggx_pdf((h.n * hv).sum(1), (v * hv).sum(1), alpha)


def sample_spec(h: Hits, v: Tensor, u: Tensor) -> Tensor:
    alpha = brdf.alpha_from_roughness(h.rough)
    hl = S.ggx_half_vector(u, alpha)
    hw = S.local_to_world(hl, h.n)
    return S.reflect(v, hw)


def diffuse_prob(h: Hits) -> Tensor:
    """Probability of sampling the cosine lobe at the camera vertex."""
    wd = (h.base * (1 - h.metal[:, None])).mean(1)
    ws = brdf.f0_from_material(h.base, h.metal[:, None]).mean(1) + 0.1
    return wd / (wd + ws)


def traced_spec(h: Hits) -> Tensor:
    """Vertices whose specular lobe is traced (glossy dielectrics, metals); the rest use
    :func:`rough_spec` (a rough dielectric's weak, broad lobe under its cached irradiance)."""
    return (h.rough < 0.45) | (h.metal > 0.5)


def rough_spec(h: Hits, v: Tensor, e: Tensor) -> Tensor:
    """Specular reflection of irradiance ``e`` as if it arrived uniformly: albedo * e / pi."""
    f0 = brdf.f0_from_material(h.base, h.metal[:, None])
    alb = prefilter.specular_albedo(cos(h.n, v).squeeze(1).clamp(1e-4, 1), h.rough, f0)
    return alb * e / math.pi


class LightMap:
    """Irradiance cache on per-face texel grids of every primitive (see the module doc)."""

    def __init__(self, sc, texel: float, max_texels: int | None = None):
        P = sc.prims
        dev = P.device
        emitter = (sc.lights.prim_light >= 0).cpu()
        if max_texels:
            area = sum(math.prod(G.face_extent(P, pid, f)) for pid in range(P.n_prims)
                       if not emitter[pid] for f in range(G.FACES[int(P.kind[pid])]))
            texel = max(texel, math.sqrt(area / max_texels))
        self.texel = texel
        self.base = torch.zeros(P.n_prims, 6, dtype=torch.long)
        self.res = torch.ones(P.n_prims, 6, 2, dtype=torch.long)
        pids, faces, sts = [], [], []
        total = 0
        for pid in range(P.n_prims):
            k = int(P.kind[pid])
            for f in range(G.FACES[k]):
                if emitter[pid]:
                    nu = nv = 1
                else:
                    a, b = G.face_extent(P, pid, f)
                    nu = int(min(max(math.ceil(a / texel), 1), 256))
                    nv = int(min(max(math.ceil(b / texel), 1), 256))
                self.base[pid, f] = total
                self.res[pid, f] = torch.tensor((nu, nv))
                s = (torch.arange(nu) + 0.5) / nu
                t = (torch.arange(nv) + 0.5) / nv
                ss, tt = torch.meshgrid(s, t, indexing="ij")
                sts.append(torch.stack((ss.reshape(-1), tt.reshape(-1)), 1))
                pids.append(torch.full((nu * nv,), pid, dtype=torch.long))
                faces.append(torch.full((nu * nv,), f, dtype=torch.long))
                total += nu * nv
        self.base, self.res = self.base.to(dev), self.res.to(dev)
        self.pid = torch.cat(pids).to(dev)
        self.face = torch.cat(faces).to(dev)
        self.st = torch.cat(sts).to(dev)
        self.n_texels = total
        self.e_dir = torch.zeros(total, 3, device=dev)
        self.e_ind = torch.zeros(total, 3, device=dev)

    def weights(self, pid: Tensor, face: Tensor, st: Tensor) -> tuple[Tensor, Tensor]:
        """Bilinear texel indices ``[N,4]`` and weights ``[N,4]`` at chart points."""
        base = self.base[pid, face]
        res = self.res[pid, face]
        nu, nv = res[:, 0], res[:, 1]
        x = (st[:, 0] * nu - 0.5).clamp(min=0)
        y = (st[:, 1] * nv - 0.5).clamp(min=0)
        x = torch.minimum(x, (nu - 1).float())
        y = torch.minimum(y, (nv - 1).float())
        x0 = torch.minimum(x.floor().long(), (nu - 2).clamp(min=0))
        y0 = torch.minimum(y.floor().long(), (nv - 2).clamp(min=0))
        fx = (x - x0).clamp(0, 1)
        fy = (y - y0).clamp(0, 1)
        x1 = torch.minimum(x0 + 1, nu - 1)
        y1 = torch.minimum(y0 + 1, nv - 1)
        idx = torch.stack((x0 * nv + y0, x1 * nv + y0, x0 * nv + y1, x1 * nv + y1), 1) + base[:, None]
        w = torch.stack(((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy), 1)
        return idx, w

    def lookup(self, h: Hits, total: bool = True) -> Tensor:
        idx, w = self.weights(h.pid, h.face, h.st)
        e = self.e_dir + self.e_ind if total else self.e_ind
        return (e[idx] * w[..., None]).sum(1)


def _stratified(n: int, k: int, dim: int, gen: torch.Generator, dev) -> Tensor:
    """``[n*k, dim]`` uniforms: one Sobol set of ``k`` points per row, randomly rotated per row."""
    shift = torch.rand(n, 1, dim, generator=gen, device=dev)
    return S.rotate(S.point_set("sobol", k, dim, 0, dev)[None], shift).reshape(-1, dim)


def build_lightmap(sc, st: TraceSettings, gen: torch.Generator) -> LightMap:
    lm = LightMap(sc, st.texel, st.lm_max_texels)
    P = sc.prims
    dev = P.device
    x, n = G.chart_to_surface(P, lm.pid, lm.face, lm.st)
    T = lm.n_texels
    active = sc.lights.prim_light[lm.pid] < 0
    # direct irradiance by light sampling
    K = st.lm_light_samples
    e_dir = torch.zeros(T, 3, device=dev)
    for a in range(0, T, max(1, 65536 // K)):
        b = min(T, a + max(1, 65536 // K))
        nn = n[a:b].repeat_interleave(K, 0)
        xx = x[a:b].repeat_interleave(K, 0) + nn * SPAWN
        u = _stratified(b - a, K, 3, gen, dev)
        li, w, dist, le, pdf, is_sun = sc.lights.sample(xx, u, nn)
        cos = (w * nn).sum(1)
        ok = (pdf > 0) & (cos > 0)
        vis = visible(sc, xx, w, dist, is_sun, ok, li)
        contrib = torch.where((ok & vis)[:, None], le * (cos / pdf.clamp(min=1e-30))[:, None], 0.0)
        e_dir[a:b] = contrib.reshape(b - a, K, 3).mean(1)
    lm.e_dir = torch.where(active[:, None], e_dir, 0.0)
    # gather rays: a fixed set of cosine-distributed hits per texel, reused by every iteration
    Gn = st.lm_gather
    rows, cols, vals = [], [], []
    for a in range(0, T, max(1, 65536 // Gn)):
        b = min(T, a + max(1, 65536 // Gn))
        xx = x[a:b].repeat_interleave(Gn, 0)
        nn = n[a:b].repeat_interleave(Gn, 0)
        u = _stratified(b - a, Gn, 2, gen, dev)
        w = S.local_to_world(S.cosine_hemisphere(u), nn)
        t, pid = G.intersect(P, xx + nn * SPAWN, w)
        ok = (pid >= 0)
        ok &= sc.lights.prim_light[pid.clamp(min=0)] < 0
        m = torch.nonzero(ok).squeeze(1)
        if m.numel() == 0:
            continue
        h = make_hits(sc, pid[m], xx[m] + t[m, None] * w[m], w[m])
        rho = h.base * (1 - h.metal[:, None]) + brdf.f0_from_material(h.base, h.metal[:, None])
        idx, wt = lm.weights(h.pid, h.face, h.st)
        row = (m // Gn + a)
        # int32 indices: the gather matrix is the largest array of a scene (~7M entries)
        rows.append(row[:, None].expand(-1, 4).reshape(-1).int())
        cols.append(idx.reshape(-1).int())
        vals.append((wt[..., None] * rho[:, None, :] / Gn).reshape(-1, 3))
    rows = torch.cat(rows) if rows else torch.zeros(0, dtype=torch.int32, device=dev)
    cols = torch.cat(cols) if cols else torch.zeros(0, dtype=torch.int32, device=dev)
    vals = torch.cat(vals) if vals else torch.zeros(0, 3, device=dev)
    e_ind = torch.zeros(T, 3, device=dev)
    for _ in range(st.lm_iters):
        e_tot = lm.e_dir + e_ind
        e_ind = torch.zeros(T, 3, device=dev).index_add_(0, rows, vals * e_tot[cols])
        e_ind = torch.where(active[:, None], e_ind, 0.0)
    lm.e_ind = e_ind
    return lm


def visible(sc, x: Tensor, w: Tensor, dist: Tensor, is_sun: Tensor, ok: Tensor | None = None,
            li: Tensor | None = None) -> Tensor:
    """Is the sampled source visible from ``x``: nothing before ``dist`` (area lights; the source's
    own primitive ``li`` is ignored), or the ray leaves through a window (the sun)."""
    out = torch.zeros(len(x), dtype=torch.bool, device=x.device)
    m = torch.arange(len(x), device=x.device) if ok is None else torch.nonzero(ok).squeeze(1)
    if m.numel() == 0:
        return out
    sun = is_sun[m]
    tmax = torch.where(sun, float("inf"), dist[m] * (1 - 1e-4) - 1e-4)
    skip = None if li is None else torch.where(sun, -1, sc.lights.pid[li[m]])
    _, pid = G.intersect(sc.prims, x[m], w[m], tmax, skip)
    lp = sc.lights.prim_light[pid.clamp(min=0)]
    through_window = (pid >= 0) & (lp >= 0) & (sc.lights.kind[lp.clamp(min=0)] == PORTAL)
    out[m] = torch.where(sun, through_window, pid < 0)
    return out


def nee(sc, h: Hits, v: Tensor, u: Tensor, spec_only: bool, q_diffuse: Tensor | None,
        count: int = 1, group: int = 1) -> Tensor:
    """One light sample per hit, MIS-weighted against the BSDF sampling used at that vertex, which
    takes ``count`` light samples per BSDF sample (average ``count`` such results); ``group``: see
    :meth:`~phyir.synth.lights.Lights.sample`."""
    x = h.p + h.n * SPAWN
    li, l, dist, le, pdf, is_sun = sc.lights.sample(x, u, h.n, group)
    nl = cos(h.n, l).squeeze(1)
    ok = (pdf > 0) & (nl > 0) & (cos(h.n, v).squeeze(1) > 0)
    vis = visible(sc, x, l, dist, is_sun, ok, li)
    fd, fs = eval_brdf(h, v, l)
    f = fs if spec_only else fd + fs
    p_spec = spec_pdf(h, v, l)
    if spec_only:
        pb = p_spec
    else:
        pb = q_diffuse * nl.clamp(min=0) / math.pi + (1 - q_diffuse) * p_spec
    wgt = S.power_heuristic(count, pdf, 1, pb)
    c = f * le * (nl.clamp(min=0) * wgt / pdf.clamp(min=1e-30))[:, None]
    return torch.where((ok & vis)[:, None], c, 0.0)


def trace_paths(sc, lm: LightMap, x: Tensor, w: Tensor, beta: Tensor, beta_emit: Tensor,
                pdf_prev: Tensor, st: TraceSettings, gen: torch.Generator, n_prev: Tensor | None = None,
                nee_count: int = 1) -> Tensor:
    """Radiance carried back along rays ``(x, w)``: ``beta_emit`` weighs sources hit first
    (MIS against ``pdf_prev`` and ``nee_count`` light samples drawn at the vertex with normal
    ``n_prev``, :func:`nee`), ``beta`` everything reflected.  The diffuse lobe of every vertex
    reads the light map; the specular lobe continues the path."""
    dev = x.device
    N = len(x)
    L = torch.zeros(N, 3, device=dev)
    idx = torch.arange(N, device=dev)
    for depth in range(st.max_depth):
        if len(idx) == 0:
            break
        t, pid = G.intersect(sc.prims, x, w)
        hit = pid >= 0
        li = sc.lights.prim_light[pid.clamp(min=0)]
        em = torch.nonzero(hit & (li >= 0)).squeeze(1)
        if em.numel() and bool(beta_emit[em].any()):
            y = x[em] + t[em, None] * w[em]
            le, sun = sc.lights.emitted(li[em], w[em])
            p_l = sc.lights.pdf(x[em], li[em], y, w[em], None if n_prev is None else n_prev[em])
            p_s = sc.lights.pdf_sun(x[em], w[em])
            pp = pdf_prev[em]
            k = nee_count if depth == 0 else 1
            wl = torch.where(pp > 0, S.power_heuristic(1, pp, k, p_l), 1.0)
            ws = torch.where(pp > 0, S.power_heuristic(1, pp, k, p_s), 1.0)
            L.index_add_(0, idx[em], beta_emit[em] * (le * wl[:, None] + sun * ws[:, None]))
        sm = torch.nonzero(hit & (li < 0)).squeeze(1)
        if sm.numel() == 0:
            break
        x, w, t, pid = x[sm], w[sm], t[sm], pid[sm]
        beta, idx = beta[sm], idx[sm]
        h = make_hits(sc, pid, x + t[:, None] * w, w)
        v = -w
        fd = brdf.brdf_diffuse(h.base, h.metal[:, None])
        e = lm.lookup(h)
        traced = traced_spec(h)
        L.index_add_(0, idx, beta * (fd * e + torch.where(traced[:, None], 0.0, rough_spec(h, v, e))))
        if depth + 1 >= st.max_depth:
            break
        # specular lobe: traced on glossy/metal vertices, Russian roulette on low throughput
        q = torch.ones(len(idx), device=dev)
        if depth + 1 >= st.rr_depth:
            q = beta.amax(1).clamp(0.05, 1)
        keep = traced & (torch.rand(len(idx), generator=gen, device=dev) < q)
        k = torch.nonzero(keep).squeeze(1)
        if k.numel() == 0:
            break
        h = Hits(*(getattr(h, f)[k] for f in ("p", "n", "face", "st", "pid", "base", "rough", "metal")))
        v, beta, idx, q = v[k], beta[k] / q[k, None], idx[k], q[k]
        u = torch.rand(len(idx), 5, generator=gen, device=dev)
        L.index_add_(0, idx, beta * nee(sc, h, v, u[:, :3], True, None))
        l = sample_spec(h, v, u[:, 3:5])
        _, fs = eval_brdf(h, v, l)
        pdf = spec_pdf(h, v, l)
        nl = cos(h.n, l).squeeze(1)
        ok = (nl > 0) & (pdf > 0)
        beta = beta * fs * torch.where(ok, nl / pdf.clamp(min=1e-30), 0.0)[:, None]
        a = torch.nonzero(ok & (beta.amax(1) > 0)).squeeze(1)
        x, w, beta, idx, pdf_prev = h.p[a] + h.n[a] * SPAWN, l[a], beta[a], idx[a], pdf[a]
        n_prev = h.n[a]
        beta_emit = beta
    return L
