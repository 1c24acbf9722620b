"""Whole-scene augmentations that keep every layer consistent: yaw rotation and left-right mirror.

Both work on unbatched and batched scenes (all tensors are indexed from the end).
"""

from __future__ import annotations

import torch
from torch import Tensor

from phyir.pano import rotate_vectors, yaw_matrix, yaw_shift_angle
from phyir.scene import PanoScene


def rotate_yaw(scene: PanoScene, shift: int) -> PanoScene:
    """Rotate the world about +y so the panorama rolls ``shift`` whole columns to the right.

    Per-pixel layers and masks are rolled exactly.  Normals are rolled and rotated by
    ``yaw_matrix(yaw_shift_angle(shift, W))``.  Probes see the same world rotation: each probe's
    content rolls by ``shift * w / W`` probe columns and the probe grid by ``shift * Wp / W``
    blocks.  When either amount is fractional, it is resampled linearly in longitude (within a
    probe: bilinear look-up at the rotated direction; across the grid: linear interpolation
    between the two neighbouring probes, the same rule that lights pixels between probe centres).
    """
    W = scene.size[1]
    shift = int(shift)

    def roll(t: Tensor | None) -> Tensor | None:
        return None if t is None else torch.roll(t, shift, dims=-1)

    normal = scene.normal
    if normal is not None:
        m = yaw_matrix(yaw_shift_angle(shift, W), dtype=normal.dtype, device=normal.device)
        normal = rotate_vectors(m, torch.roll(normal, shift, dims=-1), dim=-3)
    probes = scene.probes
    if probes is not None:
        w, Wp = probes.shape[-1], probes.shape[-4]
        probes = _roll_fraction(probes, shift * w, W, dim=-1)  # content: world rotation
        probes = _roll_fraction(probes, shift * Wp, W, dim=-4)  # grid: probe positions
    return PanoScene(image=roll(scene.image), depth=roll(scene.depth), normal=normal,
                     albedo=roll(scene.albedo), roughness=roll(scene.roughness),
                     metallic=roll(scene.metallic), probes=probes,
                     masks={k: roll(v) for k, v in scene.masks.items()}, meta=dict(scene.meta))


def _roll_fraction(x: Tensor, num: int, den: int, dim: int) -> Tensor:
    """Circular shift along ``dim`` by num/den elements (out[j] = x(j - num/den)), linear in between."""
    k, rem = divmod(num, den)
    out = torch.roll(x, k, dims=dim)
    if rem:
        f = rem / den
        out = (1 - f) * out + f * torch.roll(x, k + 1, dims=dim)
    return out


def mirror_lr(scene: PanoScene) -> PanoScene:
    """Mirror the world left-right (x -> -x): columns reversed, normals' x negated, probe grid
    and probe contents reversed in longitude.  Longitude lon maps to -lon exactly."""

    def flip(t: Tensor | None) -> Tensor | None:
        return None if t is None else torch.flip(t, dims=(-1,))

    normal = scene.normal
    if normal is not None:
        sign = torch.tensor([-1.0, 1.0, 1.0], dtype=normal.dtype, device=normal.device)
        normal = flip(normal) * sign[:, None, None]
    probes = None if scene.probes is None else torch.flip(scene.probes, dims=(-4, -1))
    return PanoScene(image=flip(scene.image), depth=flip(scene.depth), normal=normal,
                     albedo=flip(scene.albedo), roughness=flip(scene.roughness),
                     metallic=flip(scene.metallic), probes=probes,
                     masks={k: flip(v) for k, v in scene.masks.items()}, meta=dict(scene.meta))
