"""The path tracer's settings (:func:`phyir.synth.tracer.trace` and its kernels in
:mod:`phyir.synth.paths` read them)."""

from __future__ import annotations

from dataclasses import dataclass


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
