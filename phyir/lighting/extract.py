"""Dominant lights of a light probe: the bright, compact sources that cast visible shadows.

A probe ``[3, h, w]`` (equirect, docs/conventions.md) is split into ``residual + sum of lights``:

1. a texel is *bright* where its luminance exceeds ``threshold`` times the probe's mean luminance
   (solid-angle weighted); the part above that level is peak radiance, scaled colour-preservingly,
   the rest stays in the residual (so the split is continuous in the probe);
2. bright texels connected in the 8-neighbourhood (wrapping in longitude) form one light: its
   ``power`` is the sum of peak radiance x solid angle (the irradiance it gives a surface facing
   it), its ``direction`` the power-weighted mean direction, its ``solid_angle`` the participation
   ratio (sum p w)^2 / sum p^2 w of its peak luminance p over texel solid angles w (the size of a
   uniform source with the same spread);
3. lights are kept, strongest first, up to ``max_lights``; a light carrying less than
   ``full_fraction`` of the probe's total luminous power fades out (smoothstep down to
   ``min_fraction``) and what it loses goes back into the residual, so lights appear and vanish
   smoothly as the probe changes (e.g. while an inserted object is dragged).

``residual`` plus every light's share equals the probe exactly (energy is conserved).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance

THRESHOLD = 4.0
MAX_LIGHTS = 4
MIN_FRACTION = 0.02
FULL_FRACTION = 0.08


@dataclass
class Light:
    """One dominant light as seen from the probe's centre."""

    direction: Tensor  # [3] unit, toward the light
    power: Tensor  # [3] sum of radiance x solid angle (irradiance at normal incidence)
    solid_angle: float  # steradians
    fraction: float  # share of the probe's luminous power (before fading)
    peak: Tensor | None = None  # [3, h, w] its radiance in the probe (power = sum of peak x solid angle)

    @property
    def spread(self) -> float:
        """Angular radius (radians) of a disc source of this solid angle."""
        return math.acos(max(-1.0, 1.0 - self.solid_angle / (2 * math.pi)))


def components(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """Labels (-1 outside) of the 8-connected components of ``mask [h, w]``, wrapping in longitude."""
    h, w = mask.shape
    labels = np.full((h, w), -1, dtype=np.int64)
    n = 0
    for i0, j0 in zip(*np.nonzero(mask)):
        if labels[i0, j0] >= 0:
            continue
        stack = [(i0, j0)]
        labels[i0, j0] = n
        while stack:
            i, j = stack.pop()
            for di in (-1, 0, 1):
                ii = i + di
                if not 0 <= ii < h:
                    continue
                for dj in (-1, 0, 1):
                    jj = (j + dj) % w
                    if mask[ii, jj] and labels[ii, jj] < 0:
                        labels[ii, jj] = n
                        stack.append((ii, jj))
        n += 1
    return labels, n


def _smoothstep(a: float, b: float, x: float) -> float:
    t = min(max((x - a) / (b - a), 0.0), 1.0)
    return t * t * (3 - 2 * t)


def extract_lights(probe: Tensor, *, max_lights: int = MAX_LIGHTS, threshold: float = THRESHOLD,
                   min_fraction: float = MIN_FRACTION, full_fraction: float = FULL_FRACTION
                   ) -> tuple[list[Light], Tensor]:
    """``(lights, residual)`` of one probe ``[3, h, w]`` (see the module doc); lights strongest first."""
    if probe.dim() != 3 or probe.shape[0] != 3:
        raise ValueError(f"extract_lights: expected a probe [3,h,w], got {list(probe.shape)}")
    p = probe.detach().double().clamp(min=0)
    h, w = p.shape[-2:]
    omega = pano.solid_angles(h, w, dtype=torch.float64)
    lum = luminance(p)
    total = float((lum * omega).sum())
    if total <= 0:
        return [], probe.clone()
    level = threshold * total / (4 * math.pi)
    bright = lum > level
    keep = torch.where(bright, level / lum.clamp(min=1e-300), torch.ones_like(lum))
    residual = p * keep
    peak = p - residual  # [3, h, w], zero outside bright texels
    peak_lum = lum - lum * keep
    labels, n = components(bright.numpy())
    labels_t = torch.from_numpy(labels)
    dirs = pano.directions(h, w, dtype=torch.float64)
    found = []
    for c in range(n):
        m = labels_t == c
        pw = peak_lum * omega * m
        lum_power = float(pw.sum())
        if lum_power <= 0:
            continue
        d = (dirs * pw).sum((1, 2))
        norm = float(torch.linalg.vector_norm(d))
        if norm <= 1e-12:  # a band around the whole sphere has no direction: leave it in the residual
            continue
        sa = float(pw.sum() ** 2 / (peak_lum**2 * omega * m).sum().clamp(min=1e-300))
        found.append((lum_power, c, d / norm, sa))
    found.sort(key=lambda t: -t[0])
    lights = []
    for rank, (lum_power, c, d, sa) in enumerate(found):
        m = labels_t == c
        frac = lum_power / total
        s = _smoothstep(min_fraction, full_fraction, frac) if rank < max_lights else 0.0
        residual = torch.where(m, residual + (1 - s) * peak, residual)
        if s > 0:
            share = peak * m * s
            power = (share * omega).sum((1, 2))
            lights.append(Light(direction=d.to(probe.dtype), power=power.to(probe.dtype), solid_angle=sa,
                                fraction=frac, peak=share.to(probe.dtype)))
    return lights, residual.to(probe.dtype)
