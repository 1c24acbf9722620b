"""How much light a clipped region held, from what the 8-bit panorama still shows around it.

A lamp, a window or a softbox clips at 1.0 in an 8-bit panorama. Where only some of a pixel's
channels clipped (the coloured halo of a lamp, a warm wall by a fire), the others are measurements:
:func:`fill_partial` gives the clipped channels the hue of the region's surroundings and the
model's ``partial_gain``, and nothing more. Where all three clipped (the region's white core; in a
JPEG, all three near the clip: :func:`white_pixels`), how far above the clip it was is written in
the surroundings: the region's solid angle, where it sits (a ceiling lamp, a window at the
horizon), whether all three channels clipped (white) or one (coloured light), and the profile of
the unclipped rings around it out to 22 degrees: how far its glow reaches over the wall and how
sharply its edge ends, which tells a lamp from a wall or a window barely over the clip.
:class:`RegionModel` maps those :data:`FEATURES` of the region to the log of its white core's true
mean luminance over the panorama's median: ridge regressions (one law for big regions, one for small
ones) fitted on real HDR panoramas photographed by the evaluation's camera
(:mod:`phyir.learn.fit_clip_regions`; the shipped coefficients are ``phyir/assets/clip_regions.json``,
and ``clip_regions_jpeg.json`` for JPEG input, fitted on the same copies through a JPEG encoder too).
:mod:`phyir.lighting.hdr_recovery` applies it.
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

PROFILE_ROWS = 512  # the surroundings are measured at this many rows, whatever the image's size
RADII = (1, 2, 4, 8, 16, 32, 64)  # pixels at PROFILE_ROWS: rings out to 0.35, 0.7, ... 22.5 degrees
RING_STATS = ("lum", "bright", "near_clip")
FEATURES = ("log_area", "sin_lat", "white", "perimeter", "edge_chroma", "clipped_around") + tuple(
    f"{stat}_{r}" for r in RADII for stat in RING_STATS)
AROUND = 8  # clipped_around: the share of clipped pixels from AROUND to RADII[-1] pixels away
# (regions are 8-connected at LABEL_ROWS = 64 rows, so none is nearer than 8 pixels at 512)
HUE_RING = 4  # pixels at PROFILE_ROWS (1.4 degrees): the unclipped band whose colour fill_partial gives
# a clipped pixel whose channels are all above this fraction of the clip is white (a lamp's core): a
# JPEG's chroma subsampling and ringing leave a clipped white core's channels a few codes under 255
WHITE_FRACTION = 0.96
BRIGHT, NEAR_CLIP = 0.5, 0.85  # ring pixels above these fractions of the clip count as bright, near clip
MODEL_PATH = Path(__file__).resolve().parents[1] / "assets" / "clip_regions.json"
JPEG_MODEL_PATH = MODEL_PATH.with_name("clip_regions_jpeg.json")  # the law for JPEG input


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
    jpeg: int = 0  # the JPEG quality its copies also went through (0: none): the law for JPEG input

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
                        tuple(float(c) for c in d.get("small_coef", ())), float(d.get("partial_gain", 1.0)),
                        int(d.get("jpeg", 0)))
        sizes = {len(m.coef)} | ({len(m.small_coef)} if m.small_coef else set())
        return m if m.features == FEATURES and sizes == {len(FEATURES)} else None


def _dilate(mask: Tensor, r: int) -> Tensor:
    """A boolean [H,W] mask grown by ``r`` pixels (wrapping in longitude): a square's maximum, taken
    along the rows, then the columns (the same result, a fraction of the work)."""
    x = F.max_pool2d(F.pad(mask[None, None].float(), (r, r, 0, 0), mode="circular"), (1, 2 * r + 1), 1)
    return F.max_pool2d(x, (2 * r + 1, 1), 1, padding=(r, 0))[0, 0] > 0


@dataclass(frozen=True)
class Coarse:
    """A linear 8-bit panorama and its clipped pixels at PROFILE_ROWS, what the region features and
    :func:`fill_partial`'s band read (one resampling of a 360 camera's image, not one per use):
    shrunk, area-weighted and a coarse pixel clipped if any of its pixels is; enlarged, nearest (no
    glow invented at a clipped edge)."""

    image: Tensor  # [3, PROFILE_ROWS, 2·PROFILE_ROWS]
    clipped: Tensor  # [PROFILE_ROWS, 2·PROFILE_ROWS] bool
    rows: Tensor  # the full-size row and column of each coarse pixel's nearest sample
    cols: Tensor

    @staticmethod
    def of(ldr: Tensor, clipped: Tensor) -> Coarse:
        H, W = ldr.shape[-2:]
        h = PROFILE_ROWS
        rows, cols = torch.arange(h) * H // h, torch.arange(2 * h) * W // (2 * h)
        if H > h:
            image = pano.resize_area(ldr.float(), h, 2 * h)
            clip = F.adaptive_max_pool2d(clipped[None, None].float(), (h, 2 * h))[0, 0] > 0
        else:
            image, clip = ldr.float()[:, rows][:, :, cols], clipped[rows][:, cols]
        return Coarse(image, clip, rows, cols)


def clipped_pixels(ldr: Tensor, clip: float) -> Tensor:
    """[H,W]: the pixels of a linear 8-bit panorama [3,H,W] with some channel at ``clip``."""
    return (ldr >= clip).any(0)


def white_pixels(ldr: Tensor, clip: float, clipped: Tensor | None = None) -> Tensor:
    """[H,W]: the pixels of a linear 8-bit panorama [3,H,W] that clipped white (some channel at
    ``clip``, every channel above WHITE_FRACTION of it; ``clipped``: :func:`clipped_pixels`, where
    the caller has it)."""
    return (clipped_pixels(ldr, clip) if clipped is None else clipped) & (ldr >= WHITE_FRACTION * clip).all(0)


def partly_clipped(ldr: Tensor, clip: float, white: Tensor | None = None,
                   clipped: Tensor | None = None) -> Tensor:
    """[H,W]: the pixels with some channel at ``clip`` that are not white (``white``:
    :func:`white_pixels`, ``clipped``: :func:`clipped_pixels`, where the caller has them)."""
    clipped = clipped_pixels(ldr, clip) if clipped is None else clipped
    return clipped & ~(white_pixels(ldr, clip, clipped) if white is None else white)


def fill_partial(ldr: Tensor, clip: float, gain: float = 1.0, coarse: Coarse | None = None,
                 white: Tensor | None = None, clipped: Tensor | None = None) -> Tensor:
    """A linear 8-bit panorama ``[3,H,W]`` whose partly clipped pixels (:func:`partly_clipped`) have
    their clipped channels raised to the hue of the unclipped band around the clipped pixels, matched
    to the pixel's measured channels, then the pixel times ``gain``. Every other pixel is returned
    as it is (white cores are :class:`RegionModel`'s). ``coarse`` (the panorama's :class:`Coarse`
    view), ``white`` (:func:`white_pixels`) and ``clipped`` (:func:`clipped_pixels`): where the
    caller has them."""
    x = ldr.float()
    clipped = clipped_pixels(x, clip) if clipped is None else clipped
    partial = partly_clipped(x, clip, white, clipped)
    if not bool(partial.any()):
        return x.clone()  # (a new tensor either way: callers write into it)
    hue = _band_hue(coarse or Coarse.of(x, clipped))[:, None]
    # only the partly clipped pixels are gathered and compared (a 360 camera's image is 200 MB)
    xp = x[:, partial]
    op = xp >= clip
    level = torch.where(op, torch.zeros_like(xp), xp / hue).amax(0)  # the measured channels' level
    out = x.clone()
    out[:, partial] = torch.where(op, torch.maximum(xp, level * hue), xp) * gain
    return out


def _band_hue(coarse: Coarse) -> Tensor:
    """[3] colour (max 1) of the unclipped band HUE_RING pixels wide around the clipped pixels."""
    band = _dilate(coarse.clipped, HUE_RING) & ~coarse.clipped
    if not bool(band.any()):
        return torch.ones(3)
    omega = pano.solid_angles(PROFILE_ROWS, 1).expand_as(band)
    hue = (coarse.image[:, band] * omega[band]).sum(1)
    return (hue / hue.max().clamp_min(1e-12)).clamp_min(1e-3)


def panorama_median(lum: Tensor) -> float:
    """The median of a panorama's luminance [H,W], the unit of the law (at least 1e-6: a black
    panorama has one)."""
    return max(float(lum.median()), 1e-6)


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
                    lum: Tensor | None = None, coarse: Coarse | None = None,
                    white: Tensor | None = None, median: float | None = None) -> Tensor:
    """[n, len(FEATURES)] features of the clipped regions (``labels`` [H,W], -1 outside; ``clipped``
    [H,W]: :func:`phyir.lighting.hdr_recovery.clipped_regions`) of a linear 8-bit panorama ``ldr
    [3,H,W]`` clipped at ``clip``; ``lum`` (its luminance [H,W]), ``coarse`` (its :class:`Coarse`
    view), ``white`` (:func:`white_pixels`) and ``median`` (:func:`panorama_median`): where the
    caller has them."""
    H, W = ldr.shape[-2:]
    lum = luminance(ldr) if lum is None else lum
    white = white_pixels(ldr, clip, clipped) if white is None else white
    sin_lat = torch.sin(pano.pixel_lonlat(H, 1, dtype=torch.float64)[1][:, 0])[:, None].expand(H, W)
    area, (lat, white) = region_means(labels, n, sin_lat, white)
    med = panorama_median(lum) if median is None else median
    profile = _surround_profiles(coarse or Coarse.of(ldr, clipped), labels, n, clip, med)
    return torch.cat((torch.stack((torch.log(area.clamp_min(1e-12)), lat, white), 1), profile), 1)


def _surround_profiles(coarse: Coarse, labels: Tensor, n: int, clip: float, med: float) -> Tensor:
    """[n, 3 + 3·len(RADII)]: ``perimeter`` (log of the unclipped pixels touching the region per
    region pixel), ``edge_chroma`` (max - min of their mean chromaticity), ``clipped_around``, then
    for each ring between consecutive RADII (at PROFILE_ROWS): the log of its unclipped mean
    luminance / median and the solid-angle fractions of those pixels above BRIGHT and NEAR_CLIP ×
    ``clip``. How far the glow around a region reaches, and how sharply it ends, is what tells a lamp
    from a wall barely over the clip. Each region is measured in a window of the panorama around it
    (wrapping in longitude), not over the whole panorama."""
    h, R = PROFILE_ROWS, RADII[-1]
    img, clip_map, lab = coarse.image, coarse.clipped, labels[coarse.rows][:, coarse.cols]
    img_lum = luminance(img)
    lum, chroma = img_lum / med, img / img_lum.clamp_min(1e-6)
    omega = pano.solid_angles(h, 1).expand(h, 2 * h)

    def pad(t: Tensor, value: float = 0.0) -> Tensor:  # R pixels: wrapping in longitude, rows past the poles
        t = torch.cat((t[..., -R:], t, t[..., :R]), -1)
        return F.pad(t, (0, 0, R, R), value=value)

    maps = (pad(lum), pad(chroma), pad(clip_map.float()) > 0, pad(torch.ones(h, 2 * h)) > 0, pad(omega))
    lab_p = pad(lab.float(), -1)
    ys, xs = torch.nonzero(lab >= 0, as_tuple=True)
    k = lab[ys, xs].long()
    lo = torch.full((2, n), torch.iinfo(torch.int64).max, dtype=torch.int64)
    hi = torch.full((2, n), -1, dtype=torch.int64)
    for i, v in enumerate((ys, xs)):
        lo[i].scatter_reduce_(0, k, v, "amin")
        hi[i].scatter_reduce_(0, k, v, "amax")
    out = torch.zeros(n, 3 + len(RING_STATS) * len(RADII), dtype=torch.float64)
    for j in range(n):
        if int(hi[0, j]) < 0:  # the region vanished at PROFILE_ROWS: neutral features
            out[j, 0] = math.log(1e-3)
            continue
        win = tuple(slice(int(lo[i, j]), int(hi[i, j]) + 2 * R + 1) for i in range(2))
        out[j] = _profile(lab_p[win] == j, *(m[..., win[0], win[1]] for m in maps), clip / med)
    return out


def _profile(region: Tensor, lum: Tensor, chroma: Tensor, clip: Tensor, valid: Tensor, omega: Tensor,
             clip_level: float) -> Tensor:
    """:func:`_surround_profiles`' row for one region, from a window around it (``lum`` / median)."""
    grown = dict(zip((AROUND, *RADII), _grown(region, (AROUND, *RADII))))
    edge = grown[RADII[0]] & ~region & valid & ~clip
    w = omega[edge].double()
    perimeter = math.log(float(edge.sum()) / float(region.sum()) + 1e-3)
    hue = (chroma[:, edge] * w).sum(1) / w.sum() if bool(edge.any()) else torch.ones(3)
    around = grown[RADII[-1]] & ~grown[AROUND] & valid
    clipped_around = float((around & clip).sum()) / max(float(around.sum()), 1.0)
    row = [perimeter, float(hue.max() - hue.min()), clipped_around]
    inner = region
    for r in RADII:
        seen = grown[r] & ~inner & valid & ~clip
        w = omega[seen].double()
        if bool(seen.any()):
            total, ring = w.sum(), lum[seen]
            row += [math.log(float((ring * w).sum() / total) + 1e-3),
                    float(w[ring > BRIGHT * clip_level].sum() / total),
                    float(w[ring > NEAR_CLIP * clip_level].sum() / total)]
        else:
            row += [math.log(1e-3), 0.0, 0.0]
        inner = grown[r]
    return torch.tensor(row, dtype=torch.float64)


def _grown(mask: Tensor, radii: tuple[int, ...]) -> list[Tensor]:
    """A boolean [h,w] window's mask grown by each of ``radii`` pixels (a square; nothing past the
    window): box sums of one summed-area table, whatever the radius."""
    h, w = mask.shape
    table = F.pad(mask.to(torch.int32).cumsum(0).cumsum(1), (1, 0, 1, 0))
    iy, ix = torch.arange(h), torch.arange(w)
    out = []
    for r in radii:
        y0, y1 = (iy - r).clamp(0, h), (iy + r + 1).clamp(0, h)
        x0, x1 = (ix - r).clamp(0, w), (ix + r + 1).clamp(0, w)
        box = table[y1][:, x1] - table[y0][:, x1] - table[y1][:, x0] + table[y0][:, x0]
        out.append(box > 0)
    return out
