"""Gravity-aligned normals: floors and ceilings level, walls plumb.

A panorama from an upright camera (a tripod, a levelled phone) sees a room built around gravity:
floors, ceilings, table tops and stair treads are horizontal, walls, doors and cabinet fronts
vertical. A network's normals scatter around those directions (a few degrees on a good room, tens
on a poor one), and depth made to follow them comes out bowl-shaped or leaning. :func:`snap_normals`
pulls each normal that is already near horizontal-surface or vertical-surface orientation onto it
exactly, with weights that fall smoothly to zero, so slanted surfaces (a sloped ceiling, a chair
back, a dome) past the tolerances keep their normal and no seam appears where the pull ends.
"""

from __future__ import annotations

import torch
from torch import Tensor

from phyir import pano

LEVEL_DEG = (12.0, 30.0)  # within the first of ±y: snapped fully; past the second: left as it is
PLUMB_DEG = (8.0, 20.0)  # the same for the angle between a wall's normal and the horizontal plane
# Normals differentiated from a predicted depth (the fallback when the normal head failed) scatter
# far more: on a real room's floor a median 25° from up and a tail past 45°, against 0.1-0.3° for a
# network's plausible normals. A noisier measurement gives the prior more weight.
LEVEL_DEG_FROM_DEPTH = (25.0, 50.0)


def _weight(angle: Tensor, lo_hi: tuple[float, float]) -> Tensor:
    """1 below ``lo`` degrees, 0 above ``hi``, a smoothstep between."""
    lo, hi = lo_hi
    t = ((hi - angle) / (hi - lo)).clamp(0, 1)
    return t * t * (3 - 2 * t)


def snap_normals(normal: Tensor, level_deg: tuple[float, float] = LEVEL_DEG,
                 plumb_deg: tuple[float, float] = PLUMB_DEG) -> Tensor:
    """Unit normals ``[..., 3, H, W]`` (y up, facing the camera) pulled onto gravity's directions.

    Near ±y (within ``level_deg``): toward ±y, where the surface can face the camera that way (a floor
    below the horizon, a ceiling above it). Near the horizontal plane (within ``plumb_deg``): toward
    the normal's own horizontal direction. Elsewhere unchanged.
    """
    H, W = normal.shape[-2:]
    ny = normal[..., 1:2, :, :].clamp(-1, 1)
    tilt = torch.rad2deg(torch.acos(ny.abs()))  # angle to ±y
    lean = 90.0 - tilt  # angle to the horizontal plane
    d_y = pano.directions(H, W, normal.device, normal.dtype)[1:2]
    faces = ny * d_y < 0  # +y below the horizon, -y above it: the camera can see that side
    w_level = _weight(tilt, level_deg) * faces.to(normal.dtype)
    w_plumb = _weight(lean, plumb_deg)
    level = torch.zeros_like(normal)
    level[..., 1:2, :, :] = torch.sign(ny)
    horiz = normal.clone()
    horiz[..., 1:2, :, :] = 0
    horiz = horiz / torch.sqrt((horiz * horiz).sum(-3, keepdim=True)).clamp_min(1e-8)
    keep = (1 - w_level - w_plumb).clamp_min(0)
    out = w_level * level + w_plumb * horiz + keep * normal
    return out / torch.sqrt((out * out).sum(-3, keepdim=True)).clamp_min(1e-8)

