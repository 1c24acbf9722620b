"""The UE4 microfacet BRDF with metalness (PhyIR supplement A.3) — the one implementation.

f = f_d + f_s,  f_d = B (1 - M) / pi,  f_s = D F G / (4 (n.v)(n.l))
D = GGX with alpha = R^2;  F = F0 + (1 - F0) 2^((-5.55473 v.h - 6.98316) v.h),  F0 = 0.04 (1 - M) + M B
G = G1(l) G1(v), G1(x) = n.x / ((n.x)(1 - k) + k),  k = (R + 1)^2 / 8.

Everything is written on cosines so it is layout-agnostic: arguments broadcast against each other
(e.g. cosines ``[S,1,H,W]`` with materials ``[3,H,W]``).  ``G / (4 n.v n.l)`` is evaluated in the
algebraically equal form ``1 / (4 ((n.l)(1-k)+k) ((n.v)(1-k)+k))`` that stays finite as n.l or
n.v -> 0 (k >= 1/8).  The GLSL shaders (shaders/brdf.glsl) mirror these functions and are tested
against them.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

ALPHA_MIN = 1e-3  # GGX alpha floor: R = 0 becomes a very sharp lobe, not a delta (finite D)
DIELECTRIC_F0 = 0.04


def alpha_from_roughness(roughness: Tensor) -> Tensor:
    return (roughness * roughness).clamp(min=ALPHA_MIN)


def f0_from_material(base_color: Tensor, metallic: Tensor) -> Tensor:
    """Specular reflectance at normal incidence: 0.04 (1 - M) + M B."""
    return DIELECTRIC_F0 * (1 - metallic) + metallic * base_color


def ggx_d(n_dot_h: Tensor, alpha: Tensor) -> Tensor:
    """GGX normal distribution D(h) = a^2 / (pi ((1 - (n.h)^2) + (n.h)^2 a^2)^2).

    The denominator is written as (1 - c)(1 + c) + c^2 a^2 rather than c^2 (a^2 - 1) + 1: near the
    peak (c -> 1, tiny a) the latter cancels in float32 (1 - c^2 ~ a^2 ~ 1e-6 is lost to rounding),
    the former keeps both terms' relative precision.
    """
    a2 = alpha * alpha
    c = n_dot_h.clamp(0, 1)
    t = (1 - c) * (1 + c) + c * c * a2
    return a2 / (math.pi * t * t)


def fresnel_ue4(v_dot_h: Tensor, f0: Tensor) -> Tensor:
    """UE4's spherical-Gaussian approximation of Schlick's Fresnel."""
    c = v_dot_h.clamp(0, 1)
    return f0 + (1 - f0) * torch.exp2((-5.55473 * c - 6.98316) * c)


def schlick_k(roughness: Tensor) -> Tensor:
    return (roughness + 1) ** 2 / 8


def g1_schlick(n_dot_x: Tensor, k: Tensor) -> Tensor:
    c = n_dot_x.clamp(0, 1)
    return c / (c * (1 - k) + k)


def visibility(n_dot_l: Tensor, n_dot_v: Tensor, roughness: Tensor) -> Tensor:
    """G / (4 (n.v)(n.l)) in its finite form."""
    k = schlick_k(roughness)
    nl = n_dot_l.clamp(0, 1)
    nv = n_dot_v.clamp(0, 1)
    return 1.0 / (4 * (nl * (1 - k) + k) * (nv * (1 - k) + k))


def brdf_diffuse(base_color: Tensor, metallic: Tensor) -> Tensor:
    """f_d = B (1 - M) / pi."""
    return base_color * (1 - metallic) / math.pi


def brdf_specular(n_dot_l: Tensor, n_dot_v: Tensor, n_dot_h: Tensor, v_dot_h: Tensor,
                  base_color: Tensor, roughness: Tensor, metallic: Tensor) -> Tensor:
    """f_s = D F G / (4 (n.v)(n.l)); zero where the light or the eye is below the surface."""
    alpha = alpha_from_roughness(roughness)
    f = (ggx_d(n_dot_h, alpha) * fresnel_ue4(v_dot_h, f0_from_material(base_color, metallic))
         * visibility(n_dot_l, n_dot_v, roughness))
    return torch.where((n_dot_l > 0) & (n_dot_v > 0), f, torch.zeros_like(f))


def brdf(n_dot_l: Tensor, n_dot_v: Tensor, n_dot_h: Tensor, v_dot_h: Tensor,
         base_color: Tensor, roughness: Tensor, metallic: Tensor) -> tuple[Tensor, Tensor]:
    """(f_d, f_s) for the given cosines; f_d is zero where n.l <= 0 or n.v <= 0."""
    fs = brdf_specular(n_dot_l, n_dot_v, n_dot_h, v_dot_h, base_color, roughness, metallic)
    fd = brdf_diffuse(base_color, metallic)
    fd = torch.where((n_dot_l > 0) & (n_dot_v > 0), fd, torch.zeros_like(fd))
    return fd, fs


def cosines(n: Tensor, v: Tensor, l: Tensor, dim: int = -3) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(n.l, n.v, n.h, v.h) of unit vectors along axis ``dim`` (kept as size 1)."""
    h = v + l
    h = h / torch.linalg.vector_norm(h, dim=dim, keepdim=True).clamp(min=1e-12)

    def dot(a: Tensor, b: Tensor) -> Tensor:
        return (a * b).sum(dim, keepdim=True)

    return dot(n, l), dot(n, v), dot(n, h), dot(v, h)


def brdf_vectors(n: Tensor, v: Tensor, l: Tensor, base_color: Tensor, roughness: Tensor,
                 metallic: Tensor, dim: int = -3) -> tuple[Tensor, Tensor]:
    """(f_d, f_s) from unit vectors n, v (toward the eye), l (toward the light) along axis ``dim``."""
    return brdf(*cosines(n, v, l, dim), base_color, roughness, metallic)
