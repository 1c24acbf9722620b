"""Pinned probes: the light probe and the surface at a clicked panorama position."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from phyir import pano
from phyir.lighting import projection
from phyir.scene import PanoScene
from viewer.layers import probe_at, probe_block

PALETTE = ((1.0, 0.55, 0.1), (0.2, 0.8, 1.0), (0.95, 0.3, 0.7), (0.5, 1.0, 0.3),
           (1.0, 0.9, 0.2), (0.6, 0.5, 1.0), (1.0, 0.4, 0.35), (0.3, 1.0, 0.8))


@dataclass
class Pin:
    """A probe pinned at panorama coordinates (u, v)."""

    u: float
    v: float
    colour: tuple[float, float, float]
    exposure: float = 0.0                     # the probe view's own EV
    probe: np.ndarray | None = None           # [3, h, w] bilinear in the probe grid (None: no probes yet)
    probe_gt: np.ndarray | None = None        # the same from the ground truth scene
    block: tuple[int, int] | None = None      # probe grid cell under (u, v)
    direction: np.ndarray = field(default_factory=lambda: np.zeros(3))
    surface: dict[str, np.ndarray] = field(default_factory=dict)  # layer -> value at the pixel
    point: np.ndarray | None = None           # surface point (m), world frame
    position: np.ndarray | None = None        # probe position: point + PROBE_OFFSET along the normal
    textures: dict = field(default_factory=dict)  # GL resources owned by the app

    @property
    def pixel(self) -> tuple[int, int]:
        """(row, column) of the pixel under the pin."""
        return int(self.v), int(self.u)


def pixel_values(arrays: dict[str, np.ndarray], u: float, v: float,
                 size: tuple[int, int]) -> dict[str, np.ndarray]:
    """Every layer's value at the pixel containing (u, v) (the probe atlas at the stretched position)."""
    H, W = size
    out = {}
    for name, a in arrays.items():
        h, w = a.shape[:2]
        i = min(h - 1, max(0, int(v * h / H)))
        j = int(u * w / W) % w
        out[name] = a[i, j]
    return out


def make_pin(u: float, v: float, index: int, scene: PanoScene | None, arrays: dict[str, np.ndarray],
             gt: PanoScene | None = None, exposure: float = 0.0) -> Pin:
    """A pin at (u, v) filled from ``scene`` (layers as ``arrays``) and optionally ``gt``."""
    H, W = next(iter(arrays.values())).shape[:2] if scene is None else scene.size
    u = float(u) % W
    v = float(np.clip(v, 0.0, H - 1e-3))
    pin = Pin(u, v, PALETTE[index % len(PALETTE)], exposure)
    pin.direction = pano.uv_to_dir(torch.tensor(u, dtype=torch.float64), torch.tensor(v, dtype=torch.float64),
                                   H, W).numpy()
    update_pin(pin, scene, arrays, gt)
    return pin


def update_pin(pin: Pin, scene: PanoScene | None, arrays: dict[str, np.ndarray],
               gt: PanoScene | None) -> None:
    """Refresh what a pin shows after layers arrive."""
    if scene is None:
        return
    H, W = scene.size
    pin.surface = {k: val for k, val in pixel_values(arrays, pin.u, pin.v, (H, W)).items() if k != "probes"}
    if scene.probes is not None:
        pin.probe = probe_at(scene.probes.numpy(), pin.u, pin.v, (H, W))
        pin.block = probe_block(pin.u, pin.v, (H, W), scene.probe_grid)
    if gt is not None and gt.probes is not None:
        pin.probe_gt = probe_at(gt.probes.numpy(), pin.u, pin.v, gt.size)
    if scene.depth is not None:
        uu = torch.tensor([pin.u], dtype=torch.float32)
        vv = torch.tensor([pin.v], dtype=torch.float32)
        pin.point = float(pano.sample_bilinear(scene.depth.float(), uu, vv)[0, 0]) * pin.direction
        pin.position = projection.surface_points(scene, uu, vv)[0].double().numpy()
