"""Footprints on the floor plan: points in polygons, distances to walls, oriented boxes and their
overlaps (placing furniture and the camera)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Item:
    name: str
    centre: tuple  # OBB centre (room frame)
    half: tuple  # OBB half sizes (local x, y, z)
    yaw: float
    top: float | None = None  # height of a flat top that can carry small objects
    fixture: bool = False  # door/window frames: attached to the shell, not furniture


def in_polygon(poly, x, z) -> bool:
    inside = False
    n = len(poly)
    for i in range(n):
        x1, z1 = poly[i]
        x2, z2 = poly[(i + 1) % n]
        if (z1 > z) != (z2 > z):
            xi = x1 + (z - z1) * (x2 - x1) / (z2 - z1)
            if xi > x:
                inside = not inside
    return inside


def dist_to_polygon_edges(poly, x, z) -> float:
    best = math.inf
    n = len(poly)
    for i in range(n):
        a = np.array(poly[i], float)
        b = np.array(poly[(i + 1) % n], float)
        p = np.array((x, z))
        t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0, 1)
        best = min(best, float(np.linalg.norm(p - (a + t * (b - a)))))
    return best


def obb_corners(centre, half, yaw) -> np.ndarray:
    """Footprint corners [4,2] (x, z) of an OBB."""
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hz = half[0], half[2]
    loc = np.array([[-hx, -hz], [hx, -hz], [hx, hz], [-hx, hz]])
    # local (x, z) -> world with R(yaw): x' = c x + s z, z' = -s x + c z
    return np.stack((c * loc[:, 0] + s * loc[:, 1] + centre[0],
                     -s * loc[:, 0] + c * loc[:, 1] + centre[2]), 1)


def obb_overlap(a: Item | tuple, b: Item | tuple, margin: float = 0.0) -> bool:
    """Do two y-rotated OBBs overlap (by more than -margin)? Separating-axis test."""
    ca, ha, ya = (a.centre, a.half, a.yaw) if isinstance(a, Item) else a
    cb, hb, yb = (b.centre, b.half, b.yaw) if isinstance(b, Item) else b
    if abs(ca[1] - cb[1]) >= ha[1] + hb[1] - 1e-9:  # stacking (touching in y) is allowed
        return False
    pa, pb = obb_corners(ca, ha, ya), obb_corners(cb, hb, yb)
    for poly in (pa, pb):
        for i in range(2):
            e = poly[i + 1] - poly[i]
            ax = np.array((-e[1], e[0])) / np.linalg.norm(e)
            ra, rb = pa @ ax, pb @ ax
            if ra.max() + margin <= rb.min() + 1e-9 or rb.max() + margin <= ra.min() + 1e-9:
                return False
    return True


def point_in_obb(p, item: Item, margin: float = 0.0) -> bool:
    c, s = math.cos(item.yaw), math.sin(item.yaw)
    dx, dy, dz = p[0] - item.centre[0], p[1] - item.centre[1], p[2] - item.centre[2]
    lx = c * dx - s * dz
    lz = s * dx + c * dz
    h = item.half
    return abs(lx) <= h[0] + margin and abs(dy) <= h[1] + margin and abs(lz) <= h[2] + margin
