"""The split-sum fast path: tables of this BRDF, probes prefiltered per roughness level, SH irradiance.

Specular ≈ PF(l, alpha) · (F0 A + B): ``PF`` is the probe convolved with the GGX lobe under the
n = v = r assumption (Karis 2013: kernel D(h) (r.l) over directions l, normalised to preserve
constants), interpolated linearly in alpha between the levels of :data:`PREFILTER_ALPHAS`.  Karis
looks it up in the mirror direction with the surface's alpha; here the look-up follows the shape
of the actual lobe f_s cos at (n.v, R, F0) (:func:`lobe_shape_table`): the mean of two look-ups
either side of the lobe's mean direction, along its axis in the plane of n and v, each with the
alpha of the kernel as wide as the lobe across that plane — the lobe's first and second moments,
which the n = v = r kernel gets wrong at grazing views (off-specular peak, stretched lobe).
``(A, B)`` is the DFG table of *this* BRDF (UE4 Fresnel,
Schlick-GGX G with k = (R+1)^2/8, from :mod:`phyir.shading.brdf`).  Diffuse = B (1-M) · I(n), with ``I``
the cosine-weighted mean radiance (irradiance / pi) from real spherical harmonics up to band 4
(0.5% from converged Monte Carlo on the benchmark scenes, against 1.2% with the usual band 2).
At alpha = 1 GGX's D is constant, so the prefiltered lobe *is* the cosine lobe: the last level
reuses the SH irradiance.

Prefiltering is linear: every level and the SH projection are rows of one matrix, built once per
probe size from a 4x4 supersampled quadrature of the *bilinearly interpolated* probe (the radiance
the Monte Carlo path integrates; level rows sum to one, so constants stay constant), and applied to
all probes with one matmul whose output is already in the (texel, probe, channel) layout the
renderer gathers from.  The cost is proportional to the number of rows, so levels are as coarse as
the lobe allows (:func:`level_size`).

Tables are indexed ``table[c, i, j]`` at roughness R = (i+0.5)/n (rows) and n.v = (j+0.5)/n
(columns), i.e. texel centres, so a GL texture sampled linearly at (n.v, R) with clamp-to-edge
matches :func:`lookup_table`.
"""

from __future__ import annotations

import math
import os
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.shading.brdf import alpha_from_roughness, fresnel_ue4, ggx_d, visibility
from phyir.shading.sampling import ggx_half_vector, hammersley

DFG_SIZE = 32
DFG_SAMPLES = 4096
# alpha of each prefiltered level: 0 is the probe itself, 1 the SH irradiance (D is uniform there)
PREFILTER_ALPHAS = (0.0, 0.3, 0.6, 1.0)
SUPERSAMPLE = 4
# Precision of the level maps' matmul: "auto" takes bfloat16 (float32 accumulation) for float32
# probes on CPUs with native bfloat16 matmul (AVX512-BF16 / AMX) when the product has at least
# BF16_MIN_MACS multiply-adds: the prefiltered render 1.5-1.75x faster, same errors to four digits
# (docs/rendering.md, "Mixed precision"); "float32" keeps the probes' dtype.  The SH rows stay in the
# probes' dtype: high bands are small differences of large sums, which bfloat16 inputs would swamp.
# "bfloat16" takes it whatever the CPU (emulated where not native: slower, the same numbers). The
# environment variable PHYIR_LEVEL_PRECISION sets it for a process (the test suite is run with each).
LEVEL_PRECISION = os.environ.get("PHYIR_LEVEL_PRECISION", "auto")
LEVEL_PRECISIONS = ("auto", "float32", "bfloat16")
BF16_MIN_MACS = 1 << 26
# a level is halved while its texels stay below LEVEL_TEXELS_PER_ALPHA lobe widths (alpha radians);
# measured on the benchmark scenes: 2 costs +0.2% specular error over full-resolution levels
LEVEL_TEXELS_PER_ALPHA = 2.0
MIN_LEVEL_HEIGHT = 4
SH_LMAX = 4
# the lobe-shape tables' Fresnel F0: dielectric and metal (the renderer interpolates in F0)
LOBE_SHAPE_F0 = (0.04, 1.0)
# Funk-Hecke coefficients of the clamped cosine per band, divided by pi (irradiance / pi)
_COSINE_BANDS = (1.0, 2.0 / 3.0, 0.25, 0.0, -1.0 / 24.0)

