"""Monte Carlo sampling helpers shared by the rendering layer and the path tracer.

* Point sets in [0,1)^d: scrambled Sobol, Hammersley, independent uniform; the same point set is
  reused by every pixel after a seeded per-pixel Cranley-Patterson rotation (``rotate``), which
  keeps the set's stratification while decorrelating pixels.
* Direction sampling in a local frame whose z axis is the normal (``local_to_world`` maps it out):
  cosine-weighted and uniform hemisphere, uniform sphere, GGX half vectors; each with its pdf in
  solid angle.
* Orthonormal frames from a normal (Duff et al. 2017, branchless and continuous except at one
  point of measure zero), reflection, and the combination weights of multiple importance sampling.

Vector functions take the vector axis as ``dim`` (default last) and broadcast otherwise; all of them
run on any device and dtype.  pdfs are densities with respect to solid angle of the light direction.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
from torch import Tensor

from phyir.shading.brdf import ggx_d

POINT_SETS = ("sobol", "hammersley", "random")
_ONE_MINUS = 1.0 - 2.0**-24  # largest float32 below one: keeps u in [0,1) after rotation


# ---------------------------------------------------------------------------------------------
# point sets


def radical_inverse(i: Tensor, base: int) -> Tensor:
    """Van der Corput radical inverse of non-negative integers ``i`` in ``base`` (float64)."""
    i = i.to(torch.int64).clone()
    out = torch.zeros(i.shape, dtype=torch.float64, device=i.device)
    scale = 1.0 / base
    while bool((i > 0).any()):
        out += (i % base).double() * scale
        i = i // base
        scale /= base
    return out


_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19)


def hammersley(n: int, dim: int = 2, device=None, dtype=torch.float32) -> Tensor:
    """Hammersley set of ``n`` points in [0,1)^dim: ((i+0.5)/n, phi_2(i), phi_3(i), ...)."""
    if dim > len(_PRIMES) + 1:
        raise ValueError(f"hammersley: dim {dim} > {len(_PRIMES) + 1}")
    i = torch.arange(n, device=device)
    cols = [(i.double() + 0.5) / n] + [radical_inverse(i, p) for p in _PRIMES[: dim - 1]]
    return torch.stack(cols, dim=-1).to(dtype)


def sobol(n: int, dim: int = 2, seed: int = 0, device=None, dtype=torch.float32) -> Tensor:
    """First ``n`` points of a scrambled (random linear scramble + digital shift) Sobol sequence."""
    eng = torch.quasirandom.SobolEngine(dim, scramble=True, seed=seed)
    return eng.draw(n, dtype=torch.float64).to(device=device, dtype=dtype)


@lru_cache(maxsize=64)
def _point_set_cpu(kind: str, n: int, dim: int, seed: int) -> Tensor:
    if kind == "sobol":
        return sobol(n, dim, seed)
    if kind == "hammersley":
        return hammersley(n, dim)
    raise ValueError(f"unknown point set {kind!r}; expected one of {POINT_SETS}")


def point_set(kind: str, n: int, dim: int = 2, seed: int = 0, device=None,
              dtype=torch.float32) -> Tensor:
    """``n`` points in [0,1)^dim of a low-discrepancy ``kind`` ("sobol" or "hammersley"), cached."""
    return _point_set_cpu(kind, n, dim, seed).to(device=device, dtype=dtype)


def rotation_shifts(count: int, dim: int, seed: int, device=None, dtype=torch.float32) -> Tensor:
    """Seeded uniform shifts ``[count, dim]`` for per-pixel Cranley-Patterson rotation.

    Generated on the CPU so the same seed gives the same shifts on every device.
    """
    g = torch.Generator().manual_seed(int(seed))
    return torch.rand(count, dim, generator=g, dtype=torch.float64).to(device=device, dtype=dtype)


def rotate(points: Tensor, shift: Tensor) -> Tensor:
    """Cranley-Patterson rotation: ``frac(points + shift)``, broadcasting; stays in [0,1)."""
    return torch.remainder(points + shift, 1.0).clamp(max=_ONE_MINUS)


def pixel_samples(kind: str, n_pixels: int, n: int, dim: int = 2, seed: int = 0, device=None,
                  dtype=torch.float32, shifts: Tensor | None = None) -> Tensor:
    """``[n_pixels, n, dim]`` samples: one rotated low-discrepancy set per pixel, or iid uniform.

    ``kind`` is one of :data:`POINT_SETS`; ``shifts [n_pixels, dim]`` overrides the seeded shifts
    (e.g. a slice of a frame-wide table so that results don't depend on chunking).
    """
    if n == 0:
        return torch.zeros(n_pixels, 0, dim, device=device, dtype=dtype)
    if kind == "random":
        g = torch.Generator().manual_seed(int(seed))
        return torch.rand(n_pixels, n, dim, generator=g, dtype=torch.float64).to(device=device,
                                                                                  dtype=dtype)
    if shifts is None:
        shifts = rotation_shifts(n_pixels, dim, seed + 0x5EED, device, dtype)
    pts = point_set(kind, n, dim, seed, device, dtype)
    return rotate(pts[None], shifts[:, None, :].to(dtype))


# ---------------------------------------------------------------------------------------------
# frames


def _dot(a: Tensor, b: Tensor, dim: int) -> Tensor:
    return (a * b).sum(dim, keepdim=True)


def orthonormal_basis(n: Tensor, dim: int = -1) -> tuple[Tensor, Tensor]:
    """Tangent ``t`` and bitangent ``b`` with (t, b, n) right-handed, for unit ``n`` (Duff et al. 2017)."""
    x, y, z = n.unbind(dim)
    sign = torch.copysign(torch.ones_like(z), z)
    a = -1.0 / (sign + z)
    c = x * y * a
    t = torch.stack((1 + sign * x * x * a, sign * c, -sign * x), dim)
    b = torch.stack((c, sign + y * y * a, -y), dim)
    return t, b


def local_to_world(local: Tensor, n: Tensor, dim: int = -1) -> Tensor:
    """Map local directions (z along the normal) to world directions around unit normals ``n``."""
    t, b = orthonormal_basis(n, dim)
    x, y, z = local.unbind(dim)
    return x.unsqueeze(dim) * t + y.unsqueeze(dim) * b + z.unsqueeze(dim) * n


def world_to_local(d: Tensor, n: Tensor, dim: int = -1) -> Tensor:
    t, b = orthonormal_basis(n, dim)
    return torch.cat((_dot(d, t, dim), _dot(d, b, dim), _dot(d, n, dim)), dim)


def reflect(v: Tensor, h: Tensor, dim: int = -1) -> Tensor:
    """Mirror ``v`` about ``h``: 2 (v.h) h - v (both unit, pointing away from the surface)."""
    return 2 * _dot(v, h, dim) * h - v


# ---------------------------------------------------------------------------------------------
# directions (local frame, z = normal) and their pdfs


def _polar(cos_t: Tensor, sin_t: Tensor, phi: Tensor, dim: int) -> Tensor:
    return torch.stack((sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t), dim)


def cosine_hemisphere(u: Tensor, dim: int = -1) -> Tensor:
    """Cosine-weighted directions from ``u [..., 2]`` (along ``dim``); pdf = cos(theta) / pi."""
    u1, u2 = u.unbind(dim)
    r2 = u1
    cos_t = torch.sqrt((1 - r2).clamp(min=0))
    return _polar(cos_t, torch.sqrt(r2), 2 * math.pi * u2, dim)


def cosine_hemisphere_pdf(cos_theta: Tensor) -> Tensor:
    return cos_theta.clamp(min=0) / math.pi


def uniform_hemisphere(u: Tensor, dim: int = -1) -> Tensor:
    """Uniform directions on the z >= 0 hemisphere; pdf = 1 / (2 pi)."""
    u1, u2 = u.unbind(dim)
    cos_t = 1 - u1
    sin_t = torch.sqrt((1 - cos_t * cos_t).clamp(min=0))
    return _polar(cos_t, sin_t, 2 * math.pi * u2, dim)


def uniform_hemisphere_pdf(cos_theta: Tensor) -> Tensor:
    return torch.where(cos_theta >= 0, torch.full_like(cos_theta, 1 / (2 * math.pi)),
                       torch.zeros_like(cos_theta))


def uniform_sphere(u: Tensor, dim: int = -1) -> Tensor:
    """Uniform directions on the sphere; pdf = 1 / (4 pi)."""
    u1, u2 = u.unbind(dim)
    cos_t = 1 - 2 * u1
    sin_t = torch.sqrt((1 - cos_t * cos_t).clamp(min=0))
    return _polar(cos_t, sin_t, 2 * math.pi * u2, dim)


UNIFORM_SPHERE_PDF = 1 / (4 * math.pi)


def ggx_half_vector(u: Tensor, alpha: Tensor, dim: int = -1) -> Tensor:
    """GGX half vectors (local frame) distributed as D(h) (n.h): tan^2 theta = alpha^2 u1 / (1 - u1).

    The tangent form stays accurate for tiny alpha (no 1 - cos^2 cancellation).
    """
    u1, u2 = u.unbind(dim)
    a = alpha.squeeze(dim) if alpha.dim() == u.dim() else alpha
    tan2 = a * a * u1 / (1 - u1).clamp(min=2.0**-24)
    cos_t = torch.rsqrt(1 + tan2)
    sin_t = torch.sqrt(tan2) * cos_t
    return _polar(cos_t, sin_t, 2 * math.pi * u2, dim)


def ggx_half_pdf(n_dot_h: Tensor, alpha: Tensor) -> Tensor:
    """pdf of the half vector: D(h) (n.h)."""
    return ggx_d(n_dot_h, alpha) * n_dot_h.clamp(min=0)


def ggx_pdf(n_dot_h: Tensor, v_dot_h: Tensor, alpha: Tensor, d: Tensor | None = None) -> Tensor:
    """pdf of the reflected light direction l = reflect(v, h): D(h) (n.h) / (4 (v.h)).

    Zero where v.h <= 0 (such h never reflect v into the upper hemisphere of h).  Pass ``d`` to
    reuse an already evaluated D(h).
    """
    d = ggx_d(n_dot_h, alpha) if d is None else d
    vh = v_dot_h.clamp(min=1e-12)
    return torch.where(v_dot_h > 0, d * n_dot_h.clamp(min=0) / (4 * vh), torch.zeros_like(vh))


# ---------------------------------------------------------------------------------------------
# combining strategies


def balance_heuristic(n_a: float | Tensor, pdf_a: Tensor, n_b: float | Tensor, pdf_b: Tensor) -> Tensor:
    """Veach's balance heuristic weight of strategy a (``n_a`` samples) against b."""
    num = n_a * pdf_a
    den = num + n_b * pdf_b
    return torch.where(den > 0, num / den.clamp(min=1e-30), torch.zeros_like(den))


def power_heuristic(n_a: float | Tensor, pdf_a: Tensor, n_b: float | Tensor, pdf_b: Tensor,
                    beta: float = 2.0) -> Tensor:
    """Veach's power heuristic weight (exponent ``beta``) of strategy a against b."""
    a = (n_a * pdf_a) ** beta
    den = a + (n_b * pdf_b) ** beta
    return torch.where(den > 0, a / den.clamp(min=1e-30), torch.zeros_like(den))


def sample_linear(u: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Inverse CDF on [0, 1] of the density ∝ (1 - t) a + t b (a, b >= 0): the t whose CDF is ``u``
    (``u`` itself where a = b = 0).  The rendering layer's environment sampler and the path
    tracer's bilinear warp of quad lights both invert it."""
    den = a + torch.sqrt(torch.lerp(a * a, b * b, u).clamp(min=0))
    t = torch.where(den > 0, u * (a + b) / den.clamp(min=1e-30), u)
    return t.clamp(0, 1)


def select_lobe(u: Tensor, prob_first: Tensor) -> tuple[Tensor, Tensor]:
    """One-sample lobe selection: (``u < prob_first``, ``u`` rescaled to [0,1) within its lobe).

    The rescaled number can be reused as a fresh uniform for the chosen lobe.
    """
    p = prob_first.clamp(0, 1)
    first = u < p
    re = torch.where(first, u / p.clamp(min=1e-12), (u - p) / (1 - p).clamp(min=1e-12))
    return first, re.clamp(0, _ONE_MINUS)
