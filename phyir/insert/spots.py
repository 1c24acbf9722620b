"""Free floor spots to stand inserted objects on, found from the depth alone (robust to predicted
geometry: floors that curve up towards the walls, noisy normals): :func:`floor_spots` gives ``n``
pixels about a given spacing apart, a group ahead of the camera on open floor.  Used by
``benchmarks.insert_gallery`` to place its objects in any scene.
"""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.insert import placement
from phyir.scene import PanoScene

PREFERRED_DISTANCE = 1.5  # metres from the camera, horizontally
GROUP_SPREAD = math.radians(50)  # the group within this azimuth of its first spot (one view)
FIRST_TRIES = 12  # first spots (at distinct azimuths) tried before taking the largest group
ROOM = 0.8  # metres of free floor around a spot wanted before it counts as crowded
# where to look for floor spots, best first: (steepest floor tilt in degrees, horizontal distance range m)
SEARCH = ((25.0, (1.2, 2.4)), (50.0, (1.2, 2.4)), (25.0, (0.5, 2.4)), (50.0, (0.5, 2.4)), (50.0, (0.3, 2.4)))


def floor_mask(p: torch.Tensor, tilt_deg: float, step: float = 0.15) -> torch.Tensor:
    """The floor of points ``p [3, h, w]``: pixels whose depth normals are within ``tilt_deg`` of up,
    connected (4-neighbours, longitude wraps, height steps under ``step`` metres) to such pixels in
    the bottom tenth of the panorama (the camera stands on the floor).  Predicted floors curve up
    towards the walls, so a larger tilt reaches farther; table tops are not connected to the floor
    through upward normals, nor across the depth edge behind them."""
    h = p.shape[1]
    up = pano.normals_from_depth(p.norm(dim=0, keepdim=True))[1] > math.cos(math.radians(tilt_deg))
    down_ok = (p[1, 1:] - p[1, :-1]).abs() < step  # row i to row i + 1
    right_ok = (p[1].roll(-1, 1) - p[1]).abs() < step  # column j to column j + 1 (wraps)
    floor = up & (torch.arange(h)[:, None] >= h - max(1, h // 10))
    while True:
        grown = floor.clone()
        grown[1:] |= floor[:-1] & down_ok
        grown[:-1] |= floor[1:] & down_ok
        grown |= (floor & right_ok).roll(1, 1) | (floor.roll(-1, 1) & right_ok)
        grown &= up
        if bool((grown == floor).all()):
            return floor
        floor = grown


def hidden(p: torch.Tensor, i: int, j: int, clearance: float, height: float) -> bool:
    """Whether something nearer the camera hides (part of) an object ``height`` metres tall and
    2 x ``clearance`` wide standing at pixel (i, j) of the points ``p [3, h, w]``."""
    h, w = p.shape[1:]
    horiz = p[[0, 2]].norm(dim=0)
    r = float(horiz[i, j])
    half = max(1, math.ceil(math.atan2(clearance, r) / (2 * math.pi / w)))
    i_top = max(0, int((0.5 - math.atan2(float(p[1, i, j]) + height, r) / math.pi) * h))
    cols = torch.arange(j - half, j + half + 1) % w
    return bool((horiz[i_top:i, cols] < r - clearance).any())


def floor_spots(scene: PanoScene, n: int, spacing: float = 0.45, clearance: float = 0.3, height: float = 0.6,
                rows: int = 128) -> list[tuple[float, float]]:
    """``n`` free floor pixels (u, v) about ``spacing`` metres apart, sorted left to right: a group
    ahead of the camera (the panorama's centre column) about PREFERRED_DISTANCE metres away, on open
    floor where there is some; fewer (or []) when the floor has no room.

    Works on predicted (noisy) geometry, on a grid of about ``rows`` rows (a search per pixel of the
    full panorama takes minutes).  The floor comes from the depth (:func:`floor_mask`), trying the
    :data:`SEARCH` levels in turn until one gives ``n`` spots (else the one with most).  A spot is
    free when no non-floor point between 3 cm and ``height`` metres above it lies within
    ``clearance`` metres horizontally, nothing nearer the camera hides an object of that height
    standing there, and the scene's normal layer there is within placement.SNAP_DEG of up (so
    ``placement.drop`` stands the object upright).
    """
    H, W = scene.size
    s = max(1, H // rows)
    h, w = H // s, W // s
    # point samples, not area means: a mean across a depth edge makes a bridge between surfaces
    depth = scene.depth.float()[:, s // 2::s, s // 2::s][:, :h, :w]
    p = depth * pano.directions(h, w)  # [3, h, w]
    horiz = p[[0, 2]].norm(dim=0)
    upright = placement.scene_normals(scene)[1, s // 2::s, s // 2::s][:h, :w] > math.cos(
        math.radians(placement.SNAP_DEG))
    # what blocks a spot: anything off the floor at its steepest tilt (walls, furniture)
    blockers = p[:, ~floor_mask(p, max(t for t, _ in SEARCH))].T  # [m, 3]
    best = []
    for tilt, distance in SEARCH:
        floor = floor_mask(p, tilt)
        cand = torch.nonzero(floor & upright & (horiz > distance[0]) & (horiz < distance[1]))
        room = torch.full((len(cand),), math.inf)  # horizontal distance to the nearest blocker
        for k in range(0, len(cand), 256):
            c = p[:, cand[k:k + 256, 0], cand[k:k + 256, 1]].T  # [c, 3]
            dy = blockers[None, :, 1] - c[:, None, 1]
            dist = torch.cdist(c[:, [0, 2]], blockers[:, [0, 2]])
            dist[(dy <= 0.03) | (dy >= height)] = math.inf
            room[k:k + 256] = dist.amin(1) if dist.shape[1] else math.inf
        cand, room = cand[room >= clearance], room[room >= clearance]
        xz = p[[0, 2]][:, cand[:, 0], cand[:, 1]].T  # [c, 2]
        r = xz.norm(dim=1)
        # first spots ahead (near the centre column), about PREFERRED_DISTANCE away, then each spot
        # nearest the group so far and within GROUP_SPREAD of its first; all prefer open floor
        crowding = (ROOM - room).clamp_min(0)
        lon = torch.atan2(xz[:, 0], -xz[:, 1])
        ahead = (cand[:, 1] + 0.5 - w / 2).abs() * (2 * math.pi / w)
        first = ahead + (r - PREFERRED_DISTANCE).abs() + crowding
        spots, tried = [], []
        for k0 in torch.argsort(first, stable=True).tolist():
            if len(tried) == FIRST_TRIES or len(spots) == n:
                break
            near = [abs(math.remainder(float(lon[k0]) - t, 2 * math.pi)) < GROUP_SPREAD / 4 for t in tried]
            if any(near) or hidden(p, int(cand[k0, 0]), int(cand[k0, 1]), clearance, height):
                continue
            tried.append(float(lon[k0]))
            group, pts = [k0], [xz[k0]]
            ok = (torch.remainder(lon - lon[k0] + math.pi, 2 * math.pi) - math.pi).abs() <= GROUP_SPREAD
            while len(group) < n:
                key = (xz - torch.stack(pts).mean(0)).norm(dim=1) + crowding
                key[~ok | (torch.cdist(xz, torch.stack(pts)) < spacing).any(1)] = math.inf
                k = int(torch.argmin(key))
                if not math.isfinite(float(key[k])):
                    break
                ok[k] = False
                if not hidden(p, int(cand[k, 0]), int(cand[k, 1]), clearance, height):
                    group.append(k)
                    pts.append(xz[k])
            if len(group) > len(spots):
                spots = [(j * s + s // 2 + 0.5, i * s + s // 2 + 0.5) for i, j in cand[group].tolist()]
        if len(spots) == n:
            return sorted(spots)
        best = max(best, spots, key=len)
    return sorted(best)
