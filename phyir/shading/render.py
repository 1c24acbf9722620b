"""The rendering layer: shade pixels with the BRDF of :mod:`phyir.shading.brdf` under distant lighting.

Two entry points, both batched, device-agnostic and differentiable with respect to normals, view
vectors, materials and lighting:

* :func:`shade_env` — every pixel lit by one environment map (per batch item).
* :func:`render_scene` — every pixel of a :class:`~phyir.scene.PanoScene` lit by its own probe,
  bilinear between the four probes of the grid around it (probe (a, b) sits at the centre of block
  (a, b); wrap in longitude, clamp in latitude), seen from the camera centre.

Methods
-------
``"importance"`` (default)
    Monte Carlo, eq. 6 of the supplement, plus environment sampling: cosine-weighted, GGX
    half-vector and environment samples (∝ probe radiance x clamped cosine, per pixel, continuous:
    see :class:`phyir.shading.env_sampling.EnvSampler`) in the ratio :data:`SPLIT` (0 : 1 : 1) for
    pixels with a diffuse lobe, :data:`SPEC_SPLIT` (1 : 1 : 0) for metals; what the rounding leaves
    goes to the class's best single strategy (:data:`FIRST`), so 1 spp is one environment sample
    (GGX on metals).  The
    specular lobe combines all samples with the balance heuristic of multiple importance sampling
    (``1 / (n_d p_d + n_s p_s + n_e p_e)``); the diffuse lobe takes the environment samples alone
    (``1 / (n_e p_e)``), the other strategies only where p_e = 0 (see :func:`_mc_chunk`): unbiased
    for both lobes.  Metals keep the cosine samples: they cover the GGX lobe's tails, where
    D-proportional half-vector sampling at grazing views has large weights (measured: half/half
    beats 1/8-1/4 cosine and GGX only on metals at R = 0.3-0.5).
``"uniform"``
    ``spp`` directions uniform on the hemisphere (the baseline of the benchmark).
``"prefiltered"``
    Split sum (:mod:`phyir.shading.split_sum`), see :mod:`phyir.shading.prefilter`, looked up twice
    around the specular lobe's mean direction along its axis in the plane of n and v
    (:func:`phyir.shading.split_sum.lobe_taps`, shaped by the measured moments of the lobe): no
    samples, biased (measured in docs/rendering.md).

Samples come from one scrambled Sobol (or Hammersley, or iid ``sampler="random"``) point set per
lobe, rotated per pixel by seeded Cranley-Patterson shifts that depend on the pixel's position in
its image only, so results don't depend on chunking or batching and equal seeds give equal images on
every device.  Sample directions and pdfs are detached: gradients reach the integrand (BRDF, cosine,
radiance) and are unbiased for the expectation.  Pixels are shaded in chunks of
:data:`CHUNK_SAMPLES` samples, each checkpointed when gradients are needed.

Skips (``skips=True`` or a set of names from :data:`SKIPS`; measured in docs/rendering.md)
-----------------------------------------------------------------------------------------
``invalid``  normals that are non-finite or ~zero, back-facing pixels (n.v <= 0: the BRDF is zero
             there) and, in scenes, depth <= 0 or ``masks["invalid"] > 0.5``: zero, no shading.
             Always applied (those pixels are zero either way).
``emissive`` scenes only: ``masks["emission"] > 0.5`` → no shading; ``image`` keeps the scene's
             image value there, ``diffuse``/``specular`` are zero.
``mirror``   R < :data:`MIRROR_ROUGHNESS`: the specular lobe is one look-up in the reflected
             direction times the lobe's directional albedo (DFG table); slight bias.
``rough``    when the specular lobe can't exceed :data:`ROUGH_SPEC_RATIO` of the diffuse lobe under
             any lighting (π max_l f_s / (B(1-M)) from :func:`phyir.shading.prefilter.specular_peak_table`)
             pixels take half of ``spp``, cosine and environment samples only (:data:`ROUGH_SPLIT`),
             which still estimate the specular lobe, so this costs variance, not bias.
             ``ROUGH_ALL_COSINE = True`` spends all ``spp`` on the
             cosine lobe there instead (no time saved, less noise).

Precision: the layer always computes in float32 (float64 if given float64) with autocast disabled,
because GGX at R = 0 spans ~1e12 in value and gradient, beyond float16/bfloat16 — except the
prefiltered level maps' matmul, a normalised non-negative filter of radiance, which takes bfloat16
on CPUs that multiply it natively (:data:`phyir.shading.prefilter.LEVEL_PRECISION`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from phyir import pano
from phyir.errors import InputError
from phyir.scene import PanoScene, SceneError
from phyir.shading import env_sampling, prefilter
from phyir.shading.brdf import alpha_from_roughness, brdf, cosines, f0_from_material, ggx_d
from phyir.shading.pixels import Pixels, assemble, flat, flatten_pixels, select, unflat
from phyir.shading.probe_mixture import Lighting, probe_texels, radiance, unit_uv
from phyir.shading.sampling import (
    cosine_hemisphere,
    cosine_hemisphere_pdf,
    ggx_half_vector,
    ggx_pdf,
    local_to_world,
    pixel_samples,
    reflect,
    rotation_shifts,
    uniform_hemisphere,
)
from phyir.shading.split_sum import shade_prefiltered

METHODS = ("importance", "uniform", "prefiltered")
SKIPS = frozenset({"invalid", "emissive", "mirror", "rough"})
MIRROR_ROUGHNESS = 0.1
ROUGH_SPEC_RATIO = 0.2
ROUGH_ALL_COSINE = False
# share of the samples per strategy (cosine, GGX, environment): pixels with both lobes, pixels
# without a diffuse lobe (metals), pixels that sample the diffuse lobe only (rough skip, mirrors)
SPLIT = (0, 1, 1)
SPEC_SPLIT = (1, 1, 0)
ROUGH_SPLIT = (1, 0, 1)
# where the samples the split rounds away go (0 cosine, 1 GGX, 2 environment): at 1 spp a pixel
# takes one sample of this strategy, at odd spp one more.  Diffuse lobes: the environment, which
# follows radiance x cosine; metals: GGX.
FIRST = {"std": 2, "spec": 1, "rough": 2}
CHUNK_SAMPLES = 1 << 17  # samples (pixels x spp) per chunk: bounds memory to ~100 MB per chunk
# entries of a chunk's per-pixel environment-sampling tables (pixels x grid nodes; 1820 pixels for
# 16 x 32 probes): at low spp CHUNK_SAMPLES alone let them grow to 150 MB, and importance sampling
# ran 2-3x slower at 1-16 spp (docs/rendering.md, "Chunks"); results don't depend on chunking
ENV_TABLE_ENTRIES = 1 << 21


# ---------------------------------------------------------------------------------------------
# Monte Carlo over one chunk of pixels


def _mc_chunk(n: Tensor, v: Tensor, base: Tensor, rough: Tensor, metal: Tensor, u_d: Tensor,
              u_s: Tensor, u_e: Tensor, texels: Tensor, env: env_sampling.EnvSampler | None, index: Tensor,
              weight: Tensor, h: int, w: int, uniform: bool, with_spec: bool) -> tuple[Tensor, Tensor]:
    """(diffuse, specular) ``[p, 3]`` from ``u_d [p, n_d, 2]`` cosine, ``u_s [p, n_s, 2]`` GGX and
    ``u_e [p, n_e, 2]`` environment samples (``uniform``: ``u_d`` are uniform-hemisphere samples).

    The specular lobe weighs every sample by the balance heuristic over all strategies,
    ``1 / sum_i n_i p_i(l)``.  The diffuse lobe, which the environment strategy samples almost in
    proportion, takes environment samples only (``1 / (n_e p_e)``), plus the others' samples (balance
    heuristic among them) where p_e = 0: MIS weights that sum to one wherever any strategy reaches.
    """
    n_d, n_s, n_e = u_d.shape[1], u_s.shape[1], u_e.shape[1]
    with torch.no_grad():
        nn, vv = n.detach()[:, None], v.detach()[:, None]
        alpha = alpha_from_roughness(rough.detach())[:, None]  # [p, 1, 1]
        dirs = []
        if n_d:
            local = uniform_hemisphere(u_d) if uniform else cosine_hemisphere(u_d)
            dirs.append(local_to_world(local, nn))
        if n_s:
            hv = local_to_world(ggx_half_vector(u_s, alpha), nn)
            dirs.append(reflect(vv, hv))
        if n_e:
            tab = env_sampling.env_tables(env, nn[:, 0], index, weight)
            dirs.append(env_sampling.env_directions(env, tab, u_e).to(nn.dtype))
        l = torch.cat(dirs, 1) if len(dirs) > 1 else dirs[0]
        uv = unit_uv(l)
        c = cosines(nn, vv, l, dim=-1)
        nl, _, nh, vh = c
        if uniform:
            pdf = torch.full_like(nl, n_d / (2 * math.pi))
        else:
            pdf = n_d * cosine_hemisphere_pdf(nl)
            if n_s:
                pdf = pdf + n_s * ggx_pdf(nh, vh, alpha, ggx_d(nh, alpha))
        pdf_d = pdf
        if n_e:
            pe = n_e * env_sampling.env_pdf(env, tab, l, uv).to(pdf.dtype)
            env_sample = torch.arange(l.shape[1], device=l.device)[None, :, None] >= n_d + n_s
            pdf_d = torch.where(env_sample, pe, torch.where(pe > 0, torch.zeros_like(pdf), pdf))
            pdf = pdf + pe
        # below the horizon the integrand is zero: such samples are wasted, not biased
        up = nl > 0
        inv_pdf = torch.where((pdf > 0) & up, 1 / pdf.clamp(min=1e-30), torch.zeros_like(pdf))
        inv_d = torch.where((pdf_d > 0) & up, 1 / pdf_d.clamp(min=1e-30), torch.zeros_like(pdf))
    if n.requires_grad or v.requires_grad:  # the integrand's cosines carry the gradient
        c = cosines(n[:, None], v[:, None], l, dim=-1)
    fd, fs = brdf(*c, base[:, None], rough[:, None], metal[:, None])
    lw = radiance(texels, h, w, index, weight, None, uv=uv) * c[0].clamp(min=0)
    diffuse = (fd * lw * inv_d).sum(1)
    spec = (fs * lw * inv_pdf).sum(1) if with_spec else torch.zeros_like(diffuse)
    return diffuse, spec


# ---------------------------------------------------------------------------------------------
# pixel classes


def _classify(px: Pixels, light: Lighting, skips: frozenset[str], method: str) -> dict[str, Tensor]:
    """Pixel indices per class: 'std' (both lobes), 'spec' (no diffuse lobe: metals, black base),
    'rough', 'mirror_d' (mirrors with a diffuse lobe), 'mirror'."""
    with torch.no_grad():
        active = ~px.skip
        rho = (px.base * (1 - px.metal)).amax(-1)
        has_d = rho > 0
        rough = px.rough[:, 0]
        nv = (px.n * px.v).sum(-1)
        if method == "uniform":
            return {"uniform": active.nonzero()[:, 0]}
        mirror = active & (rough < MIRROR_ROUGHNESS) if "mirror" in skips else torch.zeros_like(active)
        rough_skip = torch.zeros_like(active)
        if "rough" in skips:
            f0 = f0_from_material(px.base, px.metal).amax(-1)
            t = prefilter.lookup_table(prefilter.specular_peak_table(device=nv.device, dtype=nv.dtype),
                                       nv, rough)
            bound = math.pi * (f0 * t[..., 0] + t[..., 1])
            rough_skip = active & has_d & ~mirror & (bound <= ROUGH_SPEC_RATIO * rho)
        full = active & ~mirror & ~rough_skip

        def pick(m: Tensor) -> Tensor:
            return m.nonzero()[:, 0]

        return {"std": pick(full & has_d), "spec": pick(full & ~has_d), "rough": pick(rough_skip),
                "mirror_d": pick(mirror & has_d), "mirror": pick(mirror)}


def _strategy_counts(spp: int, split: tuple[int, int, int], first: int) -> tuple[int, int, int]:
    """(cosine, GGX, environment) sample counts: ``spp`` shared in the ratio ``split``, every share
    rounded down, the rest to strategy ``first`` (0, 1, 2: the class's best single strategy, so that
    1-2 spp still sample what matters, e.g. one environment sample for a diffuse lobe).  Every
    strategy ``first`` may be alone reaches the whole hemisphere: unbiased at any ``spp``."""
    tot = sum(split)
    counts = [spp * s // tot for s in split]
    counts[first] += spp - sum(counts)
    return counts[0], counts[1], counts[2]


def _shade_mc(px: Pixels, light: Lighting, spp: int, method: str, seed: int, sampler: str,
              skips: frozenset[str]) -> tuple[Tensor, Tensor]:
    P = px.n.shape[0]
    dev, dt = px.n.device, px.n.dtype
    texels = probe_texels(light.probes)
    h, w = light.probes.shape[-2:]
    classes = _classify(px, light, skips, method)
    n_half = (spp + 1) // 2
    # (n_d, n_s, n_e, with_spec) per class
    if method == "uniform":
        plan = {"uniform": (spp, 0, 0, True)}
    else:
        rough = _strategy_counts(spp if ROUGH_ALL_COSINE else n_half, ROUGH_SPLIT, FIRST["rough"])
        plan = {"std": (*_strategy_counts(spp, SPLIT, FIRST["std"]), True),
                "spec": (*_strategy_counts(spp, SPEC_SPLIT, FIRST["spec"]), True), "rough": (*rough, True),
                "mirror_d": (*_strategy_counts(n_half, ROUGH_SPLIT, FIRST["rough"]), False)}
    uses_env = any(cnt[2] and name in classes and classes[name].numel() for name, cnt in plan.items())
    env = env_sampling.env_sampler(light.probes) if uses_env else None
    shifts = None
    if sampler != "random":  # the same per-pixel rotations in every image of a batch
        reps = P // px.per_image
        shifts = torch.cat((rotation_shifts(px.per_image, 4, seed + 0x5EED, dev, dt),
                            rotation_shifts(px.per_image, 2, seed + 0x5EEE, dev, dt)), 1).repeat(reps, 1)
    grad = torch.is_grad_enabled() and any(
        t.requires_grad for t in (px.n, px.v, px.base, px.rough, px.metal, light.probes))
    outs_idx, outs_d, outs_s = [], [], []
    for name, (n_d, n_s, n_e, with_spec) in plan.items():
        idx = classes.get(name)
        if idx is None or idx.numel() == 0:
            continue
        chunk = max(1, CHUNK_SAMPLES // max(n_d + n_s + n_e, 1))
        if n_e and env is not None:  # the per-pixel sampling tables, not the samples, fill the cache
            chunk = min(chunk, max(1, ENV_TABLE_ENTRIES // ((env.h + 2) * env.w * env.k)))
        for c0 in range(0, idx.numel(), chunk):
            ci = idx[c0:c0 + chunk]
            if sampler == "random":
                g = seed * 1000003 + c0 * 7 + len(outs_idx)
                u_d = pixel_samples("random", ci.numel(), n_d, 2, g, dev, dt)
                u_s = pixel_samples("random", ci.numel(), n_s, 2, g + 1, dev, dt)
                u_e = pixel_samples("random", ci.numel(), n_e, 2, g + 2, dev, dt)
            else:
                sh = shifts[ci]
                u_d = pixel_samples(sampler, ci.numel(), n_d, 2, seed, dev, dt, shifts=sh[:, :2])
                u_s = pixel_samples(sampler, ci.numel(), n_s, 2, seed + 1, dev, dt, shifts=sh[:, 2:4])
                u_e = pixel_samples(sampler, ci.numel(), n_e, 2, seed + 2, dev, dt, shifts=sh[:, 4:])
            args = (select(px.n, ci), select(px.v, ci), select(px.base, ci), select(px.rough, ci),
                    select(px.metal, ci), u_d, u_s, u_e, texels, env, select(light.index, ci),
                    select(light.weight, ci), h, w, name == "uniform", with_spec)
            if grad:
                d, s = checkpoint(_mc_chunk, *args, use_reentrant=False)
            else:
                d, s = _mc_chunk(*args)
            outs_idx.append(ci)
            outs_d.append(d)
            outs_s.append(s)
    mirror = classes.get("mirror")
    if mirror is not None and mirror.numel():
        outs_idx.append(mirror)
        outs_s.append(_mirror_specular(px, light, texels, mirror))
        outs_d.append(torch.zeros_like(outs_s[-1]))
    return assemble(P, outs_idx, outs_d, outs_s, dev, dt)


def _mirror_specular(px: Pixels, light: Lighting, texels: Tensor, idx: Tensor) -> Tensor:
    """One reflected look-up times the specular directional albedo."""
    n, v = select(px.n, idx), select(px.v, idx)
    nv = (n * v).sum(-1, keepdim=True)
    r = F.normalize(reflect(v, n), dim=-1)
    f0 = f0_from_material(select(px.base, idx), select(px.metal, idx))
    albedo = prefilter.specular_albedo(nv[:, 0], select(px.rough, idx)[:, 0], f0)
    h, w = light.probes.shape[-2:]
    rad = radiance(texels, h, w, select(light.index, idx), select(light.weight, idx), r[:, None])
    return albedo * rad[:, 0]


# ---------------------------------------------------------------------------------------------
# entry points


def _check(method: str, spp: int, sampler: str) -> None:
    if method not in METHODS:
        raise InputError("method", f"expected one of {METHODS}, got {method!r}")
    if method != "prefiltered" and (not isinstance(spp, int) or spp < 1):
        raise InputError("spp", f"expected a positive integer, got {spp!r}")
    if sampler not in ("sobol", "hammersley", "random"):
        raise InputError("sampler", f"expected sobol, hammersley or random, got {sampler!r}")


def _skip_set(skips: bool | Iterable[str]) -> frozenset[str]:
    if skips is True:
        return SKIPS
    if skips is False:
        return frozenset({"invalid"})
    s = frozenset(skips) | {"invalid"}
    if not s <= SKIPS:
        raise InputError("skips", f"unknown skip {sorted(s - SKIPS)}; expected names from {sorted(SKIPS)}")
    return s


def _compute_dtype(*ts: Tensor) -> torch.dtype:
    return torch.float64 if any(t.dtype == torch.float64 for t in ts) else torch.float32


def _shade(px: Pixels, light: Lighting, spp: int, method: str, seed: int, sampler: str,
           skips: frozenset[str]) -> tuple[Tensor, Tensor]:
    if method == "prefiltered":
        return shade_prefiltered(px, light)
    return _shade_mc(px, light, spp, method, seed, sampler, skips)


def shade_env(normal: Tensor, view: Tensor, base_color: Tensor, roughness: Tensor, metallic: Tensor,
              env: Tensor, *, spp: int = 64, method: str = "importance", seed: int = 0,
              sampler: str = "sobol", skips: bool | Iterable[str] = True,
              parts: bool = False) -> Tensor | tuple[Tensor, Tensor]:
    """Outgoing radiance ``[B?, 3, H, W]`` of pixels lit by a distant environment ``env [B?, 3, h, w]``.

    ``normal``, ``view`` are ``[B?, 3, H, W]`` unit vectors (``view`` from the surface toward the eye);
    ``base_color [B?, 3|1, H, W]``, ``roughness``/``metallic [B?, 1, H, W]``; an unbatched ``env``
    lights every batch item.  ``parts=True`` returns ``(diffuse, specular)`` instead of their sum.
    See the module doc for ``method``, ``sampler`` and ``skips`` (no emission mask here).
    """
    _check(method, spp, sampler)
    batched = normal.dim() == 4
    B = normal.shape[0] if batched else 1
    H, W = normal.shape[-2:]
    if env.dim() not in (3, 4) or env.shape[-3] != 3:
        raise InputError("env", f"expected [3,h,w] or [B,3,h,w], got {list(env.shape)}")
    dt = _compute_dtype(normal, view, base_color, roughness, metallic, env)
    with torch.autocast(normal.device.type, enabled=False):
        px = flatten_pixels(normal, view, base_color, roughness, metallic, B, None, dt)
        probes = env.to(dt).reshape(-1, *env.shape[-3:])
        if probes.shape[0] not in (1, B):
            raise InputError("env", f"batch {probes.shape[0]} doesn't match the pixels' batch {B}")
        index = torch.arange(B, device=probes.device) if probes.shape[0] == B else \
            torch.zeros(B, dtype=torch.long, device=probes.device)
        index = index.repeat_interleave(H * W)[:, None]
        light = Lighting(probes, index, torch.ones(index.shape, device=probes.device, dtype=dt))
        d, s = _shade(px, light, spp, method, seed, sampler, _skip_set(skips))
    d, s = unflat(d, B, H, W, batched), unflat(s, B, H, W, batched)
    return (d, s) if parts else d + s


def probe_weights(H: int, W: int, Hp: int, Wp: int, device=None,
                  dtype=torch.float32) -> tuple[Tensor, Tensor]:
    """Probe-grid indices (``a * Wp + b``) and bilinear weights ``[H*W, 4]`` of every pixel.

    Probe (a, b) sits at the centre of block (a, b); wraps in longitude, clamps in latitude.
    """
    j = (torch.arange(W, device=device, dtype=torch.float64) + 0.5) * (Wp / W)
    i = (torch.arange(H, device=device, dtype=torch.float64) + 0.5) * (Hp / H)
    v, u = torch.meshgrid(i, j, indexing="ij")
    idx, wgt = pano.bilinear_taps(u.reshape(-1), v.reshape(-1), Hp, Wp)
    return idx, wgt.to(dtype)


@lru_cache(maxsize=8)
def view_dirs(H: int, W: int, dev: torch.device, dt: torch.dtype) -> Tensor:
    """View vectors ``[3, H, W]`` of an ``H x W`` panorama: from each pixel's surface back to the camera."""
    return -pano.directions(H, W, dev, dt)


