"""How much light a clipped region held, from what the 8-bit panorama still shows around it.

A lamp, a window or a softbox clips at 1.0 in an 8-bit panorama. Where only some of a pixel's
channels clipped (the coloured halo of a lamp, a warm wall by a fire), the others are measurements:
:func:`fill_partial` gives the clipped channels the hue of the region's surroundings and the
model's ``partial_gain``, and nothing more. Where all three clipped (the region's white core), how
far above the clip it was is written in the surroundings: the region's solid angle, where it sits
(a ceiling lamp, a window at the horizon), how bright the unclipped ring around it is (the falloff
of a bright source over the wall and the glow at its edge), and whether all three channels clipped
(white) or one (coloured light). :class:`RegionModel` maps those :data:`FEATURES` of the region to
the log of its white core's true mean luminance over the panorama's median: ridge regressions (one
law for big regions, one for small ones) fitted on real HDR panoramas photographed by the
evaluation's camera (:mod:`phyir.learn.fit_clip_regions`; the shipped coefficients are
``phyir/assets/clip_regions.json``). :mod:`phyir.lighting.hdr_recovery` applies it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.color import luminance

FEATURES = ("log_area", "sin_lat", "ring_near", "ring_far", "white")
FEATURE_ROWS = 256  # the rings are measured at this many rows (2 and 8 pixels wide: ~1.4 and 5.6 degrees)
RING_NEAR, RING_FAR = 2, 8
HUE_RING = 2  # pixels at FEATURE_ROWS: the unclipped band whose colour fill_partial gives
MODEL_PATH = Path(__file__).resolve().parents[1] / "assets" / "clip_regions.json"


@dataclass(frozen=True)
class RegionModel:
    """log(white core's mean luminance / panorama median) = intercept + Σ coef · feature (of the
    whole region); ``partial_gain``: the factor of :func:`fill_partial`'s partly clipped pixels.

    With ``small_coef``, regions under ``small_below_sr`` steradians take a second law,
    ``small_intercept + Σ small_coef · feature``: the main law is fitted with each region weighted by
    its solid angle (the big regions hold the light), which overshoots the many small regions that
    are barely above the clip; the second is fitted with every small region counted once."""

    intercept: float
    coef: tuple[float, ...]
    features: tuple[str, ...] = FEATURES
    fitted_on: tuple[str, ...] = ()
    regions: int = 0
    ridge: float = 0.0
    small_below_sr: float = 0.0
    small_intercept: float = 0.0
    small_coef: tuple[float, ...] = ()
    partial_gain: float = 1.0

    def log_gain(self, feats: Tensor) -> Tensor:
        """[n] predicted log(mean luminance / median) of regions with features ``feats [n, F]``."""
        f = feats.double()
        out = self.intercept + f @ torch.tensor(self.coef, dtype=torch.float64)
        if not self.small_coef:
            return out
        small = self.small_intercept + f @ torch.tensor(self.small_coef, dtype=torch.float64)
        return torch.where(f[:, FEATURES.index("log_area")] < math.log(self.small_below_sr), small, out)

    def save(self, path: str | os.PathLike) -> None:
        from phyir.io import atomic_write

        with atomic_write(path) as tmp, open(tmp, "w") as f:
            json.dump(asdict(self), f, indent=1)

    @staticmethod
    def load(path: str | os.PathLike = MODEL_PATH) -> RegionModel | None:
        """The model stored at ``path``; None when there is none (or it is of other features)."""
        try:
            d = json.loads(Path(path).read_text())
        except FileNotFoundError:
            return None
        m = RegionModel(float(d["intercept"]), tuple(float(c) for c in d["coef"]), tuple(d["features"]),
                        tuple(d.get("fitted_on", ())), int(d.get("regions", 0)), float(d.get("ridge", 0.0)),
                        float(d.get("small_below_sr", 0.0)), float(d.get("small_intercept", 0.0)),
                        tuple(float(c) for c in d.get("small_coef", ())), float(d.get("partial_gain", 1.0)))
        sizes = {len(m.coef)} | ({len(m.small_coef)} if m.small_coef else set())
        return m if m.features == FEATURES and sizes == {len(FEATURES)} else None


def _dilate(mask: Tensor, r: int) -> Tensor:
    """A boolean [H,W] mask grown by ``r`` pixels (wrapping in longitude): a square's maximum, taken
    along the rows, then the columns (the same result, a fraction of the work)."""
    x = F.max_pool2d(F.pad(mask[None, None].float(), (r, r, 0, 0), mode="circular"), (1, 2 * r + 1), 1)
    return F.max_pool2d(x, (2 * r + 1, 1), 1, padding=(r, 0))[0, 0] > 0


def fill_partial(ldr: Tensor, clip: float, gain: float = 1.0) -> Tensor:
    """A linear 8-bit panorama ``[3,H,W]`` whose partly clipped pixels (some channels at ``clip``, not
    all) have their clipped channels raised to the hue of the unclipped band around the clipped
    pixels, matched to the pixel's measured channels, then the pixel times ``gain``. Every other
    pixel is returned as it is (white cores are :class:`RegionModel`'s)."""
    x = ldr.float()
    over = x >= clip
    partial = over.any(0) & ~over.all(0)
    if not bool(partial.any()):
        return x.clone()  # (a new tensor either way: callers write into it)
    hue = _band_hue(x, over.any(0))[:, None]
    # only the partly clipped pixels are gathered (a 360 camera's image is 200 MB)
    xp, op = x[:, partial], over[:, partial]
    level = torch.where(op, torch.zeros_like(xp), xp / hue).amax(0)  # the measured channels' level
    out = x.clone()
    out[:, partial] = torch.where(op, torch.maximum(xp, level * hue), xp) * gain
    return out


def _band_hue(x: Tensor, clipped: Tensor) -> Tensor:
    """[3] colour (max 1) of the unclipped band HUE_RING pixels wide around ``clipped`` [H,W], at
    FEATURE_ROWS rows as the rings are (the same band in degrees whatever the image's size)."""
    H, W = x.shape[-2:]
    h = min(H, FEATURE_ROWS)
    small = pano.resize_area(x, h, 2 * h)
    # a coarse pixel is clipped if any of its pixels is: max-pooled from the full-size mask
    clip = F.adaptive_max_pool2d(clipped[None, None].float(), (h, 2 * h))[0, 0] > 0 if H > h else clipped
    band = _dilate(clip, HUE_RING) & ~clip
    if not bool(band.any()):
        return torch.ones(3)
    omega = pano.solid_angles(h, 2 * h)
    hue = (small[:, band] * omega[band]).sum(1)
    return (hue / hue.max().clamp_min(1e-12)).clamp_min(1e-3)


def region_means(labels: Tensor, n: int, *maps: Tensor) -> tuple[Tensor, list[Tensor]]:
    """The solid angle [n] (float64) of each region of ``labels`` [H,W] (0..n-1, -1 outside) and the
    solid-angle-weighted mean of each ``maps`` [H,W] over it ([n] each): one pass over the pixels,
    not one per region."""
    H, W = labels.shape[-2:]
    inside = labels >= 0
    k = labels[inside].long()
    w = (pano.solid_angles(H, 1) / W).expand(H, W)[inside].double()  # a pixel's solid angle, by row
    area = torch.bincount(k, w, minlength=n)
    return area, [torch.bincount(k, m[inside].double() * w, minlength=n) / area.clamp_min(1e-300)
                  for m in maps]


def region_features(ldr: Tensor, clipped: Tensor, labels: Tensor, n: int, clip: float,
                    lum: Tensor | None = None) -> Tensor:
    """[n, len(FEATURES)] features of the clipped regions (``labels`` [H,W], -1 outside; ``clipped``
    [H,W]: :func:`phyir.lighting.hdr_recovery.clipped_regions`) of a linear 8-bit panorama ``ldr
    [3,H,W]`` clipped at ``clip``; ``lum``: its luminance [H,W], where the caller has it."""
    H, W = ldr.shape[-2:]
    lum = luminance(ldr) if lum is None else lum
    sin_lat = torch.sin(pano.pixel_lonlat(H, 1, dtype=torch.float64)[1][:, 0])[:, None].expand(H, W)
    area, (lat, white) = region_means(labels, n, sin_lat, (ldr >= clip).all(0))
    med = max(float(lum.median()), 1e-6)
    near, far = _ring_luminance(lum, clipped, labels, n, med)
    return torch.stack((torch.log(area.clamp_min(1e-12)), lat, torch.log(near + 1e-3), torch.log(far + 1e-3),
                        white), 1)


def _ring_luminance(lum_full: Tensor, clipped: Tensor, labels: Tensor, n: int,
                    med: float) -> tuple[Tensor, Tensor]:
    """Solid-angle mean luminance / median of the unclipped rings around each region, RING_NEAR
    and RING_NEAR..RING_FAR pixels wide at FEATURE_ROWS rows (0.01 where a ring is empty)."""
    H, W = lum_full.shape[-2:]
    h = min(H, FEATURE_ROWS)
    rows, cols = torch.arange(h) * H // h, torch.arange(2 * h) * W // (2 * h)
    lab, clip = labels[rows][:, cols], clipped[rows][:, cols]
    lum = pano.resize_area(lum_full[None].float(), h, 2 * h)[0].double() / med
    omega = pano.solid_angles(h, 2 * h, dtype=torch.float64)
    out = torch.full((2, n), 0.01, dtype=torch.float64)
    for j in range(n):
        m = lab == j
        if not bool(m.any()):
            continue
        grown = _dilate(m, RING_NEAR)
        for i, ring in enumerate((grown & ~clip, _dilate(m, RING_FAR) & ~grown & ~clip)):
            if bool(ring.any()):
                out[i, j] = (lum[ring] * omega[ring]).sum() / omega[ring].sum()
    return out[0], out[1]