# ---------------------------------------------------------------------------------------------
# tables over (n.v, R)


def _grid(size: int) -> Tensor:
    return (torch.arange(size, dtype=torch.float64) + 0.5) / size


def _lobe_samples(pts: Tensor, nv: Tensor, rough: float) -> tuple[Tensor, Tensor, Tensor]:
    """GGX half-vector samples ``pts [N, 2]`` of roughness ``rough`` reflected about views at
    ``nv [S]`` (n = z, v in the xz plane): directions ``l [N, S, 3]``, ``v.h [N, S]`` and the
    weight f_s cos / pdf without Fresnel, Vis 4 (v.h) (n.l) / (n.h) (D cancels), zero below the
    horizon.  What the tables over (R, n.v) integrate."""
    r = torch.tensor(rough, dtype=torch.float64)
    v = torch.stack((torch.sqrt(1 - nv * nv), torch.zeros_like(nv), nv), -1)  # [S, 3]
    h = ggx_half_vector(pts, alpha_from_roughness(r))[:, None]  # [N, 1, 3]
    vh = (h * v).sum(-1)  # [N, S]
    l = 2 * vh[..., None] * h - v
    nl = l[..., 2]
    w = torch.where(nl > 0, visibility(nl, nv, r) * 4 * vh * nl / h[..., 2], torch.zeros_like(nl))
    return l, vh, w


@lru_cache(maxsize=8)
def _dfg_cpu(size: int, samples: int) -> Tensor:
    pts = hammersley(samples, 2, dtype=torch.float64)  # [N, 2]
    out = torch.empty(2, size, size, dtype=torch.float64)
    for i, r in enumerate(_grid(size).tolist()):
        _, vh, w = _lobe_samples(pts, _grid(size), r)
        fc = fresnel_ue4(vh, torch.zeros_like(vh))
        out[0, i] = ((1 - fc) * w).mean(0)
        out[1, i] = (fc * w).mean(0)
    return out


def dfg_table(size: int = DFG_SIZE, samples: int = DFG_SAMPLES, device=None,
              dtype=torch.float32) -> Tensor:
    """``[2, size, size]`` (A, B) with ∫ f_s (n.l) dl = F0 A + B for this BRDF (see module doc)."""
    return _dfg_cpu(size, samples).to(device=device, dtype=dtype)


@lru_cache(maxsize=8)
def _spec_peak_cpu(size: int) -> Tensor:
    # max over l of D Vis (1 - Fc) and D Vis Fc: f_s <= F0 T0 + T1 for every l
    th = (torch.arange(96, dtype=torch.float64) + 0.5) * (math.pi / 2 / 96)
    ph = torch.linspace(0, math.pi, 97, dtype=torch.float64)
    th, ph = torch.meshgrid(th, ph, indexing="ij")
    ls = torch.stack((th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()), -1).reshape(-1, 3)
    out = torch.empty(2, size, size, dtype=torch.float64)
    for j, nv in enumerate(_grid(size).tolist()):
        v = torch.tensor([math.sqrt(1 - nv * nv), 0.0, nv], dtype=torch.float64)
        mirror = torch.tensor([[-v[0], 0.0, nv]], dtype=torch.float64)
        l = torch.cat((ls, mirror))
        h = l + v
        h = h / h.norm(dim=-1, keepdim=True)
        nl, nh, vh = l[:, 2], h[:, 2], h @ v
        for i, r in enumerate(_grid(size).tolist()):
            rough = torch.tensor(r, dtype=torch.float64)
            dv = ggx_d(nh, alpha_from_roughness(rough)) * visibility(nl, torch.tensor(nv), rough)
            fc = fresnel_ue4(vh, torch.zeros_like(vh))
            out[0, i, j] = (dv * (1 - fc)).max()
            out[1, i, j] = (dv * fc).max()
    return out


