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
    see :class:`_EnvSampler`) in the ratio :data:`SPLIT` (0 : 1 : 1) for pixels with a diffuse lobe,
    :data:`SPEC_SPLIT` (1 : 1 : 0) for metals; what the rounding leaves goes to the class's best
    single strategy (:data:`FIRST`), so 1 spp is one environment sample (GGX on metals).  The
    specular lobe combines all samples with the balance heuristic of multiple importance sampling
    (``1 / (n_d p_d + n_s p_s + n_e p_e)``); the diffuse lobe takes the environment samples alone
    (``1 / (n_e p_e)``), the other strategies only where p_e = 0 (see :func:`_mc_chunk`): unbiased
    for both lobes.  Metals keep the cosine samples: they cover the GGX lobe's tails, where
    D-proportional half-vector sampling at grazing views has large weights (measured: half/half
    beats 1/8-1/4 cosine and GGX only on metals at R = 0.3-0.5).
``"uniform"``
    ``spp`` directions uniform on the hemisphere (the baseline of the benchmark).
``"prefiltered"``
    Split sum, see :mod:`phyir.shading.prefilter`, looked up twice around the specular lobe's mean direction
    along its axis in the plane of n and v (:func:`_lobe_taps`, shaped by the measured moments of
    the lobe): no samples, biased (measured in docs/rendering.md).

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
from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from phyir import pano
from phyir.errors import InputError
from phyir.scene import PanoScene, SceneError
from phyir.shading import prefilter
from phyir.shading.brdf import alpha_from_roughness, brdf, cosines, f0_from_material, ggx_d
from phyir.shading.sampling import (
    cosine_hemisphere,
    cosine_hemisphere_pdf,
    ggx_half_vector,
    ggx_pdf,
    local_to_world,
    pixel_samples,
    reflect,
    rotation_shifts,
    sample_linear,
    uniform_hemisphere,
)

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
_POLE_EPS = 1e-6


# ---------------------------------------------------------------------------------------------
# lighting: per-pixel mixtures of equirect probes


@dataclass
class _Lighting:
    """Radiance of per-pixel probe mixtures: pixel p sees sum_k weight[p,k] probe[index[p,k]]."""

    probes: Tensor  # [N, 3, h, w]
    index: Tensor  # [P, K] long
    weight: Tensor  # [P, K]


def _texels(probes: Tensor) -> Tensor:
    """Channels-last flat texels ``[N*h*w, 3]`` of probes ``[N, 3, h, w]``."""
    return probes.permute(0, 2, 3, 1).reshape(-1, probes.shape[1])


def _safe_dirs(d: Tensor) -> Tensor:
    """Nudge directions off the poles so the longitude (atan2) has a finite gradient there."""
    x, y, z = d.unbind(-1)
    near = (x * x + z * z) < _POLE_EPS**2
    return torch.stack((torch.where(near, x + _POLE_EPS, x), y, z), -1)


def _mix(table: Tensor, index: Tensor, weight: Tensor) -> Tensor:
    """``sum_j weight[:, j] * table[index[:, j]]``: ``table [M, C]``, ``index/weight [n, k]`` -> ``[n, C]``.

    Without gradients to track this is one fused ``embedding_bag`` (2-20x faster on CPU); with them,
    a gather and a batched product (embedding_bag's backward into a large table is slower).
    """
    if torch.is_grad_enabled() and (table.requires_grad or weight.requires_grad):
        vals = table.index_select(0, index.reshape(-1)).reshape(*index.shape, table.shape[1])
        return torch.bmm(weight[:, None, :], vals)[:, 0]
    return F.embedding_bag(index, table, per_sample_weights=weight, mode="sum")


def _unit_uv(d: Tensor) -> tuple[Tensor, Tensor]:
    """Equirect coordinates of directions ``d [..., 3]`` scaled to [0, 1): multiply by (w, h)."""
    return pano.dir_to_uv(_safe_dirs(d) if d.requires_grad else d, 1, 1, dim=-1)


