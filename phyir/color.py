"""Colour: luminance, exposure normalisation and the display tone curve — one definition each.

* :data:`LUMA` / :func:`luminance`: Rec. 709 luminance of linear RGB (the weights of every luminance in
  the project, GLSL's ``colour.glsl`` included).
* :func:`exposure_scale`: the factor that brings an image's median luminance to :data:`KEY` — the
  input normalisation of training and inference alike (docs/training.md).
* :func:`srgb_to_linear` / :func:`linear_to_srgb`: the sRGB transfer curve (IEC 61966-2-1).
* :func:`aces` (Narkowicz's ACES fit) and :func:`to_srgb8`: what a display shows of linear radiance,
  the same curve as the viewer's ``colour.glsl``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

LUMA = (0.2126, 0.7152, 0.0722)
KEY = 0.25  # normalised median luminance
SCALE_RANGE = (1e-6, 1e6)


def luminance(rgb: Tensor, dim: int = -3) -> Tensor:
    """Luminance of linear RGB along ``dim`` (channels; default -3: [...,3,H,W] -> [...,H,W])."""
    w = torch.tensor(LUMA, dtype=rgb.dtype, device=rgb.device)
    shape = [1] * rgb.dim()
    shape[dim] = 3
    return (rgb * w.view(shape)).sum(dim)


def clean_radiance(image: Tensor) -> Tensor:
    """``image`` as float32 with NaN, infinities and negatives zeroed: the input itself when it is
    clean already (the usual case; a 360 camera's panorama is 200 MB a copy)."""
    x = image.float()
    if x.numel():
        lo, hi = torch.aminmax(x)  # one pass; NaN anywhere makes both NaN, and NaN >= 0 is False
        if bool(lo >= 0) and bool(hi < math.inf):
            return x
    return torch.nan_to_num(x, nan=0.0, posinf=0.0).clamp_min(0)


def exposure_scale(image: Tensor) -> Tensor:
    """Per-image factor bringing the median luminance to ``KEY``: [B,3,H,W] -> [B] (or [3,H,W] -> []).

    The median ignores lamps and windows (a few bright pixels) and dark corners alike.  An image whose
    median is zero (mostly black) falls back to its mean; an all-black image gets scale 1.
    """
    L = luminance(clean_radiance(image)).flatten(-2)
    med = L.median(dim=-1).values
    stat = torch.where(med > 0, med, L.mean(-1))
    scale = torch.where(stat > 0, KEY / stat.clamp(min=1e-30), torch.ones_like(stat))
    return scale.clamp(*SCALE_RANGE)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear (IEC 61966-2-1)."""
    x = np.asarray(x, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values to sRGB encoding; clipped to [0, 1] first."""
    x = np.clip(np.asarray(x, np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1 / 2.4) - 0.055).astype(np.float32)


def aces(x):
    """Narkowicz's fit of the ACES filmic tone curve, [0, inf) -> [0, 1); a tensor or a numpy array."""
    x = x.clip(max=1e4)  # the curve is 1 long before; x^2 of x > 1e19 would overflow to inf/inf = NaN
    return ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clip(0, 1)


def to_srgb8(x: Tensor | np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance ``[3,H,W]`` tensor or ``[H,W,3]`` array -> display uint8 ``[H,W,3]``:
    ``exposure`` x ACES, sRGB-encoded, rounded."""
    if isinstance(x, Tensor):
        x = x.detach().float().cpu().permute(1, 2, 0).numpy()
    y = linear_to_srgb(aces(np.maximum(x, 0) * exposure))
    return (np.clip(y, 0, 1) * 255 + 0.5).astype(np.uint8)
