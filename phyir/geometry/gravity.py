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

import math

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


def _unit(v: Tensor) -> Tensor:
    """``v [...,3,H,W]`` normalised by the square root of its sum of squares (not F.normalize: its
    last-bit differences moved predict's exposure equivariance past the stress test's tolerance)."""
    return v / torch.sqrt((v * v).sum(-3, keepdim=True)).clamp_min(1e-8)


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
    horiz = _unit(horiz)
    keep = (1 - w_level - w_plumb).clamp_min(0)
    out = w_level * level + w_plumb * horiz + keep * normal
    return _unit(out)


# The floor under the camera. A panorama is shot from a tripod, a monopod or a hand above the
# floor it stands on: straight below the camera is that floor. Within NADIR_CAP_DEG of the nadir
# (radius 0.13-0.21 m at camera heights 1.2-2 m: inside a tripod's footprint) nothing else can
# be, yet it is where a network is least reliable: the equirectangular image smears a few
# centimetres of floor across whole rows (a patterned rug becomes radial stripes), and its depth
# there comes out bumpy. Where the ring around the cap is a level floor, the cap continues its
# plane; elsewhere (a camera above a stair, a table, no floor in view) nothing changes.
NADIR_CAP_DEG = 6.0  # the cap: latitudes below -(90 - this)
NADIR_BLEND_DEG = 4.0  # the plane fades out over this many degrees above the cap
FLOOR_RING_DEG = (6.0, 20.0)  # the ring measured: this far from the nadir (degrees)
FLOOR_RING_LEVEL = 0.8  # share of the ring's normals within FLOOR_LEVEL_DEG of up
FLOOR_LEVEL_DEG = 20.0
FLOOR_RING_PLANARITY = (0.8, 0.05)  # this share of the ring within this |height - plane| / height


def floor_under_camera(depth: Tensor, normal: Tensor) -> tuple[Tensor, Tensor, float | None]:
    """Radial ``depth [...,1,H,W]`` and unit ``normal [...,3,H,W]`` (one panorama) with the cap below
    the camera on the plane of the level floor around it (see above); also the camera height it
    used, or None where the ring is not a level floor (then both are returned unchanged)."""
    H, W = depth.shape[-2:]
    d = pano.directions(H, W, depth.device, depth.dtype)
    from_nadir = 90.0 + torch.rad2deg(torch.asin(d[1].clamp(-1, 1)))  # [H,W], 0 straight down
    ring = (from_nadir >= FLOOR_RING_DEG[0]) & (from_nadir < FLOOR_RING_DEG[1])
    if not bool(ring.any()):
        return depth, normal, None
    heights = -(depth[..., 0, :, :] * d[1])[..., ring]  # the floor's distance below the camera
    level = normal[..., 1, :, :][..., ring] > math.cos(math.radians(FLOOR_LEVEL_DEG))
    if float(level.float().mean()) < FLOOR_RING_LEVEL:
        return depth, normal, None
    height = heights[level].median()
    share, tol = FLOOR_RING_PLANARITY
    if not bool(height > 0) or float(((heights - height).abs() / height).quantile(share)) > tol:
        return depth, normal, None
    w = _weight(from_nadir, (NADIR_CAP_DEG, NADIR_CAP_DEG + NADIR_BLEND_DEG)) * (d[1] < 0)  # 1 in the cap
    plane = height / (-d[1]).clamp_min(1e-6)
    up = torch.zeros_like(normal)
    up[..., 1, :, :] = 1
    return w * plane + (1 - w) * depth, _unit(w * up + (1 - w) * normal), float(height)
