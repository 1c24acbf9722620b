"""Comparing a layer with the same layer of a reference image (tev/HDRView-style): the modes, their
formulas in numpy (the reference ``shaders/compare.glsl`` is tested against, and what the automatic
range is computed from) and their colour maps.

Per channel, with ``a`` the current image's linear value and ``b`` the reference's:

* ``diff``     a - b (signed)
* ``reldiff``  (a - b) / (|b| + 0.01): tev's relative error, signed; |b| keeps it finite for signed
  layers (normals)
* ``sqerr``    (a - b)^2
* ``split``    no formula: the current image left of the split, the reference right of it

A colour layer's metric is then reduced to one value per pixel, as the display shows channels: the
mean over R, G, B, one channel, or the metric of the luminances (``channel``); scalar layers use
their one channel, normals the mean.  That value goes through a colour map over ``range``.
"""

from __future__ import annotations

import numpy as np

MODES = ("diff", "reldiff", "sqerr", "split")
METRICS = ("diff", "reldiff", "sqerr")  # the modes drawn as one false-coloured value
REL_EPS = 0.01
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)  # shaders/colour.glsl
# signed metrics: a diverging map centred on 0; the squared error: a sequential one from 0
COLORMAP = {"diff": "coolwarm", "reldiff": "coolwarm", "sqerr": "inferno"}
DEFAULT_RANGE = {"diff": 1.0, "reldiff": 1.0, "sqerr": 1.0}


def metric(a: np.ndarray, b: np.ndarray, mode: str) -> np.ndarray:
    """The per-channel metric of ``mode`` (one of METRICS) between same-shaped arrays."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    if mode == "diff":
        return a - b
    if mode == "reldiff":
        return (a - b) / (np.abs(b) + np.float32(REL_EPS))
    if mode == "sqerr":
        return (a - b) ** 2
    raise ValueError(f"unknown metric {mode!r} (choose from {', '.join(METRICS)})")


def compare_values(a: np.ndarray, b: np.ndarray, mode: str, kind: str = "hdr",
                   channel: str = "rgb") -> np.ndarray:
    """H x W values the false colour shows for H x W x C layers ``a`` and ``b`` (``kind``: the layer's
    display kind, viewer.renderer.KINDS; ``channel``: one of viewer.renderer.CHANNELS)."""
    a, b = np.asarray(a, np.float32), np.asarray(b, np.float32)
    if kind == "scalar":
        return metric(a[..., 0], b[..., 0], mode)
    if kind in ("hdr", "colour") and channel == "luminance":
        return metric(a[..., :3] @ LUMINANCE, b[..., :3] @ LUMINANCE, mode)
    if kind in ("hdr", "colour") and channel in ("r", "g", "b"):
        k = "rgb".index(channel)
        return metric(a[..., k], b[..., k], mode)
    return metric(a[..., :3], b[..., :3], mode).mean(-1)


def colour_range(mode: str, extent: float) -> tuple[float, float]:
    """The values mapped onto the colour map: [-extent, extent] for signed metrics, [0, extent] for
    the squared error."""
    return (0.0, extent) if mode == "sqerr" else (-extent, extent)


def auto_extent(values: np.ndarray, percentile: float = 99.0) -> float:
    """An extent that shows most of ``values``: the ``percentile`` of their magnitude (1 when zero)."""
    v = np.abs(np.asarray(values, np.float64))
    v = v[np.isfinite(v)]
    x = float(np.percentile(v, percentile)) if v.size else 0.0
    return x if x > 0 else 1.0


def resample_nearest(b: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``b`` (H' x W' x C) at the pixels of an H x W panorama, nearest: what the view shows of a
    reference of another size laid over the same panorama coordinates."""
    h, w = shape
    if b.shape[:2] == (h, w):
        return b
    rows = ((np.arange(h) + 0.5) * b.shape[0] / h).astype(int)
    cols = ((np.arange(w) + 0.5) * b.shape[1] / w).astype(int)
    return b[rows][:, cols]
