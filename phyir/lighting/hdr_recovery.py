"""HDR from LDR: the light an 8-bit panorama clipped, given back to its clipped regions.

An 8-bit panorama (a phone, a JPEG) clips lamps and windows at 1.0: the naive environment from it
holds a fraction of their energy (the real panoramas of ``phyir eval --real``: a diffuse sphere lit by
the LDR copy is 0.4-0.9x as bright as under the HDR). Each connected clipped region (8-connected,
wrapping in longitude, found at :data:`LABEL_ROWS` rows) is given light back in one of two ways.
With a :class:`phyir.lighting.clip_regions.RegionModel` (fitted on real HDR panoramas; what
``phyir predict`` uses) its white core is brought to the luminance the model predicts from what the
panorama shows around the region, and its partly clipped pixels get only their clipped channels
back (:func:`phyir.lighting.clip_regions.fill_partial`). Without one, the whole region is brought
to the mean luminance, relative to the panorama's median, that a clipped steradian has in
path-traced rooms: ``L / median = GAIN * A**AREA_EXPONENT`` (``python -m
benchmarks.ldr_clip_calibration DATA``; the region's area tells almost nothing there, so
AREA_EXPONENT is 0). The region keeps its colour and its shape; a region already brighter than its
target is left alone.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.lighting.clip_regions import (
    JPEG_MODEL_PATH,
    MODEL_PATH,
    Coarse,
    RegionModel,
    clipped_pixels,
    fill_partial,
    panorama_median,
    region_features,
    region_means,
    white_pixels,
)
from phyir.lighting.extract import components

CLIP_LEVEL = 0.99  # linear value at or above which an 8-bit channel is clipped (254.5/255 decoded)
# benchmarks/ldr_clip_calibration.py gave 13.53 on `phyir synth --count 40 --seed 7000 --size 128x256`
# when it was set; today's generator gives 16.09 there (--spp 8) and 13.11 at 256x512 (data/cal256:
# --seed 9100, nearer the real panoramas' size), so it stands (a clipped steradian spreads ~4x anyway)
GAIN = 13.53
AREA_EXPONENT = 0.0
LABEL_ROWS = 64


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover_clipped` did: regions boosted, their solid angle, the energy factor."""

    regions: int
    solid_angle: float  # steradians of clipped pixels
    energy_gain: float  # luminous energy of the panorama after / before
    method: str = "gain"  # "gain", "regions", "regions-jpeg" (this module) or "clipnet" (ldr_to_hdr)


def clipped_regions(image: Tensor, clip: float = CLIP_LEVEL) -> tuple[Tensor, Tensor, int]:
    """``(clipped [H,W] bool, labels [H,W] (-1 outside), count)`` of an LDR panorama ``[3,H,W]``."""
    H, W = image.shape[-2:]
    clipped = clipped_pixels(image, clip)
    rows = min(LABEL_ROWS, H)
    coarse = pano.resize_area(clipped[None].float(), rows, 2 * rows)[0] > 0
    labels, n = components(coarse.numpy())
    lab = torch.from_numpy(labels).to(torch.int32)  # (int32: a 360 camera's label map is 66 MB, not 133)
    lab = lab[(torch.arange(H) * rows // H)][:, (torch.arange(W) * 2 * rows // W)]
    return clipped, lab.masked_fill_(~clipped, -1), n


def white_cores(image: Tensor, labels: Tensor, clip: float = CLIP_LEVEL,
                white: Tensor | None = None) -> Tensor:
    """``labels`` [H,W] kept only where ``image`` clipped white (-1 elsewhere;
    :func:`phyir.lighting.clip_regions.white_pixels`; ``white``: that mask, where the caller has it)."""
    return labels.masked_fill(~(white_pixels(image, clip) if white is None else white), -1)


def recover_clipped(image: Tensor, clip: float = CLIP_LEVEL,
                    model: RegionModel | None | str = None) -> tuple[Tensor, Recovery]:
    """The LDR panorama ``[3,H,W]`` (linear, clipped at ``clip``) with its clipped regions brought to
    the calibrated gain (see the module doc), or, with a ``model``, to the radiance it predicts for
    each (:class:`phyir.lighting.clip_regions.RegionModel`; "shipped": ``phyir/assets/
    clip_regions.json``, "shipped-jpeg": the law for JPEG input, ``clip_regions_jpeg.json``, else
    the first; None where the files are missing); unclipped pixels are unchanged."""
    if isinstance(model, str):
        if model not in ("shipped", "shipped-jpeg"):
            raise ValueError(f"unknown region model {model!r}")
        model = shipped_model(jpeg=model == "shipped-jpeg")
    x = image.float()
    H, W = x.shape[-2:]
    clipped, labels, n = clipped_regions(x, clip)
    if n == 0:
        return image, Recovery(0, 0.0, 1.0)
    # solid angle depends on the row only: [H,1], no full-size map (a 360 camera's is 66 MB)
    omega = pano.solid_angles(H, 1) / W
    lum = luminance(x)
    med = panorama_median(lum)
    if model is not None:  # the law lifts the white cores; the partly clipped pixels are filled
        # the coarse view and the masks once, for the features, the cores and the fill
        coarse, white = Coarse.of(x, clipped), white_pixels(x, clip, clipped)
        feats = region_features(x, clipped, labels, n, clip, lum, coarse, white, med)
        labels = white_cores(x, labels, clip, white)
        area, (mean,) = region_means(labels, n, lum)
        target = med * torch.exp(model.log_gain(feats))
        out = fill_partial(x, clip, model.partial_gain, coarse, white, clipped)
    else:
        area, (mean,) = region_means(labels, n, lum)
        target = med * GAIN * area ** AREA_EXPONENT
        out = x.clone()
    boost = (area > 0) & (target > mean)
    factor = torch.where(boost, target / mean.clamp_min(1e-6), torch.ones_like(mean)).float()
    inside = labels >= 0
    out[:, inside] = x[:, inside] * factor[labels[inside].long()]
    boosted = int(boost.sum())
    before = float((lum.sum(-1, keepdim=True) * omega).sum())
    after = float((luminance(out).sum(-1, keepdim=True) * omega).sum())
    clipped_sr = float(omega.expand(H, W)[clipped].sum())
    method = "gain" if model is None else "regions-jpeg" if model.jpeg else "regions"
    return out, Recovery(boosted, clipped_sr, after / max(before, 1e-30), method)


def shipped_model(jpeg: bool = False) -> RegionModel | None:
    """The shipped :class:`phyir.lighting.clip_regions.RegionModel`: with ``jpeg`` the law for JPEG
    input, where its file is present, else the first; None where neither is."""
    return (_load_model(JPEG_MODEL_PATH) if jpeg else None) or _load_model(MODEL_PATH)


@functools.cache
def _load_model(path: Path) -> RegionModel | None:
    return RegionModel.load(path)
