"""Light at any point from the panorama's own light (phyir.lighting.at_point)."""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.lighting.at_point import DRAFT_STEP, LightAtPoint, light_at
from phyir.scene import PanoScene
from phyir.synth.analytic import box_room

H, W = 64, 128
LO, HI = (-2.0, -1.5, -3.0), (2.5, 1.3, 2.0)


def room(probes: bool = True) -> PanoScene:
    depth, normal = box_room(H, W, LO, HI)
    d = pano.directions(H, W)
    image = 0.3 + 0.2 * torch.stack([d[0].abs(), d[1] * 0.5 + 0.5, d[2].abs()])  # smooth, coloured
    grid = torch.full((4, 8, 3, 8, 16), 0.7) if probes else None
    return PanoScene(image=image, depth=depth.float(), normal=normal.float(), probes=grid)


def test_at_the_camera_the_light_is_the_panorama():
    sc = room()
    p = light_at(sc, torch.zeros(1, 3), (16, 32))[0]
    ref = pano.resize_area(sc.image, 16, 32)
    assert float((p - ref).abs().sum() / ref.sum()) < 0.02


def test_away_from_the_camera_the_light_follows_parallax():
    sc = room()
    # a point near the +x wall sees that wall's radiance over a wider solid angle than the camera does
    x = torch.tensor([[2.2, 0.0, 0.0]])
    p = light_at(sc, x, (16, 32))[0]
    u, v = pano.dir_to_uv(torch.tensor([1.0, 0.0, 0.0]), 16, 32, dim=0)
    wall = sc.image[:, H // 2, int(float(u) / 32 * W)]
    near = p[:, 8, int(u)]
    assert torch.allclose(near, wall, rtol=0.05)
    side = pano.directions(16, 32)[0] > math.cos(math.radians(60))  # within 60° of +x
    assert float(side.float().mean()) > 0
    assert float((p[0][side] - wall[0]).abs().mean()) < 0.05


def test_unseen_light_comes_from_the_learned_probes():
    sc = room()
    outside = torch.tensor([[5.0, 0.0, 0.0]])  # behind the wall: nothing the camera saw
    p = light_at(sc, outside, (8, 16))[0]
    assert torch.allclose(p, torch.full_like(p, 0.7), atol=1e-5)
    no_probes = light_at(room(probes=False), outside, (8, 16))[0]
    assert float(no_probes.abs().max()) == 0.0


def test_probes_are_cached_by_position_and_drafts_snap_to_their_grid():
    lap = LightAtPoint(room())
    a = lap.probe_at(torch.tensor([0.1, -0.5, -1.0]))
    assert lap.probe_at(torch.tensor([0.1, -0.5, -1.0])) is not None and len(lap._cache) == 1
    assert a.shape == (3, *lap.probe_size)
    d1 = lap.probe_at(torch.tensor([0.101, -0.5, -1.0]), draft=True, grid=DRAFT_STEP)
    d2 = lap.probe_at(torch.tensor([0.1 + 0.4 * DRAFT_STEP, -0.5, -1.0]), draft=True, grid=DRAFT_STEP)
    assert torch.equal(d1, d2) and len(lap._cache) == 2 and d1.shape == a.shape
    assert float((d1 - a).abs().sum() / a.sum()) < 0.05  # one ray per texel: close to full quality


def test_extreme_radiance_is_projected_in_normalised_units():
    # sums of 1e37 radiance over thousands of rays overflow float32 in the scene's own units
    sc = room()
    x = torch.tensor([[0.3, -0.4, -0.8]])
    ref = light_at(sc, x, (16, 32))
    for k in (1e-30, 2e38):  # values up to 1e38: four of them summed (mips) are inf
        big = PanoScene(image=sc.image * k, depth=sc.depth, normal=sc.normal, probes=sc.probes * k)
        p = light_at(big, x, (16, 32))
        assert bool(torch.isfinite(p).all())
        assert torch.allclose(p / k, ref, rtol=1e-4, atol=1e-6)