def _radiance(texels: Tensor, h: int, w: int, index: Tensor, weight: Tensor, d: Tensor | None,
              uv: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Radiance ``[p, S, 3]`` in directions ``d [p, S, 3]`` of pixels with probes ``index/weight [p, K]``.

    ``texels`` is probe-major channels-last ``[N*h*w, 3]`` (:func:`_texels`).  ``uv`` (from
    :func:`_unit_uv`, ``[p, S]`` each) replaces ``d`` when already known.
    """
    if uv is None:
        u, v = pano.dir_to_uv(_safe_dirs(d) if d.requires_grad else d, h, w, dim=-1)
    else:
        u, v = uv[0] * w, uv[1] * h
    p, s = u.shape[:2]
    k = index.shape[1]
    tidx, twgt = pano.bilinear_taps(u, v, h, w)  # [p, S, 4]
    idx = (index[:, None, :, None] * (h * w) + tidx[:, :, None, :]).reshape(p * s, k * 4)
    wgt = (weight[:, None, :, None] * twgt[:, :, None, :]).reshape(p * s, k * 4)
    return _mix(texels, idx, wgt).reshape(p, s, 3)


# ---------------------------------------------------------------------------------------------
# environment importance sampling: a continuous density, bilinear between the probes' texel centres


ENV_FLOOR = 1e-3  # of a probe's mean luminance: keeps every direction above the horizon reachable
ENV_GRID_ROWS = 16  # probes with more rows are sampled from an area-downsampled luminance map
ENV_COLUMNS = 2  # nodes per texel along a row: finer steps of the cosine factor across the horizon


@dataclass
class _EnvSampler:
    """Per-probe luminance at the nodes of the sampling grid, for a density ∝ radiance x clamped cosine.

    Nodes sit on the rows of the probes' texel centres (of an area-downsampled copy when probes have
    more than :data:`ENV_GRID_ROWS` rows), :data:`ENV_COLUMNS` per texel along each row (texel centres
    and the points between them, where the radiance is the linear interpolant of its neighbours),
    plus one row at each pole.  A pixel with normal n mixing probes with weights w_k gives node i the
    weight ``q_i = (sum_k w_k lum_k[i]) max(n.d_i, 0) cos(lat_i)`` (``cos(lat)``: the solid angle
    per unit of (u, v), zero at the poles) and draws (u, v) with a density equal to the bilinear
    interpolant of q.  The radiance is bilinear on that grid too, so radiance x cosine / pdf is
    nearly constant and continuous.  Sampling is exact and continuous in the random numbers: v from
    its marginal (piecewise linear in v) with u1, then u from its conditional at that v (piecewise
    linear in u) with u2 (:func:`_env_directions`).  Directions that land below the horizon (in
    cells straddling it) are mirrored about the tangent plane, so no sample is wasted and the
    density above the horizon is p(l) + p(mirror(l)) (:func:`_env_pdf`).
    """

    lum: Tensor  # [N, h*w*k] luminance (+ floor) at the nodes
    node_dir: Tensor  # [h*w*k, 3]
    node_cos_lat: Tensor  # [h*w*k]
    row_v: Tensor  # [h+2]: v of the node rows, poles included (0, 0.5, 1.5, ..., h-0.5, h)
    h: int  # rows of the grid (texel rows)
    w: int  # texel columns; node column j sits at u = 0.5 + j / k
    k: int


@dataclass
class _EnvTables:
    """Pixels' densities: normals ``n [p, 3]``, node weights ``q [p, (h+2)*w*k]`` (zero pole rows),
    cumulative masses of the dual rows ``row_cdf [p, h+1]`` and of the cells along each node row
    ``col_cdf [p, (h+2)*w*k]``."""

    n: Tensor
    q: Tensor
    row_cdf: Tensor
    col_cdf: Tensor


@lru_cache(maxsize=8)
def _env_grid(h: int, w: int, k: int, dev: torch.device, dt: torch.dtype) -> tuple[Tensor, Tensor, Tensor]:
    """Node directions ``[h*w*k, 3]``, their cos(latitude) and the v of the node rows (poles included)."""
    u = 0.5 + torch.arange(w * k, dtype=torch.float64) / k
    v = torch.arange(h, dtype=torch.float64) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    node_dir = pano.uv_to_dir(uu, vv, h, w, dim=-1).reshape(-1, 3)
    cos_lat = torch.sqrt(node_dir[:, 0] ** 2 + node_dir[:, 2] ** 2)
    pole = torch.zeros(1, dtype=torch.float64)
    row_v = torch.cat((pole, v, pole + h))
    return node_dir.to(dev, dt), cos_lat.to(dev, dt), row_v.to(dev, dt)


def _env_sampler(probes: Tensor) -> _EnvSampler:
    """Build the per-probe tables once per call (no gradients: pdfs are detached)."""
    with torch.no_grad():
        N, _, h, w = probes.shape
        dev, dt = probes.device, probes.dtype
        lum = torch.nan_to_num(probes.detach().mean(1), nan=0.0, posinf=0.0).clamp(min=0)
        if h > ENV_GRID_ROWS:
            h, w = ENV_GRID_ROWS, max(2, round(w * ENV_GRID_ROWS / h))
            lum = pano.resize_area(lum[:, None], h, w)[:, 0].clamp(min=0)
        k = ENV_COLUMNS
        # the bilinear radiance between texel centres j and j + 1 (wrapping) at the nodes in between
        step = torch.arange(k, device=dev, dtype=dt) / k
        lum = torch.lerp(lum[..., None], lum.roll(-1, -1)[..., None], step)  # [N, h, w, k]
        node_dir, cos_lat, row_v = _env_grid(h, w, k, dev, dt)
        lum = lum.reshape(N, h * w * k)
        mean = (lum * cos_lat).sum(1, keepdim=True) / cos_lat.sum()
        lum = lum + ENV_FLOOR * mean + torch.finfo(dt).tiny * 1e3
    return _EnvSampler(lum, node_dir, cos_lat, row_v, h, w, k)


def _env_tables(env: _EnvSampler, n: Tensor, index: Tensor, weight: Tensor) -> _EnvTables:
    """The density tables of pixels with normals ``n [p, 3]`` and probes ``index/weight [p, K]``."""
    h, wk = env.h, env.w * env.k
    p = n.shape[0]
    q = _mix(env.lum, index, weight) * (n @ env.node_dir.T).clamp(min=0) * env.node_cos_lat
    q = q.reshape(p, h, wk)
    q = F.pad(q, (0, 0, 1, 1))  # the poles: zero solid angle per unit of v
    col = ((q + q.roll(-1, -1)) * 0.5).cumsum(-1)  # cell j spans nodes j and j + 1 (wrapping)
    rows = col[..., -1]
    height = env.row_v[1:] - env.row_v[:-1]
    row_cdf = ((rows[:, :-1] + rows[:, 1:]) * (0.5 * height)).cumsum(-1)
    return _EnvTables(n, q.reshape(p, -1), row_cdf, col.reshape(p, -1))


def _invert(cdf: Tensor, u: Tensor) -> tuple[Tensor, Tensor]:
    """Bin ``[..., S]`` of ``u [..., S]`` in the inclusive CDFs ``cdf [..., n]`` (last = 1) and the
    position within the bin, in [0, 1]."""
    n = cdf.shape[-1]
    i = torch.searchsorted(cdf, u.contiguous(), right=True).clamp(max=n - 1)
    lo = torch.where(i > 0, cdf.gather(-1, (i - 1).clamp(min=0)), torch.zeros_like(u))
    frac = (u - lo) / (cdf.gather(-1, i) - lo).clamp(min=1e-30)
    return i, frac.clamp(0, 1)


def _lerp_rows(table: Tensor, r: Tensor, c: Tensor, t: Tensor, w: int) -> Tensor:
    """``table [p, (h+2)*w]`` at column ``c`` of node rows r and r + 1, interpolated at ``t``."""
    return torch.lerp(table.gather(1, r * w + c), table.gather(1, (r + 1) * w + c), t)


def _env_directions(env: _EnvSampler, tab: _EnvTables, u: Tensor) -> Tensor:
    """Directions ``[p, S, 3]`` from ``u [p, S, 2]``: v by the marginal, u by the conditional at v,
    mirrored above the horizon."""
    wk = env.w * env.k
    u = u.to(tab.q.dtype)
    r, xi = _invert(tab.row_cdf / tab.row_cdf[:, -1:].clamp(min=1e-30), u[..., 0])  # dual row [p, S]
    rows = tab.col_cdf[:, wk - 1::wk]  # [p, h+2]: node row sums
    a, b = rows.gather(1, r), rows.gather(1, r + 1)
    t = sample_linear(xi, a, b)
    # the cell: the first column whose cumulative mass at v exceeds u2 x the row's mass at v
    target = u[..., 1] * torch.lerp(a, b, t)
    lo, hi = torch.zeros_like(r), torch.full_like(r, wk - 1)
    for _ in range(max(1, (wk - 1).bit_length())):
        mid = (lo + hi) >> 1
        right = _lerp_rows(tab.col_cdf, r, mid, t, wk) <= target
        lo, hi = torch.where(right, mid + 1, lo), torch.where(right, hi, mid)
    c = lo.clamp(max=wk - 1)
    prev = torch.where(c > 0, _lerp_rows(tab.col_cdf, r, (c - 1).clamp(min=0), t, wk), torch.zeros_like(t))
    a = _lerp_rows(tab.q, r, c, t, wk)
    b = _lerp_rows(tab.q, r, torch.where(c == wk - 1, 0, c + 1), t, wk)
    xi = ((target - prev) / ((a + b) * 0.5).clamp(min=1e-30)).clamp(0, 1)
    uu = 0.5 + (c + sample_linear(xi, a, b)) / env.k
    vv = torch.lerp(env.row_v[r], env.row_v[r + 1], t)
    d = pano.uv_to_dir(uu, vv, env.h, env.w, dim=-1)
    n = tab.n[:, None]
    return d - 2 * (d * n).sum(-1, keepdim=True).clamp(max=0) * n


def _grid_density(env: _EnvSampler, tab: _EnvTables, u: Tensor, v: Tensor) -> Tensor:
    """The density's bilinear interpolant of q over cos(lat) at grid coordinates ``u, v [p, S]``
    (texel units), unnormalised."""
    h, wk = env.h, env.w * env.k
    r = torch.floor(v + 0.5).long().clamp(0, h)
    top = env.row_v[r]
    t = ((v - top) / (env.row_v[r + 1] - top)).clamp(0, 1)
    x = (u - 0.5) * env.k
    c = torch.floor(x)
    s = x - c
    c = torch.remainder(c.long(), wk)
    q0 = _lerp_rows(tab.q, r, c, t, wk)
    q1 = _lerp_rows(tab.q, r, torch.where(c == wk - 1, 0, c + 1), t, wk)
    return torch.lerp(q0, q1, s) / torch.sin(v * (math.pi / h)).clamp(min=1e-30)


def _env_pdf(env: _EnvSampler, tab: _EnvTables, d: Tensor, uv: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Density ``[p, S, 1]`` in solid angle of :func:`_env_directions` at unit directions ``d [p, S, 3]``
    (``uv``: their :func:`_unit_uv`, when already known): p(d) + p(mirror(d)) above the horizon."""
    h, w = env.h, env.w
    n = tab.n[:, None]
    c = (d * n).sum(-1, keepdim=True)
    u, v = _unit_uv(d) if uv is None else uv
    um, vm = _unit_uv(d - 2 * c * n)
    dens = _grid_density(env, tab, u * w, v * h) + _grid_density(env, tab, um * w, vm * h)
    # per unit of (u, v): k x the interpolant; solid angle per unit of (u, v): cos(lat) 2 pi^2 / (h w)
    norm = tab.row_cdf[:, -1:] * (2 * math.pi**2 / (h * w * env.k))
    pdf = dens / norm.clamp(min=1e-30)
    return torch.where(c > 0, pdf[..., None], torch.zeros_like(c))