def specular_peak_table(size: int = DFG_SIZE, device=None, dtype=torch.float32) -> Tensor:
    """``[2, size, size]`` (T0, T1) with f_s(v, l) <= F0 T0 + T1 for all l (max over a fine grid).

    Since ∫ f_s L cos <= max_l f_s · ∫ L cos and the diffuse lobe is B(1-M)/pi · ∫ L cos, the ratio
    specular / diffuse of a pixel is at most pi (F0 T0 + T1) / (B (1 - M)) under any lighting.
    """
    return _spec_peak_cpu(size).to(device=device, dtype=dtype)


def _rms_tangent(w: Tensor, x: Tensor) -> Tensor:
    """Root mean square of the tangent coordinate ``x`` under weights ``w`` (over dim 0)."""
    return ((w * x * x).sum(0) / w.sum(0)).sqrt()


@lru_cache(maxsize=2)
def _kernel_widths(samples: int) -> tuple[Tensor, Tensor]:
    """Alphas and the RMS tangent coordinate of their prefilter kernels (:func:`lobe_kernel`)."""
    pts = hammersley(samples, 2, dtype=torch.float64)
    alphas = torch.cat((torch.tensor([1e-4]), torch.logspace(-3, 0, 97))).double()
    h = ggx_half_vector(pts[:, None], alphas[None])  # [N, A, 3], ∝ D(h) (n.h)
    l = 2 * h[..., 2:] * h - h.new_tensor([0.0, 0.0, 1.0])
    return alphas, _rms_tangent((4 * l[..., 2]).clamp(min=0), l[..., 0])  # n = v = r: kernel/pdf = 4 r.l


def _kernel_alpha(width: Tensor, samples: int) -> Tensor:
    """The alpha whose prefilter kernel has RMS tangent coordinate ``width`` (interpolated; clamped
    to alpha in [1e-4, 1])."""
    alphas, widths = _kernel_widths(samples)
    k = torch.searchsorted(widths, width.contiguous()).clamp(1, len(widths) - 1)
    x = ((width - widths[k - 1]) / (widths[k] - widths[k - 1])).clamp(0, 1)
    return torch.lerp(alphas[k - 1], alphas[k], x)


@lru_cache(maxsize=4)
def _lobe_shape_cpu(size: int, samples: int, f0: float) -> Tensor:
    pts = hammersley(samples, 2, dtype=torch.float64)
    th_r = torch.acos(_grid(size))
    out = torch.empty(3, size, size, dtype=torch.float64)
    for i, r in enumerate(_grid(size).tolist()):
        l, vh, w = _lobe_samples(pts, _grid(size), r)  # [N, S, 3], [N, S], [N, S]
        w = w * fresnel_ue4(vh, torch.full_like(vh, f0))  # f_s cos / pdf
        m = (w[..., None] * l).sum(0)  # [S, 3]
        th = torch.atan2(-m[:, 0], m[:, 2])  # the mean direction's angle from n, toward r
        # normalize(lerp(n, r, f)) points at th: tan th = f sin th_r / (1 - f + f cos th_r)
        t = torch.tan(th)
        f = torch.where(th_r > 1e-9, t / (torch.sin(th_r) + t * (1 - torch.cos(th_r))), 1.0)
        e1 = torch.stack((torch.cos(th), torch.zeros_like(th), torch.sin(th)), -1)  # in-plane, ⊥ mean
        w1 = _rms_tangent(w, (l * e1).sum(-1))
        w2 = _rms_tangent(w, l[..., 1])
        # two taps at +-d along e1, each with the lobe's width across, match its width in the plane
        out[0, i], out[1, i] = f.clamp(0, 1), (w1 * w1 - w2 * w2).clamp(min=0).sqrt()
        out[2, i] = _kernel_alpha(w2, samples)
    return out


