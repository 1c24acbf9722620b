"""Analytic rooms: exact depth and normals of axis-aligned boxes seen from the camera, for tests,
benchmarks and checks that need ground truth without the path tracer (the one box-room geometry)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from phyir import pano


def box_hits(dirs: Tensor, lo: Sequence[float], hi: Sequence[float], inside: bool
             ) -> tuple[Tensor, Tensor, Tensor]:
    """Rays from the origin along unit ``dirs [3, ...]`` against the box ``lo..hi`` (metres, camera frame).

    ``inside``: the camera is in the box and the rays leave it (the room's walls, always hit); else the
    box is an object in front of the camera (hit where the slab interval is non-empty and ahead).
    Returns distance ``t [...]``, the face normal facing the camera ``n [3, ...]`` and ``hit [...]``."""
    lo_t = torch.as_tensor(lo, dtype=dirs.dtype).reshape(3, *([1] * (dirs.dim() - 1)))
    hi_t = torch.as_tensor(hi, dtype=dirs.dtype).reshape(3, *([1] * (dirs.dim() - 1)))
    safe = torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t1, t2 = lo_t / safe, hi_t / safe
    near, far = torch.minimum(t1, t2), torch.maximum(t1, t2)
    if inside:
        t, axis = far.min(0)
        hit = torch.ones_like(t, dtype=torch.bool)
    else:
        t, axis = near.max(0)
        hit = (t <= far.min(0).values) & (t > 0)
    sign = torch.gather(torch.sign(dirs), 0, axis[None])[0]
    n = torch.zeros_like(dirs).scatter_(0, axis[None], -sign[None])
    return t, n, hit


def box_room(H: int, W: int, lo: Sequence[float], hi: Sequence[float]) -> tuple[Tensor, Tensor]:
    """Radial depth ``[1,H,W]`` and normals ``[3,H,W]`` (float64) of a box room ``lo..hi`` around the
    camera at the origin."""
    t, n, _ = box_hits(pano.directions(H, W, dtype=torch.float64), lo, hi, inside=True)
    return t[None], n
