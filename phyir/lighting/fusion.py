"""Probes fused from two estimates of the same light: LNet's and the panorama projected from the
probe along the predicted depth (:mod:`phyir.lighting.projection`, LNet where the camera did not see).

Their errors are of different kinds. LNet infers the light: smooth, too dim at lamps. The projection
reads the light the camera saw: sharp, but misplaced wherever the predicted depth is wrong (the
panorama re-read through a surface that is not where it looks). The fused probe takes its
directional shape and colour from their geometric mean — an average of log radiance, where both
errors are multiplicative and partly cancel — and its energy from the mean of theirs (a geometric mean
alone is darker than either, by Jensen's inequality, which diffuse objects would show). Both steps are
exposure-equivariant: probes of an input 8x brighter come out exactly 8x brighter.

``phyir eval --data data/h128 --split train`` (24 rooms held out from the shipped weights), against
LNet alone: probe log-MSE 0.042 against 0.052, relighting error of the diffuse / matte-silver /
mirror-silver sphere 0.013 / 0.018 / 0.036 against 0.018 / 0.025 / 0.047 (README, "The model").
"""

from __future__ import annotations

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance

# LNet's share, chosen on 40 training rooms of the wider generator (`phyir synth --seed 20000`), not the
# held-out ones (`python -m benchmarks.probe_fusion data/n128 train 40`): probe log-MSE 0.0581 / 0.0579 /
# 0.0590 at 0.4 / 0.5 / 0.6, mirror-sphere relighting 0.0537 / 0.0535 / 0.0545, the other two spheres
# within 6 % of each other (LNet alone: log-MSE 0.0751, the projection alone 0.0716)
FUSE_WEIGHT = 0.5
FLOOR = 1e-6  # floor of the logarithm relative to the mean radiance (black stays black, not -inf)


def geometric_mean(a: Tensor, b: Tensor, weight: float = FUSE_WEIGHT) -> Tensor:
    """``a^weight * b^(1-weight)`` of non-negative tensors, with the logarithm's floor relative to their
    mean radiance (so it scales with the input and black stays black)."""
    a, b = a.clamp_min(0), b.clamp_min(0)
    floor = FLOOR * float(torch.maximum(a.mean(), b.mean()).clamp_min(1e-30))
    log = weight * torch.log(a + floor) + (1 - weight) * torch.log(b + floor)
    return (torch.exp(log) - floor).clamp_min(0)


def fuse_probes(lnet: Tensor, projected: Tensor, weight: float = FUSE_WEIGHT) -> Tensor:
    """Probes ``[..., 3, h, w]`` with the shape and colour of ``lnet^weight * projected^(1-weight)`` and,
    per probe, the radiant energy (luminance, solid-angle weighted) of ``weight*lnet + (1-weight)*projected``.
    One factor per probe, not per channel: in a strongly coloured room (firelight: the panorama's blue
    nearly black) a per-channel one gave the blue of LNet's probe to the few texels where the
    projection had any, magenta patches."""
    if lnet.shape != projected.shape:
        raise ValueError(f"fuse_probes: shapes {tuple(lnet.shape)} and {tuple(projected.shape)} differ")
    a, b = lnet.clamp_min(0), projected.clamp_min(0)
    shape = geometric_mean(a, b, weight)
    omega = pano.solid_angles(*a.shape[-2:], a.device, a.dtype)

    def energy(x: Tensor) -> Tensor:
        return (luminance(x) * omega).sum((-2, -1))[..., None, None, None]

    mean = weight * a + (1 - weight) * b
    target, have = energy(mean), energy(shape)
    # an estimate with no light at all in a probe says nothing of its shape: the mean there
    both = (energy(a) > 0) & (energy(b) > 0) & (have > 0)
    return torch.where(both, shape * (target / have.clamp_min(1e-30)), mean)