def lobe_shape_table(f0: float, size: int = DFG_SIZE, samples: int = DFG_SAMPLES, device=None,
                     dtype=torch.float32) -> Tensor:
    """``[3, size, size]`` (f, d, alpha): where the split sum looks up the specular lobe f_s cos of
    a surface with Fresnel F0 ``f0`` at (R, n.v) (rows, columns as in :func:`dfg_table`).

    The lobe's mean direction is ``normalize(lerp(n, r, f))`` (r the mirror direction); two
    look-ups at tangent offsets ``+-d`` from it along the lobe's axis in the plane of n and v, each
    in the level of ``alpha`` (the prefilter kernel as wide as the lobe across that plane), match the
    lobe's RMS widths in and across the plane.  Moments by GGX importance sampling, as the DFG table.
    """
    return _lobe_shape_cpu(size, samples, f0).to(device=device, dtype=dtype)


@lru_cache(maxsize=4)
def _lobe_shapes_cpu(size: int, samples: int) -> Tensor:
    return torch.cat([_lobe_shape_cpu(size, samples, f0) for f0 in LOBE_SHAPE_F0])


def lobe_shape_tables(size: int = DFG_SIZE, samples: int = DFG_SAMPLES, device=None,
                      dtype=torch.float32) -> Tensor:
    """``[6, size, size]``: :func:`lobe_shape_table` at F0 = each of :data:`LOBE_SHAPE_F0`, stacked."""
    return _lobe_shapes_cpu(size, samples).to(device=device, dtype=dtype)