# ---------------------------------------------------------------------------------------------
# Monte Carlo over one chunk of pixels


def _mc_chunk(n: Tensor, v: Tensor, base: Tensor, rough: Tensor, metal: Tensor, u_d: Tensor,
              u_s: Tensor, u_e: Tensor, texels: Tensor, env: _EnvSampler | None, index: Tensor,
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
            tab = _env_tables(env, nn[:, 0], index, weight)
            dirs.append(_env_directions(env, tab, u_e).to(nn.dtype))
        l = torch.cat(dirs, 1) if len(dirs) > 1 else dirs[0]
        uv = _unit_uv(l)
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
            pe = n_e * _env_pdf(env, tab, l, uv).to(pdf.dtype)
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
    lw = _radiance(texels, h, w, index, weight, None, uv=uv) * c[0].clamp(min=0)
    diffuse = (fd * lw * inv_d).sum(1)
    spec = (fs * lw * inv_pdf).sum(1) if with_spec else torch.zeros_like(diffuse)
    return diffuse, spec


# ---------------------------------------------------------------------------------------------
# pixel classes


@dataclass
class _Pixels:
    """Flat, channels-last pixel inputs: ``n, v [P, 3]``, ``base [P, 3]``, ``rough, metal [P, 1]``."""

    n: Tensor
    v: Tensor
    base: Tensor
    rough: Tensor
    metal: Tensor
    skip: Tensor  # [P] bool: no shading at all
    per_image: int  # pixels per image: pixel p draws the samples of pixel p % per_image


def _classify(px: _Pixels, light: _Lighting, skips: frozenset[str], method: str) -> dict[str, Tensor]:
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
        pick = lambda m: m.nonzero()[:, 0]  # noqa: E731
        return {"std": pick(full & has_d), "spec": pick(full & ~has_d), "rough": pick(rough_skip),
                "mirror_d": pick(mirror & has_d), "mirror": pick(mirror)}


def _select(t: Tensor, idx: Tensor) -> Tensor:
    return t.index_select(0, idx)


def _strategy_counts(spp: int, split: tuple[int, int, int], first: int) -> tuple[int, int, int]:
    """(cosine, GGX, environment) sample counts: ``spp`` shared in the ratio ``split``, every share
    rounded down, the rest to strategy ``first`` (0, 1, 2: the class's best single strategy, so that
    1-2 spp still sample what matters, e.g. one environment sample for a diffuse lobe).  Every
    strategy ``first`` may be alone reaches the whole hemisphere: unbiased at any ``spp``."""
    tot = sum(split)
    counts = [spp * s // tot for s in split]
    counts[first] += spp - sum(counts)
    return counts[0], counts[1], counts[2]


def _shade_mc(px: _Pixels, light: _Lighting, spp: int, method: str, seed: int, sampler: str,
              skips: frozenset[str]) -> tuple[Tensor, Tensor]:
    P = px.n.shape[0]
    dev, dt = px.n.device, px.n.dtype
    texels = _texels(light.probes)
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
    env = _env_sampler(light.probes) if uses_env else None
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
            args = (_select(px.n, ci), _select(px.v, ci), _select(px.base, ci), _select(px.rough, ci),
                    _select(px.metal, ci), u_d, u_s, u_e, texels, env, _select(light.index, ci),
                    _select(light.weight, ci), h, w, name == "uniform", with_spec)
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
    return _assemble(P, outs_idx, outs_d, outs_s, dev, dt)


def _assemble(P: int, idx: list[Tensor], d: list[Tensor], s: list[Tensor], dev, dt) -> tuple[Tensor, Tensor]:
    diffuse = torch.zeros(P, 3, device=dev, dtype=dt)
    spec = torch.zeros(P, 3, device=dev, dtype=dt)
    if idx:
        i = torch.cat(idx)
        diffuse = diffuse.index_add(0, i, torch.cat(d))
        spec = spec.index_add(0, i, torch.cat(s))
    return diffuse, spec


def _mirror_specular(px: _Pixels, light: _Lighting, texels: Tensor, idx: Tensor) -> Tensor:
    """One reflected look-up times the specular directional albedo."""
    n, v = _select(px.n, idx), _select(px.v, idx)
    nv = (n * v).sum(-1, keepdim=True)
    r = F.normalize(reflect(v, n), dim=-1)
    f0 = f0_from_material(_select(px.base, idx), _select(px.metal, idx))
    albedo = prefilter.specular_albedo(nv[:, 0], _select(px.rough, idx)[:, 0], f0)
    h, w = light.probes.shape[-2:]
    rad = _radiance(texels, h, w, _select(light.index, idx), _select(light.weight, idx), r[:, None])
    return albedo * rad[:, 0]


# ---------------------------------------------------------------------------------------------
# split sum


def _sh_radiance(sh: Tensor, index: Tensor, weight: Tensor, d: Tensor) -> Tensor:
    """``sum_k c_k Y_k(d)`` with coefficients ``sh [N, 3*K]`` mixed over the pixels' probes; ``[p, 3]``.
    ``d [p, 3]``, or ``[p, T, 3]`` for the mean over T directions (the basis is linear)."""
    c = _mix(sh, index, weight)  # [p, 3*K]
    y = prefilter.sh_basis(d)  # [p, K] or [p, T, K]
    y = y.mean(1) if y.dim() == 3 else y
    return torch.bmm(c.reshape(len(y), 3, -1), y[:, :, None])[..., 0]


def _lobe_shape(nv: Tensor, rough: Tensor, f0: Tensor) -> Tensor:
    """``[p, 3]`` (f, d, alpha) of :func:`phyir.shading.prefilter.lobe_shape_table`, linear in F0 between
    its tables at :data:`phyir.shading.prefilter.LOBE_SHAPE_F0` (F0: the mean over channels)."""
    both = prefilter.lookup_table(prefilter.lobe_shape_tables(device=nv.device, dtype=nv.dtype), nv, rough)
    lo, hi = prefilter.LOBE_SHAPE_F0
    t = ((f0.mean(-1, keepdim=True) - lo) / (hi - lo)).clamp(0, 1)
    return torch.lerp(both[:, :3], both[:, 3:], t)


def _lobe_taps(n: Tensor, v: Tensor, f: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
    """The split sum's two look-up directions: the lobe's mean direction ``normalize(lerp(n, r, f))``
    (r the mirror direction) moved by the tangent offsets ``+-d`` along the lobe's axis in the plane
    of n and v (:func:`phyir.shading.prefilter.lobe_shape_table`; ``f, d [p]``)."""
    mu = F.normalize(torch.lerp(n, reflect(v, n), f[:, None]), dim=-1)
    axis = n - (n * mu).sum(-1, keepdim=True) * mu  # zero at n.v = 1 or R = 1, where d = 0
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp(min=1e-4)
    step = d[:, None] * axis
    return F.normalize(mu + step, dim=-1), F.normalize(mu - step, dim=-1)


def _lookup(table: Tensor, h: int, w: int, index: Tensor, weight: Tensor, uv: tuple[Tensor, Tensor],
            scale: Tensor, planes: bool = False) -> Tensor:
    """``scale x`` the mean of bilinear look-ups ``[p, 3]`` at ``uv`` (:func:`_unit_uv`, ``[p, T]``
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
        return _mix(table.reshape(-1, 3), idx, wgt)
    if torch.is_grad_enabled() and table.requires_grad:  # one bag per channel plane
        flat = table.reshape(-1, 1)
        return torch.cat([_mix(flat, idx + c * (h * w), wgt) for c in range(3)], 1)
    # row i of this (overlapping) view holds (i, i + h w, i + 2 h w): a texel's three channel planes
    return _mix(table.reshape(-1).as_strided((table.numel() - 2 * h * w, 3), (1, h * w)), idx, wgt)


def _level_radiance(pf: prefilter.Prefiltered, probes: Tensor, sh: Tensor | None, level: int, index: Tensor,
                    weight: Tensor, taps: Tensor, uv: tuple[Tensor, Tensor], scale: Tensor) -> Tensor:
    """``scale x`` the mean radiance ``[p, 3]`` of prefiltered level ``level`` at the look-up
    directions ``taps [p, T, 3]`` (``uv`` their :func:`_unit_uv`) of the pixels' probe mixtures
    ``index/weight``: the probes themselves, a map, or the SH irradiance (``sh [N, 3*K]``)."""
    kind, hl, wl = pf.plan[level]
    if kind == "sh":
        return scale[:, None] * _sh_radiance(sh, index, weight, taps)
    if kind == "probe":
        return _lookup(probes, hl, wl, index, weight, uv, scale, planes=True)
    return _lookup(pf.maps[level], hl, wl, index, weight, uv, scale)


def _shade_prefiltered(px: _Pixels, light: _Lighting) -> tuple[Tensor, Tensor]:
    P = px.n.shape[0]
    dev, dt = px.n.device, px.n.dtype
    idx = (~px.skip).nonzero()[:, 0]
    if idx.numel() == 0:  # nothing to shade (all invalid, back-facing or emissive)
        return _assemble(P, [], [], [], dev, dt)
    sel = (lambda t: t) if idx.numel() == P else (lambda t: _select(t, idx))  # noqa: E731
    n, v, rough, base, metal = (sel(t) for t in (px.n, px.v, px.rough, px.base, px.metal))
    index, weight = sel(light.index), sel(light.weight)
    alphas = prefilter.PREFILTER_ALPHAS
    nv = (n * v).sum(-1)
    f0 = f0_from_material(base, metal)
    shape = _lobe_shape(nv, rough[:, 0], f0)
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
    taps = torch.stack(_lobe_taps(n, v, shape[:, 0], shape[:, 1]), 1)  # [p, 2, 3]
    uv = _unit_uv(taps)  # one direction -> texel mapping for every level

    def look(level: int, rows: Tensor | None) -> Tensor:
        if rows is None:
            return _level_radiance(pf, light.probes, sh, level, index, weight, taps, uv, level_w[level])
        return _level_radiance(pf, light.probes, sh, level, index[rows], weight[rows], taps[rows],
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
    return _assemble(P, [idx], [diffuse], [spec], dev, dt)


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


def _flat(t: Tensor, B: int, C: int) -> Tensor:
    """``[B?, C|1, H, W]`` -> channels-last ``[B*H*W, C]``."""
    t = t.reshape(-1, *t.shape[-3:]) if t.dim() == 4 else t[None]
    return t.expand(B, C, *t.shape[-2:]).permute(0, 2, 3, 1).reshape(-1, C).contiguous()


def _unflat(t: Tensor, B: int, H: int, W: int, batched: bool) -> Tensor:
    out = t.reshape(B, H, W, -1).permute(0, 3, 1, 2)
    return out if batched else out[0]


def _pixels(normal: Tensor, view: Tensor, base_color: Tensor, roughness: Tensor, metallic: Tensor,
            B: int, extra_skip: Tensor | None, dt: torch.dtype) -> _Pixels:
    n = _flat(normal.to(dt), B, 3)
    v = F.normalize(_flat(view.to(dt), B, 3), dim=-1)
    base, rough, metal = (_flat(x.to(dt), B, c) for x, c in ((base_color, 3), (roughness, 1), (metallic, 1)))
    with torch.no_grad():
        norm = torch.linalg.vector_norm(n, dim=-1)
        finite = torch.isfinite(torch.cat((n, v, base, rough, metal), -1)).all(-1)
        skip = ~finite | (norm < 1e-6)
    n = F.normalize(torch.where(skip[:, None], 0.0, n), dim=-1)
    with torch.no_grad():
        skip = skip | ((n * v).sum(-1) <= 0)
        if extra_skip is not None:
            skip = skip | extra_skip
    clean = lambda x: torch.where(skip[:, None], 0.0, x)  # noqa: E731
    return _Pixels(clean(n), v, clean(base), clean(rough), clean(metal), skip, n.shape[0] // B)


def _shade(px: _Pixels, light: _Lighting, spp: int, method: str, seed: int, sampler: str,
           skips: frozenset[str]) -> tuple[Tensor, Tensor]:
    if method == "prefiltered":
        return _shade_prefiltered(px, light)
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
        px = _pixels(normal, view, base_color, roughness, metallic, B, None, dt)
        probes = env.to(dt).reshape(-1, *env.shape[-3:])
        if probes.shape[0] not in (1, B):
            raise InputError("env", f"batch {probes.shape[0]} doesn't match the pixels' batch {B}")
        index = torch.arange(B, device=probes.device) if probes.shape[0] == B else \
            torch.zeros(B, dtype=torch.long, device=probes.device)
        index = index.repeat_interleave(H * W)[:, None]
        light = _Lighting(probes, index, torch.ones(index.shape, device=probes.device, dtype=dt))
        d, s = _shade(px, light, spp, method, seed, sampler, _skip_set(skips))
    d, s = _unflat(d, B, H, W, batched), _unflat(s, B, H, W, batched)
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
def _view_dirs(H: int, W: int, dev: torch.device, dt: torch.dtype) -> Tensor:
    return -pano.directions(H, W, dev, dt)


@lru_cache(maxsize=8)
def _probe_weights_cached(H: int, W: int, Hp: int, Wp: int, dev: torch.device,
                          dt: torch.dtype) -> tuple[Tensor, Tensor]:
    return probe_weights(H, W, Hp, Wp, dev, dt)


def _scene_inputs(scene: PanoScene, sk: frozenset[str]):
    """Flat pixels, lighting and emissive mask of a scene (inside the caller's autocast guard)."""
    for name in ("normal", "albedo", "roughness", "metallic", "probes"):
        if getattr(scene, name) is None:
            raise SceneError(f"{name}: render_scene needs it (got None)")
    H, W = scene.size
    B = scene.image.shape[0] if scene.batched else 1
    Hp, Wp = scene.probe_grid  # type: ignore[misc]
    dev = scene.normal.device
    dt = _compute_dtype(scene.normal, scene.albedo, scene.roughness, scene.metallic, scene.probes)
    view = _view_dirs(H, W, dev, dt)
    extra = torch.zeros(B * H * W, dtype=torch.bool, device=dev)
    emissive = None
    if "emission" in scene.masks and "emissive" in sk:
        emissive = _flat(scene.masks["emission"], B, 1)[:, 0] > 0.5
        extra |= emissive
    if "invalid" in scene.masks:
        extra |= _flat(scene.masks["invalid"], B, 1)[:, 0] > 0.5
    if scene.depth is not None:
        dep = _flat(scene.depth, B, 1)[:, 0]
        extra |= ~(torch.isfinite(dep) & (dep > 0))
    px = _pixels(scene.normal, view, scene.albedo, scene.roughness, scene.metallic, B, extra, dt)
    probes = scene.probes.to(dt).reshape(B * Hp * Wp, *scene.probes.shape[-3:])
    pidx, pw = _probe_weights_cached(H, W, Hp, Wp, dev, dt)
    index = (pidx[None] + (torch.arange(B, device=dev) * (Hp * Wp))[:, None, None]).reshape(-1, 4)
    return px, _Lighting(probes, index, pw.repeat(B, 1)), emissive, dt


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
        px, light, emissive, dt = _scene_inputs(scene, sk)
        d, s = _shade(px, light, spp, method, seed, sampler, sk)
        img = d + s
        if emissive is not None:
            img = torch.where(emissive[:, None], _flat(scene.image.to(dt), B, 3), img)
    out = {"diffuse": d, "specular": s, "image": img}
    return {k: _unflat(t, B, H, W, scene.batched) for k, t in out.items()}


def pixel_classes(scene: PanoScene, skips: bool | Iterable[str] = True) -> dict[str, Tensor]:
    """Flat pixel indices (into ``B*H*W``) of each Monte Carlo path, for the skip measurements.

    ``skipped`` (invalid, back-facing, emissive), ``std`` (full MIS), ``rough`` (no GGX samples),
    ``mirror`` (one reflected look-up; ``mirror_d`` of them also sample the diffuse lobe).
    """
    sk = _skip_set(skips)
    with torch.no_grad(), torch.autocast(scene.image.device.type, enabled=False):
        px, light, _, _ = _scene_inputs(scene, sk)
        classes = _classify(px, light, sk, "importance")
    return {"skipped": px.skip.nonzero()[:, 0], **classes}
