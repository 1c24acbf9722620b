"""Path tracer for the synthetic rooms (torch, vectorised over rays, CPU or CUDA).

Outputs, for a :class:`~phyir.synth.room.TraceScene` seen from the origin (camera frame):

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
from phyir.shading import brdf
from phyir.shading import sampling as S
from phyir.synth import geometry as G
from phyir.synth.paths import (
    SPAWN,
    Hits,
    LightMap,
    build_lightmap,
    cos,
    diffuse_prob,
    eval_brdf,
    make_hits,
    nee,
    sample_spec,
    spec_pdf,
    trace_paths,
    visible,
)
from phyir.synth.trace_settings import TraceSettings


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


# ---------------------------------------------------------------------------------------------
# light map


# ---------------------------------------------------------------------------------------------
# visibility and next-event estimation


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
        nl = cos(hr.n, l).squeeze(1)
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
    """The probe grid ``[Hp,Wp,3,h,w]`` at :func:`probe_points`."""
    Hp, Wp = st.probe_grid
    h, w = st.probe_size
    flat = render_probes_at(sc, lm, probe_points(sc, st), st, gen)
    return flat.reshape(Hp, Wp, 3, h, w)


def render_probes_at(sc, lm: LightMap, points: Tensor, st: TraceSettings, gen: torch.Generator) -> Tensor:
    """Probes ``[N,3,h,w]`` (``st.probe_size``) at any points ``[N,3]`` of the camera frame."""
    h, w = st.probe_size
    q_all = points.to(sc.device, torch.float32).reshape(-1, 3)
    out = torch.zeros(len(q_all), h * w, 3, device=sc.device)
    for a in range(0, len(q_all), st.probe_batch):
        q = q_all[a:a + st.probe_batch]
        out[a:a + len(q)] = _probe_main(sc, lm, q, st, gen) + _probe_emitters(sc, q, st, gen)
        out[a:a + len(q)] += _probe_sun(sc, q, st, gen)
    return out.reshape(-1, h, w, 3).permute(0, 3, 1, 2).contiguous()


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
