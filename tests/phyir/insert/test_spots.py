"""The floor-spot finder (phyir.insert.spots, used by benchmarks.insert_gallery) on an exact box room
and on the same room as a model predicts it: a floor that curves up towards the walls and a normal layer
that says "up" everywhere (as the shipped model does on ../shared/panos/fireplace_1k.hdr)."""

from __future__ import annotations

import math
import time

import numpy as np
import torch
from support.scenes import FLOOR_Y, TABLE_HI, TABLE_LO, room_with_table

from phyir import pano
from phyir.insert.spots import GROUP_SPREAD, floor_spots
from phyir.scene import PanoScene

H, W = 256, 512


def room_depth_normal() -> tuple[torch.Tensor, torch.Tensor]:
    """Exact radial depth [1,H,W] and normals [3,H,W] of the fixture room with its table ahead."""
    depth, normal, _ = room_with_table(H, W)
    return depth.float(), normal.float()


def scene_of(depth: torch.Tensor, normal: torch.Tensor) -> PanoScene:
    return PanoScene(image=torch.full((3, H, W), 0.5), depth=depth, normal=normal).validate()


def footprint_gap(x: float, z: float) -> float:
    """Horizontal distance from (x, z) to the table's footprint."""
    dx = max(TABLE_LO[0] - x, 0.0, x - TABLE_HI[0])
    dz = max(TABLE_LO[2] - z, 0.0, z - TABLE_HI[2])
    return math.hypot(dx, dz)


def true_points(depth: torch.Tensor, spots) -> np.ndarray:
    p = depth * pano.directions(H, W)
    return np.array([p[:, int(v), int(u)].numpy() for u, v in spots])


def test_spots_stand_on_the_open_floor_of_an_exact_room():
    depth, normal = room_depth_normal()
    spots = floor_spots(scene_of(depth, normal), 4)
    assert len(spots) == 4
    pts = true_points(depth, spots)
    assert np.allclose(pts[:, 1], FLOOR_Y, atol=0.01)
    horiz = np.hypot(pts[:, 0], pts[:, 2])
    assert ((horiz > 1.15) & (horiz < 2.45)).all()  # the preferred ring (+- a grid cell) is reachable
    for k, (x, _, z) in enumerate(pts):
        assert footprint_gap(x, z) >= 0.3 - 0.03  # clearance (one grid cell of slack)
        others = np.delete(pts, k, 0)
        assert np.hypot(others[:, 0] - x, others[:, 2] - z).min() >= 0.45 - 0.03  # spacing (grid cell slack)
    assert [u for u, _ in spots] == sorted(u for u, _ in spots)


def test_spots_on_predicted_like_geometry_are_found_fast_and_on_the_real_floor():
    depth, _ = room_depth_normal()
    # a model's room: far points pulled towards the camera (the floor bends up like a bowl), a
    # little smooth noise, and a normal layer that is "up" everywhere
    p = depth * pano.directions(H, W)
    horiz = p[[0, 2]].norm(dim=0, keepdim=True)
    gen = torch.Generator().manual_seed(3)
    wobble = torch.nn.functional.interpolate(torch.randn(1, 1, 8, 16, generator=gen), size=(H, W),
                                             mode="bilinear", align_corners=False)[0]
    predicted = depth / (1 + 0.3 * (horiz - 0.8).clamp_min(0)) * (1 + 0.01 * wobble)
    up = torch.zeros(3, H, W)
    up[1] = 1
    t = time.process_time()
    spots = floor_spots(scene_of(predicted, up), 4)
    assert time.process_time() - t < 10  # the per-pixel search took minutes on 512 x 1024
    assert len(spots) == 4
    pts = true_points(depth, spots)
    assert np.allclose(pts[:, 1], FLOOR_Y, atol=0.01)  # the real floor, not the table or a wall
    assert all(footprint_gap(x, z) > 0.1 for x, _, z in pts)
    lon = np.arctan2(pts[:, 0], -pts[:, 2])
    spread = np.abs((lon[:, None] - lon[None] + np.pi) % (2 * np.pi) - np.pi).max()
    assert spread <= 2 * GROUP_SPREAD + 1e-6  # one group, in one view