@lru_cache(maxsize=8)
def _probe_weights_cached(H: int, W: int, Hp: int, Wp: int, dev: torch.device,
                          dt: torch.dtype) -> tuple[Tensor, Tensor]:
    return probe_weights(H, W, Hp, Wp, dev, dt)


def scene_inputs(scene: PanoScene, skips: bool | Iterable[str] = True):
    """``(pixels, lighting, emissive, dtype)``: the flat :class:`~phyir.shading.pixels.Pixels`, the
    per-pixel :class:`~phyir.shading.probe_mixture.Lighting` and the emissive mask (``[B*H*W]`` bool,
    or ``None``) that :func:`render_scene` shades, under ``skips`` (as there); call it inside an
    autocast-disabled guard."""
    sk = _skip_set(skips)
    for name in ("normal", "albedo", "roughness", "metallic", "probes"):
        if getattr(scene, name) is None:
            raise SceneError(f"{name}: render_scene needs it (got None)")
    H, W = scene.size
    B = scene.image.shape[0] if scene.batched else 1
    Hp, Wp = scene.probe_grid  # type: ignore[misc]
    dev = scene.normal.device
    dt = _compute_dtype(scene.normal, scene.albedo, scene.roughness, scene.metallic, scene.probes)
    view = view_dirs(H, W, dev, dt)
    extra = torch.zeros(B * H * W, dtype=torch.bool, device=dev)
    emissive = None
    if "emission" in scene.masks and "emissive" in sk:
        emissive = flat(scene.masks["emission"], B, 1)[:, 0] > 0.5
        extra |= emissive
    if "invalid" in scene.masks:
        extra |= flat(scene.masks["invalid"], B, 1)[:, 0] > 0.5
    if scene.depth is not None:
        dep = flat(scene.depth, B, 1)[:, 0]
        extra |= ~(torch.isfinite(dep) & (dep > 0))
    px = flatten_pixels(scene.normal, view, scene.albedo, scene.roughness, scene.metallic, B, extra, dt)
    probes = scene.probes.to(dt).reshape(B * Hp * Wp, *scene.probes.shape[-3:])
    pidx, pw = _probe_weights_cached(H, W, Hp, Wp, dev, dt)
    index = (pidx[None] + (torch.arange(B, device=dev) * (Hp * Wp))[:, None, None]).reshape(-1, 4)
    return px, Lighting(probes, index, pw.repeat(B, 1)), emissive, dt


