"""Path tracer for the synthetic rooms (torch, vectorised over rays, CPU or CUDA).

Outputs, for a :class:`~phyir.synth.rooms.TraceScene` seen from the origin (camera frame):

* exact G-buffers of the pixel-centre rays: radial depth, normal (facing the camera), base colour,
  roughness, metalness, emission mask;
* the HDR image: emitted radiance of emitters; on every other pixel next-event estimation on the
  sources (``nee_samples`` light samples per camera sample) with multiple importance sampling
  (power heuristic) against BSDF sampling, ``spp`` samples per pixel from rotated Sobol sets, plus
  indirect light;
* a probe grid: probe (a, b) at the surface point seen through the centre of block (a, b), offset
  5 cm along its normal; each texel the mean incident radiance over its solid angle.

Indirect light uses a **light map** (a radiance cache for diffuse transport): irradiance at texel
centres of every primitive face (~``texel`` metres), direct part by light sampling, indirect part by
cosine-sampled gather rays iterated to convergence (Jacobi; ``lm_iters`` diffuse bounces, each
gather hit reflecting with its diffuse + specular albedo).  The diffuse lobe of a path vertex reads
the cache; the specular lobe of glossy dielectrics and metals is traced: next-event estimation with
MIS plus a GGX-sampled continuation, Russian roulette from vertex ``rr_depth``, up to
``max_depth``; rough dielectrics reflect their cached irradiance with their exact specular albedo.
So camera pixels get exact direct light, cached diffuse indirect light, and traced glossy and mirror
reflections (of reflections, ...).

Probe texels: one ray through each texel centre for everything but emitters (its hit is shaded like
a path vertex); emitters seen directly are rasterised exactly instead: per probe and source, the
texels within the source's bounding cone are supersampled against the source's own shape (a
cheap one-primitive test, up to ``cov_budget`` sub-rays per probe and source) and multiplied by a
visibility fraction from ``vis_rays`` full shadow rays per texel; the sun adds ``sun_rays``
stratified visibility rays per probe inside its disc.  Each covered sub-ray is splatted bilinearly
(:func:`splat`), so the rendering layer's bilinear reconstruction gets every source's energy at its
true direction.  This keeps emitter edges, small lamps and the sun noise-free in the probes at one
ray per texel.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch
from torch import Tensor

from phyir.pano import bilinear_taps, dir_to_uv, directions, solid_angles, uv_to_dir
from phyir.scene import PROBE_OFFSET
from phyir.shading import brdf, prefilter
from phyir.shading import sampling as S
from phyir.synth import geometry as G
from phyir.synth.lights import PORTAL
from phyir.synth.materials import evaluate

SPAWN = 5e-4  # ray origin offset from surfaces


@dataclass
class TraceSettings:
    size: tuple[int, int] = (256, 512)
    probe_grid: tuple[int, int] | None = (64, 128)
    probe_size: tuple[int, int] = (16, 32)
    spp: int = 16  # camera samples per pixel
    nee_samples: int = 4  # light samples per camera sample (first vertex only)
    texel: float = 0.1  # light-map texel size (metres), enlarged to stay under lm_max_texels
    lm_max_texels: int = 12000
    lm_light_samples: int = 32
    lm_gather: int = 128  # a power of two: a complete Sobol net per texel
    lm_iters: int = 8
    max_depth: int = 6
    rr_depth: int = 3
    cov_budget: int = 1024  # sub-rays per probe and source for emitter coverage
    cov_max_sub: int = 12  # at most cov_max_sub^2 sub-rays per texel
    vis_rays: int = 4
    sun_rays: int = 8
    probe_batch: int = 512
    pixel_batch: int = 16384


@dataclass
class TraceResult:
    image: Tensor  # [3,H,W]
    depth: Tensor  # [1,H,W]
    normal: Tensor
    albedo: Tensor
    roughness: Tensor
    metallic: Tensor
    emission: Tensor  # [1,H,W] mask
    probes: Tensor | None  # [Hp,Wp,3,h,w]
    stats: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# hits and materials


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


def _cos(a: Tensor, b: Tensor) -> Tensor:
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
    alb = prefilter.specular_albedo(_cos(h.n, v).squeeze(1).clamp(1e-4, 1), h.rough, f0)
    return alb * e / math.pi


# ---------------------------------------------------------------------------------------------
# light map


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


# ---------------------------------------------------------------------------------------------
# visibility and next-event estimation


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
    nl = _cos(h.n, l).squeeze(1)
    ok = (pdf > 0) & (nl > 0) & (_cos(h.n, v).squeeze(1) > 0)
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
        nl = _cos(h.n, l).squeeze(1)
        ok = (nl > 0) & (pdf > 0)
        beta = beta * fs * torch.where(ok, nl / pdf.clamp(min=1e-30), 0.0)[:, None]
        a = torch.nonzero(ok & (beta.amax(1) > 0)).squeeze(1)
        x, w, beta, idx, pdf_prev = h.p[a] + h.n[a] * SPAWN, l[a], beta[a], idx[a], pdf[a]
        n_prev = h.n[a]
        beta_emit = beta
    return L


# ---------------------------------------------------------------------------------------------
# camera


def render_camera(sc, lm: LightMap, st: TraceSettings, seed: int, gen: torch.Generator):
    dev = sc.device
    H, W = st.size
    d = directions(H, W, device=dev).permute(1, 2, 0).reshape(-1, 3)
    o = torch.zeros_like(d)
    t, pid = G.intersect(sc.prims, o, d)
    if bool((pid < 0).any()):
        raise RuntimeError(f"{int((pid < 0).sum())} camera rays left the room (geometry leak)")
    p = t[:, None] * d
    li = sc.lights.prim_light[pid]
    h = make_hits(sc, pid, p, d)
    emissive = li >= 0
    image = torch.zeros(H * W, 3, device=dev)
    em = torch.nonzero(emissive).squeeze(1)
    if em.numel():
        le, sun = sc.lights.emitted(li[em], d[em])
        image[em] = le + sun
    surf = torch.nonzero(~emissive).squeeze(1)
    shifts = S.rotation_shifts(H * W, 5, seed + 101, device=dev)
    spp, K = st.spp, st.nee_samples
    for a in range(0, len(surf), max(1, st.pixel_batch // spp)):
        m = surf[a:a + max(1, st.pixel_batch // spp)]
        hb = Hits(*(getattr(h, f)[m] for f in ("p", "n", "face", "st", "pid", "base", "rough", "metal")))
        v = -d[m]
        acc = brdf.brdf_diffuse(hb.base, hb.metal[:, None]) * lm.lookup(hb, total=False)
        u = S.pixel_samples("sobol", len(m), spp, 5, seed, dev, shifts=shifts[m])  # [n,spp,5]
        # K light samples per camera sample: one Sobol set of spp*K points per pixel in the light
        # dimensions (K=1: dimensions 0-2 of u), consecutive points to one camera sample
        u_l = S.pixel_samples("sobol", len(m), spp * K, 3, seed, dev, shifts=shifts[m, :3])
        u_l = u_l.reshape(len(m), spp, K, 3)
        def rep(x):
            return x.repeat_interleave(spp, 0)
        hr = Hits(*(rep(getattr(hb, f)) for f in ("p", "n", "face", "st", "pid", "base", "rough", "metal")))
        vr = rep(v)
        ur = u.reshape(-1, 5)
        qd = diffuse_prob(hr)
        c = sum(nee(sc, hr, vr, u_l[:, :, k].reshape(-1, 3), False, qd, K, spp) for k in range(K)) / K
        # BSDF sample: lobe choice, then cosine or GGX direction
        first, u3 = S.select_lobe(ur[:, 3], qd)
        ud = torch.stack((u3, ur[:, 4]), 1)
        l_d = S.local_to_world(S.cosine_hemisphere(ud), hr.n)
        l_s = sample_spec(hr, vr, ud)
        l = torch.where(first[:, None], l_d, l_s)
        nl = _cos(hr.n, l).squeeze(1)
        pb = qd * nl.clamp(min=0) / math.pi + (1 - qd) * spec_pdf(hr, vr, l)
        fd, fs = eval_brdf(hr, vr, l)
        ok = (nl > 0) & (pb > 0)
        scale = torch.where(ok, nl / pb.clamp(min=1e-30), 0.0)[:, None]
        beta_emit = (fd + fs) * scale
        beta = fs * scale
        c = c + trace_paths(sc, lm, hr.p + hr.n * SPAWN, l, beta, beta_emit, pb, st, gen, hr.n, K)
        acc = acc + c.reshape(len(m), spp, 3).mean(1)
        image[m] = acc
    gbuf = dict(depth=t, normal=h.n, albedo=h.base, roughness=h.rough, metallic=h.metal,
                emission=emissive.float())
    return image, gbuf


# ---------------------------------------------------------------------------------------------
# probes


def probe_points(sc, st: TraceSettings) -> Tensor:
    """World positions ``[Hp*Wp, 3]`` of the probes (block-centre surface points + offset)."""
    H, W = st.size
    Hp, Wp = st.probe_grid
    bh, bw = H / Hp, W / Wp
    dev = sc.device
    v = (torch.arange(Hp, device=dev, dtype=torch.float64) + 0.5) * bh
    u = (torch.arange(Wp, device=dev, dtype=torch.float64) + 0.5) * bw
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    d = uv_to_dir(uu.reshape(-1), vv.reshape(-1), H, W, dim=1).float()
    t, pid = G.intersect(sc.prims, torch.zeros_like(d), d)
    surf = G.surface_at(sc.prims, pid, t[:, None] * d)
    n = torch.where(((surf.n * d).sum(1) > 0)[:, None], -surf.n, surf.n)
    return surf.p + PROBE_OFFSET * n


def render_probes(sc, lm: LightMap, st: TraceSettings, gen: torch.Generator) -> Tensor:
    dev = sc.device
    Hp, Wp = st.probe_grid
    h, w = st.probe_size
    q_all = probe_points(sc, st)
    out = torch.zeros(len(q_all), h * w, 3, device=dev)
    for a in range(0, len(q_all), st.probe_batch):
        q = q_all[a:a + st.probe_batch]
        out[a:a + len(q)] = _probe_main(sc, lm, q, st, gen) + _probe_emitters(sc, q, st, gen)
        out[a:a + len(q)] += _probe_sun(sc, q, st, gen)
    return out.reshape(Hp, Wp, h, w, 3).permute(0, 1, 4, 2, 3).contiguous()


def texel_dirs(i: Tensor, j: Tensor, jitter: Tensor, h: int, w: int) -> Tensor:
    """Directions ``[..., 3]`` in texels (row ``i``, column ``j``) of an h x w equirect image.

    ``jitter [..., 2]`` in [0,1)^2 maps uniformly in solid angle over the texel (uniform in
    longitude and in sin(latitude)), so averages of samples are texel means over solid angle.
    """
    lon = 2 * math.pi * (j + jitter[..., 0]) / w - math.pi
    s0 = torch.sin(math.pi / 2 - math.pi * i / h)
    s1 = torch.sin(math.pi / 2 - math.pi * (i + 1) / h)
    lat = torch.asin((s0 + (s1 - s0) * jitter[..., 1]).clamp(-1, 1))
    c = torch.cos(lat)
    return torch.stack((c * torch.sin(lon), torch.sin(lat), -c * torch.cos(lon)), -1)


def _texel_dirs(h: int, w: int, jitter: Tensor) -> Tensor:
    """Directions ``[..., h*w, 3]`` of all texels (row-major) at offsets ``jitter [..., h*w, 2]``."""
    j = torch.arange(w, device=jitter.device).repeat(h).float()
    i = torch.arange(h, device=jitter.device).repeat_interleave(w).float()
    return texel_dirs(i, j, jitter, h, w)


def _probe_main(sc, lm, q, st, gen) -> Tensor:
    h, w = st.probe_size
    P, T = len(q), h * w
    dev = q.device
    # texel-centre directions: the rendering layer reads probes as point samples (bilinear); a
    # random direction per texel would add the full texture/lighting variance within the texel
    d = _texel_dirs(h, w, torch.full((P, T, 2), 0.5, device=dev)).reshape(-1, 3)
    x = q.repeat_interleave(T, 0)
    one = torch.ones(len(x), 3, device=dev)
    L = trace_paths(sc, lm, x, d, one, torch.zeros_like(one), torch.zeros(len(x), device=dev), st, gen)
    return L.reshape(P, T, 3)


def splat(out: Tensor, row0: Tensor, d: Tensor, energy: Tensor, h: int, w: int, omega: Tensor) -> None:
    """Add ``energy [N,3]`` (radiance x solid angle) arriving from directions ``d [N,3]`` to the
    texels of flat probes ``out [P*h*w, 3]`` (probe ``k`` starts at row ``row0[k]``).

    The energy is split over the four texels of a bilinear look-up of ``d`` (the adjoint of the
    rendering layer's bilinear reconstruction), each share divided by that texel's solid angle: the
    reconstructed radiance then integrates to ``energy`` and its centroid lies at ``d`` — a box
    filter would move every source smaller than a texel to the texel centre (up to 5.6 degrees at
    16x32, a cosine error of up to ~35 % for a low sun on the floor).
    """
    u, v = dir_to_uv(d, h, w, dim=1)
    idx, wgt = bilinear_taps(u, v, h, w)
    val = energy[:, None, :] * (wgt / omega[idx])[..., None]
    out.index_add_(0, (row0[:, None] + idx).reshape(-1), val.reshape(-1, 3))


def _probe_emitters(sc, q, st, gen) -> Tensor:
    """Directly visible sources rasterised into the probe texels (see the module doc)."""
    lights = sc.lights
    h, w = st.probe_size
    P, T = len(q), h * w
    dev = q.device
    out = torch.zeros(P * T, 3, device=dev)
    texel_d = directions(h, w, device=dev).permute(1, 2, 0).reshape(T, 3)
    omega = solid_angles(h, w, device=dev).reshape(T)
    delta = math.hypot(math.pi / h / 2, math.pi / w)  # texel angular radius (upper bound)
    for li in range(lights.n):
        pid = int(lights.pid[li])
        if pid < 0:
            continue  # the sun: _probe_sun
        v = lights.centre[li] - q
        D = v.norm(dim=1)
        axis = v / D[:, None]
        r = float(lights.bound[li])
        half = torch.where(D > r, torch.asin((r / D).clamp(max=1)), math.pi)
        cand = (axis @ texel_d.T) >= torch.cos((half + delta).clamp(max=math.pi))[:, None]  # [P,T]
        n_c = cand.sum(1)
        sub = (st.cov_budget / n_c.clamp(min=1).float()).sqrt().floor().clamp(1, st.cov_max_sub).long()
        for s in sub.unique().tolist():
            pp, tt = torch.nonzero(cand & (sub == s)[:, None], as_tuple=True)
            if pp.numel() == 0:
                continue
            ns = s * s
            grid = torch.stack(torch.meshgrid(torch.arange(s, device=dev), torch.arange(s, device=dev),
                                              indexing="ij"), -1).reshape(ns, 2).float()
            # sub-ray cell centres: coverage and its bilinear split are deterministic (no probe noise)
            jit = ((grid + 0.5) / s)[None].expand(len(pp), ns, 2)
            i = (tt // w).float()[:, None]
            j = (tt % w).float()[:, None]
            dirs = texel_dirs(i, j, jit, h, w).reshape(-1, 3)
            org = q[pp].repeat_interleave(ns, 0)
            te = G.intersect_one(sc.prims, pid, org, dirs)
            hitm = torch.nonzero(torch.isfinite(te)).squeeze(1)
            if hitm.numel() == 0:
                continue
            pair = hitm // ns
            le, _ = lights.emitted(torch.full((len(hitm),), li, device=dev), dirs[hitm])
            # visibility from up to vis_rays random covered sub-rays per texel
            key = pair.double() + torch.rand(len(pair), generator=gen, device=dev, dtype=torch.float64) * 0.5
            order = torch.argsort(key)
            ps = pair[order]
            first = torch.searchsorted(ps, ps, right=False)
            rank = torch.arange(len(ps), device=dev) - first
            sel = order[rank < st.vis_rays]
            hs = hitm[sel]
            _, blk = G.intersect(sc.prims, org[hs], dirs[hs], te[hs] * (1 - 1e-4) - 1e-4)
            vis_n = torch.zeros(len(pp), device=dev).index_add_(0, pair[sel], (blk < 0).float())
            ones = torch.ones(len(sel), device=dev)
            tot_n = torch.zeros(len(pp), device=dev).index_add_(0, pair[sel], ones)
            frac = vis_n / tot_n.clamp(min=1)
            # each covered sub-ray carries radiance x its share of the texel's solid angle
            energy = le * (omega[tt[pair]] / ns * frac[pair])[:, None]
            splat(out, pp[pair] * T, dirs[hitm], energy, h, w, omega)
    return out.reshape(P, T, 3)


def _probe_sun(sc, q, st, gen) -> Tensor:
    lights = sc.lights
    h, w = st.probe_size
    P, T = len(q), h * w
    dev = q.device
    out = torch.zeros(P * T, 3, device=dev)
    if not lights.has_sun:
        return out.reshape(P, T, 3)
    K = st.sun_rays
    # the same K Sobol points of the disc for every probe and seed: the split of the sun's energy
    # among the texels is then noise-free; only the visibility of partly shadowed probes varies
    u = S.point_set("sobol", K, 2, 0, dev).repeat(P, 1)
    cos_t = 1 - u[:, 0] * (1 - lights.sun_cos)
    sin_t = torch.sqrt((1 - cos_t * cos_t).clamp(min=0))
    phi = 2 * math.pi * u[:, 1]
    loc = torch.stack((sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t), 1)
    d = S.local_to_world(loc, lights.sun_dir.expand(len(loc), 3))
    x = q.repeat_interleave(K, 0)
    vis = visible(sc, x, d, torch.full((len(x),), float("inf"), device=dev),
                  torch.ones(len(x), dtype=torch.bool, device=dev))
    energy = lights.radiance[lights.sun_index] * (lights.sun_omega / K) * vis.float()[:, None]
    splat(out, torch.arange(P, device=dev).repeat_interleave(K) * T, d, energy, h, w,
          solid_angles(h, w, device=dev).reshape(T))
    return out.reshape(P, T, 3)


# ---------------------------------------------------------------------------------------------
# entry point


def trace(sc, settings: TraceSettings | None = None, seed: int = 0) -> TraceResult:
    """Render a scene's image, G-buffers and (if ``settings.probe_grid``) probes."""
    st = settings or TraceSettings()
    H, W = st.size
    if st.probe_grid is not None:
        Hp, Wp = st.probe_grid
        if H % Hp or W % Wp:
            raise ValueError(f"probe grid {Hp}x{Wp} must divide the image size {H}x{W}")
    dev = sc.device
    gen = torch.Generator(device=dev).manual_seed(int(seed))
    stats = {}
    t0, c0 = time.perf_counter(), time.process_time()
    lm = build_lightmap(sc, st, gen)
    stats["lightmap_s"], stats["lightmap_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    stats["texels"] = lm.n_texels
    t0, c0 = time.perf_counter(), time.process_time()
    image, g = render_camera(sc, lm, st, seed, gen)
    stats["camera_s"], stats["camera_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    probes = None
    if st.probe_grid is not None:
        t0, c0 = time.perf_counter(), time.process_time()
        probes = render_probes(sc, lm, st, gen)
        stats["probes_s"], stats["probes_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    def img(x, c):
        return x.reshape(H, W, c).permute(2, 0, 1).contiguous()
    return TraceResult(image=img(image, 3), depth=img(g["depth"], 1), normal=img(g["normal"], 3),
                       albedo=img(g["albedo"], 3), roughness=img(g["roughness"], 1),
                       metallic=img(g["metallic"], 1), emission=img(g["emission"], 1), probes=probes,
                       stats=stats)
