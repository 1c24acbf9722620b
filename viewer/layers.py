"""The viewer's layers: names, how each is displayed, CPU copies for read-outs, probe look-ups.

Layer arrays are float32 H x W x C numpy arrays (rows from the top), made once per scene off the
GL thread; the GL thread only uploads them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano
from phyir.scene import PanoScene

# display order = command-line names = number keys 1..9, 0, minus
LAYERS = ("image", "depth", "normal", "albedo", "roughness", "metallic",
          "rerender", "diffuse", "specular", "error", "probes")
SCENE_LAYERS = ("image", "depth", "normal", "albedo", "roughness", "metallic")
PREDICTED = ("depth", "normal", "albedo", "roughness", "metallic", "probes")  # what the model adds
RENDERED = ("rerender", "diffuse", "specular", "error")  # what the renderer adds
KEYS = "1234567890-"


@dataclass(frozen=True)
class LayerSpec:
    name: str
    kind: str                              # renderer.KINDS
    range: tuple[float, float] | None      # scalar layers: default colour-map range; None = automatic
    colormap: str = "viridis"
    unit: str = ""
    help: str = ""


SPECS: dict[str, LayerSpec] = {s.name: s for s in (
    LayerSpec("image", "hdr", None, help="input radiance (linear HDR)"),
    LayerSpec("depth", "scalar", None, "viridis", "m", "radial distance from the camera"),
    LayerSpec("normal", "normal", None, help="world-space normal, shown as 0.5 n + 0.5"),
    LayerSpec("albedo", "colour", None, help="base colour (linear, shown as sRGB)"),
    LayerSpec("roughness", "scalar", (0.0, 1.0), "viridis", help="GGX roughness R"),
    LayerSpec("metallic", "scalar", (0.0, 1.0), "viridis", help="metalness M"),
    LayerSpec("rerender", "hdr", None, help="re-rendered image: diffuse + specular"),
    LayerSpec("diffuse", "hdr", None, help="re-rendered diffuse term"),
    LayerSpec("specular", "hdr", None, help="re-rendered specular term"),
    LayerSpec("error", "scalar", (0.0, 0.5), "magma",
              help="|input - rerender| / (input + rerender), summed over RGB"),
    LayerSpec("probes", "hdr", None, help="light-probe atlas: probe (a,b) drawn over its block"),
)}


def to_hwc(t: torch.Tensor) -> np.ndarray:
    """[C, H, W] tensor -> contiguous float32 [H, W, C] array."""
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def probe_atlas(probes: torch.Tensor | np.ndarray) -> np.ndarray:
    """[Hp, Wp, 3, h, w] probes -> [Hp*h, Wp*w, 3] atlas (the layout of phyir.io's probes part)."""
    p = np.asarray(probes.detach().cpu() if isinstance(probes, torch.Tensor) else probes, np.float32)
    Hp, Wp, c, h, w = p.shape
    return np.ascontiguousarray(p.transpose(0, 3, 1, 4, 2).reshape(Hp * h, Wp * w, c))


def error_map(image: np.ndarray, rerender: np.ndarray) -> np.ndarray:
    """Symmetric relative error in [0, 1] per pixel: sum|I - R| / (sum I + sum R) over RGB."""
    num = np.abs(image - rerender).sum(-1, keepdims=True)
    den = image.sum(-1, keepdims=True) + rerender.sum(-1, keepdims=True)
    eps = 1e-6 + 1e-3 * float(den.mean())
    return (num / (den + eps)).astype(np.float32)


def scene_arrays(scene: PanoScene, names=LAYERS) -> dict[str, np.ndarray]:
    """The layers of ``scene`` among ``names`` as H x W x C arrays (probes as their atlas)."""
    out = {}
    for n in names:
        if n in SCENE_LAYERS and getattr(scene, n) is not None:
            out[n] = to_hwc(getattr(scene, n))
        elif n == "probes" and scene.probes is not None:
            out[n] = probe_atlas(scene.probes)
    return out


def rendered_arrays(image: np.ndarray, passes: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """``phyir.shading.render.render_scene`` output -> rerender/diffuse/specular/error arrays."""
    out = {"rerender": to_hwc(passes["image"]), "diffuse": to_hwc(passes["diffuse"]),
           "specular": to_hwc(passes["specular"])}
    out["error"] = error_map(image, out["rerender"])
    return out


def auto_range(a: np.ndarray) -> tuple[float, float]:
    """1st-99th percentile of the finite values (the default range of depth)."""
    v = a[np.isfinite(a)]
    if v.size == 0:
        return 0.0, 1.0
    sample = v[:: max(1, v.size // 200_000)]
    lo, hi = (float(x) for x in np.percentile(sample, [1, 99]))
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


def auto_ranges(arrays: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """Default colour-map ranges of the scalar layers without a fixed one (computed off the UI thread)."""
    return {n: auto_range(a) for n, a in arrays.items()
            if SPECS[n].kind == "scalar" and SPECS[n].range is None}


def probe_at(probes: np.ndarray, u: float, v: float, size: tuple[int, int]) -> np.ndarray:
    """The light probe at panorama coordinates (u, v): bilinear in the probe grid, wrapping in
    longitude (docs/conventions.md); [3, h, w]."""
    Hp, Wp, c, h, w = probes.shape
    H, W = size
    grid = torch.from_numpy(np.ascontiguousarray(probes.reshape(Hp, Wp, -1).transpose(2, 0, 1)))
    uu = torch.tensor([u * Wp / W], dtype=torch.float32)
    vv = torch.tensor([v * Hp / H], dtype=torch.float32)
    return pano.sample_bilinear(grid, uu, vv)[:, 0].numpy().reshape(c, h, w)


def probe_block(u: float, v: float, size: tuple[int, int], grid: tuple[int, int]) -> tuple[int, int]:
    """Index (a, b) of the probe block containing (u, v)."""
    (H, W), (Hp, Wp) = size, grid
    return (min(Hp - 1, max(0, int(v * Hp / H))), int(u * Wp / W) % Wp)


HIST_BINS = 64
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def histogram(a: np.ndarray, kind: str, channel: str = "rgb", bins: int = HIST_BINS
              ) -> tuple[np.ndarray, float, float, str] | None:
    """The side panel's histogram of a layer ``a [h, w, C]``: counts ``[bins]`` (float32) over
    ``[lo, hi]`` and the axis' unit.  HDR: log2 of the luminance (or of the one ``channel``) of the
    positive pixels, over their 0.1-99.9 percentiles (EV); colour: the luminance (or channel) over
    [0, 1]; scalar: the value over its finite range; normals: None (no one-number pixel value)."""
    if kind == "normal":
        return None
    x = a[..., :3] if a.ndim == 3 and a.shape[-1] >= 3 else a.reshape(*a.shape[:2], -1)[..., :1]
    if x.shape[-1] == 3:
        pick = {"r": 0, "g": 1, "b": 2}.get(channel)
        x = x[..., pick] if pick is not None else x @ LUMA
    else:
        x = x[..., 0]
    x = x[np.isfinite(x)].astype(np.float64)
    if kind == "hdr":
        x = np.log2(x[x > 0])
        unit = "log2 (EV)"
        if x.size == 0:
            return np.zeros(bins, np.float32), 0.0, 1.0, unit
        lo, hi = np.percentile(x, [0.1, 99.9])
    elif kind == "colour":
        lo, hi, unit = 0.0, 1.0, "value"
    else:
        lo, hi = (float(x.min()), float(x.max())) if x.size else (0.0, 1.0)
        unit = "value"
    hi = hi if hi > lo else lo + 1e-6
    counts, _ = np.histogram(np.clip(x, lo, hi), bins=bins, range=(lo, hi))
    return counts.astype(np.float32), float(lo), float(hi), unit