def render_scene(scene: PanoScene, *, spp: int = 64, method: str = "importance", seed: int = 0,
                 sampler: str = "sobol", skips: bool | Iterable[str] = True) -> dict[str, Tensor]:
    """Re-render a scene from its normals, materials and probes: ``dict(diffuse, specular, image)``.

    Each ``[B?, 3, H, W]``.  The view vector of a pixel points back to the camera centre (minus its
    panorama direction).  ``image = diffuse + specular`` except at emissive pixels (see module doc).
    Missing normals, materials or probes raise :class:`~phyir.scene.SceneError`.
    """
    _check(method, spp, sampler)
    sk = _skip_set(skips)
    H, W = scene.size
    B = scene.image.shape[0] if scene.batched else 1
    with torch.autocast(scene.image.device.type, enabled=False):
        px, light, emissive, dt = scene_inputs(scene, sk)
        d, s = _shade(px, light, spp, method, seed, sampler, sk)
        img = d + s
        if emissive is not None:
            img = torch.where(emissive[:, None], flat(scene.image.to(dt), B, 3), img)
    out = {"diffuse": d, "specular": s, "image": img}
    return {k: unflat(t, B, H, W, scene.batched) for k, t in out.items()}


def pixel_classes(scene: PanoScene, skips: bool | Iterable[str] = True) -> dict[str, Tensor]:
    """Flat pixel indices (into ``B*H*W``) of each Monte Carlo path, for the skip measurements.

    ``skipped`` (invalid, back-facing, emissive), ``std`` (full MIS), ``rough`` (no GGX samples),
    ``mirror`` (one reflected look-up; ``mirror_d`` of them also sample the diffuse lobe).
    """
    sk = _skip_set(skips)
    with torch.no_grad(), torch.autocast(scene.image.device.type, enabled=False):
        px, light, _, _ = scene_inputs(scene, sk)
        classes = _classify(px, light, sk, "importance")
    return {"skipped": px.skip.nonzero()[:, 0], **classes}