def lookup_table(table: Tensor, n_dot_v: Tensor, roughness: Tensor) -> Tensor:
    """Bilinear look-up (clamped at the edges) of ``table [C, n, n]``; returns ``[*S, C]``.

    ``n_dot_v`` and ``roughness`` broadcast to ``S``; differentiable in both.
    """
    nv, r = torch.broadcast_tensors(n_dot_v, roughness)
    # texel centres at (i + 1/2) / n, clamped to the edge texels: exactly grid_sample's
    # align_corners=False with border padding (one fused op, ~7x faster than explicit taps)
    grid = (torch.stack((nv, r), -1).to(table.dtype) * 2 - 1).reshape(1, 1, -1, 2)
    out = F.grid_sample(table[None], grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[0, :, 0].T.reshape(*nv.shape, table.shape[0])


def specular_albedo(n_dot_v: Tensor, roughness: Tensor, f0: Tensor, table: Tensor | None = None) -> Tensor:
    """Directional albedo of the specular lobe, F0 A + B (``f0`` broadcasts, e.g. ``[..., 3]``)."""
    table = dfg_table(device=f0.device, dtype=f0.dtype) if table is None else table
    ab = lookup_table(table, n_dot_v, roughness)
    return f0 * ab[..., :1] + ab[..., 1:]


# ---------------------------------------------------------------------------------------------
# spherical harmonics


def sh_basis(d: Tensor, lmax: int = SH_LMAX, dim: int = -1) -> Tensor:
    """Real orthonormal spherical harmonics up to band ``lmax`` <= 4 of unit ``d``; ``[..., (lmax+1)^2]``.

    Bands in order l = 0..lmax, m = -l..l (the usual real-SH polynomials in x, y, z).
    """
    if not 0 <= lmax <= 4:
        raise ValueError(f"sh_basis: lmax {lmax} not in 0..4")
    x, y, z = d.unbind(dim)
    xx, yy, zz = x * x, y * y, z * z
    out = [torch.full_like(x, 0.28209479177387814)]
    if lmax >= 1:
        c = 0.4886025119029199
        out += [c * y, c * z, c * x]
    if lmax >= 2:
        out += [1.0925484305920792 * x * y, 1.0925484305920792 * y * z, 0.31539156525252005 * (3 * zz - 1),
                1.0925484305920792 * x * z, 0.5462742152960396 * (xx - yy)]
    if lmax >= 3:
        out += [0.5900435899266435 * y * (3 * xx - yy), 2.890611442640554 * x * y * z,
                0.4570457994644658 * y * (5 * zz - 1), 0.3731763325901154 * z * (5 * zz - 3),
                0.4570457994644658 * x * (5 * zz - 1), 1.445305721320277 * z * (xx - yy),
                0.5900435899266435 * x * (xx - 3 * yy)]
    if lmax >= 4:
        out += [2.5033429417967046 * x * y * (xx - yy), 1.7701307697799304 * y * z * (3 * xx - yy),
                0.9461746957575601 * x * y * (7 * zz - 1), 0.6690465435572892 * y * z * (7 * zz - 3),
                0.10578554691520431 * (35 * zz * zz - 30 * zz + 3), 0.6690465435572892 * x * z * (7 * zz - 3),
                0.47308734787878004 * (xx - yy) * (7 * zz - 1), 1.7701307697799304 * x * z * (xx - 3 * yy),
                0.6258357354491761 * (xx * (xx - 3 * yy) - yy * (3 * xx - yy))]
    return torch.stack(out, -1 if dim == -1 else dim)


def _cosine_band_weights(lmax: int) -> Tensor:
    return torch.tensor([_COSINE_BANDS[l] for l in range(lmax + 1) for _ in range(2 * l + 1)],
                        dtype=torch.float64)


# ---------------------------------------------------------------------------------------------
# prefiltering operators


def level_size(h: int, w: int, alpha: float) -> tuple[int, int]:
    """Resolution of the level of lobe width ``alpha`` for ``h x w`` probes (halvings of h x w).

    Halved while texels (pi / rows radians) stay within ``LEVEL_TEXELS_PER_ALPHA * alpha`` and the
    level keeps at least :data:`MIN_LEVEL_HEIGHT` rows; ``alpha <= 0`` keeps the full size.
    """
    if alpha <= 0:
        return h, w
    want = max(math.pi / (LEVEL_TEXELS_PER_ALPHA * alpha), MIN_LEVEL_HEIGHT)
    f = 1
    while h / (2 * f) >= want and h % (2 * f) == 0 and w % (2 * f) == 0:
        f *= 2
    return h // f, w // f


@lru_cache(maxsize=8)
def fine_grid(h: int, w: int) -> tuple[Tensor, Tensor]:
    """Fine quadrature directions ``[F, 3]`` and their weights mapped onto probe texels ``[F, h*w]``.

    Row f of the second holds solid angle x bilinear weights: integrating the bilinear interpolant
    of a probe x against a kernel k is ``k @ (weights @ x)``.
    """
    s = SUPERSAMPLE
    hf, wf = h * s, w * s
    d = pano.directions(hf, wf, dtype=torch.float64).reshape(3, -1).T
    omega = pano.solid_angles(hf, wf, dtype=torch.float64).reshape(-1, 1)
    jf = (torch.arange(wf, dtype=torch.float64) + 0.5) / s
    i_f = (torch.arange(hf, dtype=torch.float64) + 0.5) / s
    vv, uu = torch.meshgrid(i_f, jf, indexing="ij")
    idx, wgt = pano.bilinear_taps(uu.reshape(-1), vv.reshape(-1), h, w)
    to_probe = torch.zeros(hf * wf, h * w, dtype=torch.float64).scatter_add_(1, idx, wgt)
    return d, omega * to_probe


def lobe_kernel(cos: Tensor, alpha: Tensor) -> Tensor:
    """The prefiltering kernel D(h) (r.l) (unnormalised) of a direction l at cosine ``cos`` = r.l from
    the lobe axis r, under n = v = r (so n.h = sqrt((1 + cos) / 2)); zero behind the axis."""
    return ggx_d(torch.sqrt(((1 + cos) / 2).clamp(min=0)), alpha) * cos.clamp(min=0)


@lru_cache(maxsize=32)
def _level_operator_cpu(h: int, w: int, hl: int, wl: int, alpha: float) -> Tensor:
    """``[hl*wl, h*w]``: the GGX lobe of ``alpha`` (n = v = r) at the centres of an ``hl x wl`` level."""
    d, weights = fine_grid(h, w)
    r = pano.directions(hl, wl, dtype=torch.float64).reshape(3, -1).T
    op = lobe_kernel(r @ d.T, torch.tensor(alpha, dtype=torch.float64)) @ weights
    return op / op.sum(-1, keepdim=True)


@lru_cache(maxsize=8)
def _sh_operator_cpu(h: int, w: int) -> Tensor:
    """``[K, h*w]``: SH coefficients of irradiance / pi (cosine band weights folded in)."""
    d, weights = fine_grid(h, w)
    y = sh_basis(d)
    op = (y.T @ weights) * _cosine_band_weights(SH_LMAX)[:, None]
    # normalise so that a constant probe gives exactly that constant
    return op / (op[0].sum() * 0.28209479177387814)


def _plan(h: int, w: int, alphas: tuple[float, ...]) -> list[tuple[str, int, int]]:
    """Per level: ("probe"|"map"|"sh", hl, wl)."""
    if not alphas or alphas[0] != 0 or any(b <= a for a, b in zip(alphas, alphas[1:])) or alphas[-1] > 1:
        raise ValueError(f"alphas must start at 0, increase and end at most at 1: {alphas}")
    out = []
    for a in alphas:
        if a <= 0:
            out.append(("probe", h, w))
        elif a >= 1:
            out.append(("sh", 0, 0))
        else:
            out.append(("map", *level_size(h, w, a)))
    return out


def _takes_map(plan: list[tuple[str, int, int]], need: tuple[int, ...]) -> list[bool]:
    """Per level of ``plan``: whether it is a map level in ``need`` (a block of operator rows)."""
    return [kind == "map" and i in need for i, (kind, _, _) in enumerate(plan)]


def map_rows(h: int, w: int, alphas: tuple[float, ...] = PREFILTER_ALPHAS,
             need: tuple[int, ...] | None = None) -> int:
    """Rows (level texels) of the map levels ``need`` (default all) for ``h x w`` probes: with the
    probes' size, the multiply-adds of the maps' matmul per probe channel."""
    plan = _plan(h, w, alphas)
    need = tuple(range(len(alphas))) if need is None else need
    return sum(hl * wl for t, (_, hl, wl) in zip(_takes_map(plan, need), plan) if t)


@lru_cache(maxsize=16)
def _stacked_operator_cpu(h: int, w: int, alphas: tuple[float, ...], need: tuple[int, ...]) -> Tensor:
    """Rows of the needed map levels, then the SH projection (if level "sh" or -1 is needed)."""
    plan = _plan(h, w, alphas)
    rows = [_level_operator_cpu(h, w, hl, wl, a) for i, ((kind, hl, wl), a) in enumerate(zip(plan, alphas))
            if kind == "map" and i in need]
    if -1 in need or any(plan[i][0] == "sh" for i in need):
        rows.append(_sh_operator_cpu(h, w))
    return torch.cat(rows) if rows else torch.zeros(0, h * w, dtype=torch.float64)


@lru_cache(maxsize=1)
def cpu_has_native_bf16() -> bool:
    """Whether this CPU multiplies bfloat16 natively (x86 ``avx512_bf16`` or ``amx_bf16``, from
    /proc/cpuinfo; False where that can't be read)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return bool(flags & {"avx512_bf16", "amx_bf16"})
    except OSError:
        pass
    return False


def level_matmul_dtype(env: Tensor, macs: int) -> torch.dtype:
    """dtype of the level maps' matmul for probes ``env`` and a product of ``macs`` multiply-adds
    (see :data:`LEVEL_PRECISION`)."""
    if LEVEL_PRECISION not in LEVEL_PRECISIONS:
        raise ValueError(f"LEVEL_PRECISION (PHYIR_LEVEL_PRECISION) must be one of {LEVEL_PRECISIONS}, "
                         f"got {LEVEL_PRECISION!r}")
    native = LEVEL_PRECISION == "bfloat16" or (LEVEL_PRECISION == "auto" and cpu_has_native_bf16())
    if native and env.dtype == torch.float32 and env.device.type == "cpu" and macs >= BF16_MIN_MACS:
        return torch.bfloat16
    return env.dtype


class Prefiltered:
    """Prefiltered probes ``env [..., 3, h, w]`` in the layouts the renderer gathers from.

    ``maps[i]`` is ``[hl*wl, N, 3]`` (texel, probe, channel) for a level of ``plan[i]``, ``None``
    for level 0 (the probes), for an alpha-1 level (use the SH) and for levels not in ``need``.
    ``sh`` is ``[K, N, 3]`` (or ``None`` if not needed): the irradiance / pi at direction n is
    ``sum_k sh[k] Y_k(n)``.  ``need`` lists level indices, -1 for the irradiance; default all.
    Built with one matmul (two where the maps take bfloat16: :func:`level_matmul_dtype`).
    """

    def __init__(self, env: Tensor, alphas: tuple[float, ...] = PREFILTER_ALPHAS,
                 need: tuple[int, ...] | None = None):
        h, w = env.shape[-2:]
        self.lead = env.shape[:-3]
        self.alphas = tuple(alphas)
        self.plan = _plan(h, w, self.alphas)
        self.need = tuple(range(-1, len(alphas))) if need is None else tuple(sorted(set(need)))
        op = _stacked_operator_cpu(h, w, self.alphas, self.need)
        x = env.reshape(-1, h * w)
        N = x.shape[0] // 3
        take = _takes_map(self.plan, self.need)
        n_map = map_rows(h, w, self.alphas, self.need)
        low = level_matmul_dtype(env, n_map * x.numel())
        if low == env.dtype:  # one matmul, its rows already (texel, probe, channel)
            out = (op.to(device=env.device, dtype=env.dtype) @ x.T).reshape(op.shape[0], N, 3)
            maps, sh = out[:n_map], out[n_map:]
        else:
            maps = (op[:n_map].to(device=env.device, dtype=low) @ x.to(low).T).to(env.dtype)
            maps = maps.reshape(n_map, N, 3)
            sh = (op[n_map:].to(device=env.device, dtype=env.dtype) @ x.T).reshape(-1, N, 3)
        self.maps: list[Tensor | None] = []
        o = 0
        for t, (_, hl, wl) in zip(take, self.plan):
            self.maps.append(maps[o:o + hl * wl] if t else None)
            o += hl * wl if t else 0
        self.sh = sh if sh.shape[0] else None

    def has(self, need: tuple[int, ...]) -> bool:
        return set(need) <= set(self.need)

    def image(self, i: int) -> Tensor:
        """Level ``i`` as an equirect image ``[*lead, 3, hl, wl]`` (an SH level: a 4 x 8 map)."""
        kind, hl, wl = self.plan[i]
        if kind == "sh":
            return self.irradiance_image(MIN_LEVEL_HEIGHT, 2 * MIN_LEVEL_HEIGHT)
        t = self.maps[i]
        assert t is not None, "level 0 is the probe itself"
        return t.permute(1, 2, 0).reshape(*self.lead, 3, hl, wl)

    def irradiance_image(self, hl: int, wl: int) -> Tensor:
        """The SH irradiance / pi evaluated at the texel centres of an ``hl x wl`` map."""
        assert self.sh is not None, "irradiance not computed (need -1)"
        y = sh_basis(pano.directions(hl, wl, self.sh.device, self.sh.dtype).permute(1, 2, 0))  # [hl,wl,K]
        img = torch.einsum("hwk,knc->nchw", y, self.sh)
        return img.reshape(*self.lead, 3, hl, wl)


def prefilter_probe(env: Tensor, alphas: tuple[float, ...] = PREFILTER_ALPHAS) -> list[Tensor]:
    """GGX-prefiltered levels of equirect probes ``env [..., 3, h, w]``, one per alpha (for textures).

    Level i is ``[..., 3, h_i, w_i]`` (:func:`level_size`); alpha 0 returns ``env`` itself and an
    alpha-1 level the irradiance / pi map at 4 x 8.  Differentiable in ``env``.
    """
    pf = Prefiltered(env, alphas)
    return [env if kind == "probe" else pf.image(i) for i, (kind, _, _) in enumerate(pf.plan)]


def irradiance_sh(env: Tensor) -> Tensor:
    """``[..., 3, K]`` SH coefficients (bands 0..4) of irradiance / pi of ``env [..., 3, h, w]``.

    Evaluate as ``sum_k c[k] * sh_basis(n)[k]`` (the viewer's shader does the same with 25 uniforms).
    """
    h, w = env.shape[-2:]
    op = _sh_operator_cpu(h, w).to(device=env.device, dtype=env.dtype)
    return env.reshape(*env.shape[:-2], h * w) @ op.T


def irradiance_map(env: Tensor, size: tuple[int, int] | None = None) -> Tensor:
    """Irradiance / pi of ``env [..., 3, h, w]`` as an equirect map (default: the probe's size)."""
    h, w = env.shape[-2:]
    hl, wl = size or (h, w)
    c = irradiance_sh(env)  # [..., 3, K]
    y = sh_basis(pano.directions(hl, wl, env.device, env.dtype).permute(1, 2, 0))  # [hl, wl, K]
    return torch.einsum("...ck,hwk->...chw", c, y)


def level_coords(roughness: Tensor, alphas: tuple[float, ...] = PREFILTER_ALPHAS) -> tuple[Tensor, Tensor]:
    """Level ``i0`` and weight ``t`` of level ``i0 + 1`` for linear interpolation in alpha."""
    return level_coords_alpha(alpha_from_roughness(roughness), alphas)


def level_coords_alpha(alpha: Tensor, alphas: tuple[float, ...] = PREFILTER_ALPHAS) -> tuple[Tensor, Tensor]:
    """:func:`level_coords` of lobe widths ``alpha``."""
    a = torch.tensor(alphas, device=alpha.device, dtype=alpha.dtype)
    i0 = (torch.searchsorted(a, alpha.detach().contiguous(), right=True) - 1).clamp(0, len(alphas) - 2)
    t = ((alpha - a[i0]) / (a[i0 + 1] - a[i0])).clamp(0, 1)
    return i0, t


# ---------------------------------------------------------------------------------------------
# cache: the last probe tensor seen (e.g. the viewer's or a benchmark's static probes)

_cache: dict[str, object] = {}


def _key(env: Tensor, alphas: tuple[float, ...]) -> tuple:
    # inference tensors (from torch.inference_mode, e.g. phyir.predict's probes) have no version
    # counter: a checksum stands in for it (~10 ms on a 64x128 grid, against ~40 ms of prefiltering)
    version = float(env.detach().double().sum()) if env.is_inference() else env._version
    return (env.data_ptr(), tuple(env.shape), env.stride(), env.dtype, env.device, version, alphas)


def prefiltered(env: Tensor, alphas: tuple[float, ...] = PREFILTER_ALPHAS,
                need: tuple[int, ...] | None = None) -> Prefiltered:
    """:class:`Prefiltered` levels ``need`` (default all) of ``env``, reused while the same
    (unmodified) memory is passed and the cached entry has every needed level.

    The cache holds one entry and a reference to its tensor (so its memory can't be reused under
    the same key).  Tensors that need gradients are never cached (each call builds its own graph).
    """
    if env.requires_grad and torch.is_grad_enabled():
        return Prefiltered(env, alphas, need)
    key = _key(env, alphas)
    value = _cache.get("value")
    if _cache.get("key") != key or not value.has(need if need is not None else tuple(range(-1, len(alphas)))):
        _cache.clear()
        _cache.update(key=key, env=env, value=Prefiltered(env, alphas, need))
    return _cache["value"]  # type: ignore[return-value]


def clear_cache(operators: bool = False) -> None:
    """Forget the cached :func:`prefiltered` levels (the next call prefilters again, e.g. to time it);
    ``operators`` also forgets the stacked prefiltering matrices, which depend on the level sizes
    (:data:`LEVEL_TEXELS_PER_ALPHA`) without being keyed by them."""
    _cache.clear()
    if operators:
        _stacked_operator_cpu.cache_clear()
