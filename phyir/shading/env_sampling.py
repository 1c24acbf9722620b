"""Environment importance sampling for :mod:`phyir.shading.render`: per pixel, a continuous density
∝ probe radiance x clamped cosine, bilinear between the probes' texel centres (:class:`EnvSampler`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.shading.probe_mixture import mix, unit_uv
from phyir.shading.sampling import sample_linear

ENV_FLOOR = 1e-3  # of a probe's mean luminance: keeps every direction above the horizon reachable
ENV_GRID_ROWS = 16  # probes with more rows are sampled from an area-downsampled luminance map
ENV_COLUMNS = 2  # nodes per texel along a row: finer steps of the cosine factor across the horizon


@dataclass
class EnvSampler:
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
    linear in u) with u2 (:func:`env_directions`).  Directions that land below the horizon (in
    cells straddling it) are mirrored about the tangent plane, so no sample is wasted and the
    density above the horizon is p(l) + p(mirror(l)) (:func:`env_pdf`).
    """

    lum: Tensor  # [N, h*w*k] luminance (+ floor) at the nodes
    node_dir: Tensor  # [h*w*k, 3]
    node_cos_lat: Tensor  # [h*w*k]
    row_v: Tensor  # [h+2]: v of the node rows, poles included (0, 0.5, 1.5, ..., h-0.5, h)
    h: int  # rows of the grid (texel rows)
    w: int  # texel columns; node column j sits at u = 0.5 + j / k
    k: int


@dataclass
class EnvTables:
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


def env_sampler(probes: Tensor) -> EnvSampler:
    """The :class:`EnvSampler` of probes ``[N, 3, h, w]``, built once per call (no gradients: pdfs are
    detached)."""
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
    return EnvSampler(lum, node_dir, cos_lat, row_v, h, w, k)


def env_tables(env: EnvSampler, n: Tensor, index: Tensor, weight: Tensor) -> EnvTables:
    """The density tables of pixels with normals ``n [p, 3]`` and probes ``index/weight [p, K]``."""
    h, wk = env.h, env.w * env.k
    p = n.shape[0]
    q = mix(env.lum, index, weight) * (n @ env.node_dir.T).clamp(min=0) * env.node_cos_lat
    q = q.reshape(p, h, wk)
    q = F.pad(q, (0, 0, 1, 1))  # the poles: zero solid angle per unit of v
    col = ((q + q.roll(-1, -1)) * 0.5).cumsum(-1)  # cell j spans nodes j and j + 1 (wrapping)
    rows = col[..., -1]
    height = env.row_v[1:] - env.row_v[:-1]
    row_cdf = ((rows[:, :-1] + rows[:, 1:]) * (0.5 * height)).cumsum(-1)
    return EnvTables(n, q.reshape(p, -1), row_cdf, col.reshape(p, -1))


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


def env_directions(env: EnvSampler, tab: EnvTables, u: Tensor) -> Tensor:
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


def _grid_density(env: EnvSampler, tab: EnvTables, u: Tensor, v: Tensor) -> Tensor:
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


def env_pdf(env: EnvSampler, tab: EnvTables, d: Tensor, uv: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Density ``[p, S, 1]`` in solid angle of :func:`env_directions` at unit directions ``d [p, S, 3]``
    (``uv``: their :func:`unit_uv`, when already known): p(d) + p(mirror(d)) above the horizon."""
    h, w = env.h, env.w
    n = tab.n[:, None]
    c = (d * n).sum(-1, keepdim=True)
    u, v = unit_uv(d) if uv is None else uv
    um, vm = unit_uv(d - 2 * c * n)
    dens = _grid_density(env, tab, u * w, v * h) + _grid_density(env, tab, um * w, vm * h)
    # per unit of (u, v): k x the interpolant; solid angle per unit of (u, v): cos(lat) 2 pi^2 / (h w)
    norm = tab.row_cdf[:, -1:] * (2 * math.pi**2 / (h * w * env.k))
    pdf = dens / norm.clamp(min=1e-30)
    return torch.where(c > 0, pdf[..., None], torch.zeros_like(c))
