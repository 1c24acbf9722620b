"""phyir.geometry.gravity: normals near level or plumb are pulled onto gravity's directions exactly, smoothly,
only toward a side the camera can see, and slanted surfaces past the tolerances keep theirs."""

from __future__ import annotations

import math

import pytest
import torch

from phyir import pano
from phyir.geometry.gravity import (
    FLOOR_RING_DEG,
    LEVEL_DEG,
    NADIR_BLEND_DEG,
    NADIR_CAP_DEG,
    PLUMB_DEG,
    floor_under_camera,
    snap_normals,
)

H, W = 16, 32


def tilted(deg: float, toward: tuple[float, float, float] = (1.0, 0.0, 0.0),
           sign: float = 1.0) -> torch.Tensor:
    """A normal field [3,H,W] at ``deg`` degrees from sign * y, leaning toward ``toward``."""
    a = math.radians(deg)
    t = torch.tensor(toward, dtype=torch.float64)
    n = sign * math.cos(a) * torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64) + math.sin(a) * t
    return n[:, None, None].expand(3, H, W).clone()


def rows(where: str) -> slice:
    return slice(H // 2, H) if where == "below" else slice(0, H // 2)


def angle_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos((a * b).sum(0).clamp(-1, 1)))


def test_near_level_floors_and_ceilings_snap_exactly_and_only_where_they_face_the_camera():
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)[:, None, None]
    floor = snap_normals(tilted(LEVEL_DEG[0] - 1))
    assert float(angle_deg(floor[:, rows("below")], up.expand(3, H // 2, W)).max()) < 1e-6
    # "up" above the horizon is a surface's underside the camera cannot see: left alone
    assert torch.allclose(floor[:, rows("above")], tilted(LEVEL_DEG[0] - 1)[:, rows("above")])
    ceiling = snap_normals(tilted(LEVEL_DEG[0] - 1, sign=-1.0))
    assert float(angle_deg(ceiling[:, rows("above")], -up.expand(3, H // 2, W)).max()) < 1e-6


def test_near_plumb_walls_lose_their_lean_and_keep_their_azimuth():
    wall = tilted(90 - (PLUMB_DEG[0] - 1), toward=(0.6, 0.0, -0.8))  # 7 degrees off the horizontal
    out = snap_normals(wall)
    assert float(out[1].abs().max()) < 1e-9
    assert torch.allclose(out[0] / out[2], torch.full((H, W), 0.6 / -0.8, dtype=torch.float64))


def test_slanted_surfaces_past_the_tolerances_keep_their_normals():
    for deg in (LEVEL_DEG[1] + 1, 45.0, 90 - PLUMB_DEG[1] - 1):
        n = tilted(deg)
        assert torch.allclose(snap_normals(n), n), deg


def test_the_pull_is_continuous_in_the_angle():
    """No seam where the pull ends: 0.1 degree more tilt moves the result by at most ~0.5 degree."""
    angles = torch.arange(0.0, 90.0, 0.1, dtype=torch.float64)
    out = []
    for deg in angles.tolist():
        out.append(snap_normals(tilted(deg))[:, -1, 0])
    out = torch.stack(out, 1)
    step = angle_deg(out[:, 1:], out[:, :-1])
    assert float(step.max()) < 0.6
    # and every output is a unit normal
    assert torch.allclose(out.norm(dim=0), torch.ones(len(angles), dtype=torch.float64))


def test_exact_box_room_normals_are_unchanged():
    from phyir.synth.analytic import box_room

    _, normal = box_room(32, 64, (-2.0, -1.4, -3.0), (2.5, 1.3, 2.0))
    assert torch.allclose(snap_normals(normal), normal, atol=1e-12)
    d = pano.directions(32, 64, dtype=torch.float64)
    assert float(((snap_normals(normal) * d).sum(0) > 0).double().mean()) == 0.0  # all face the camera


def floor_room(h: float = 1.4, bump: float = 0.0, size: tuple[int, int] = (90, 180)):
    """A box room's depth and normals (camera ``h`` m above its floor), the floor within 8 degrees of
    the nadir bumped by ``bump`` (relative depth, varying in longitude, as a network's pole rows)."""
    from phyir.synth.analytic import box_room

    H, W = size
    depth, normal = box_room(H, W, (-3.0, -h, -4.0), (3.5, 1.2, 3.0))
    lon, lat = pano.pixel_lonlat(H, W, dtype=torch.float64)
    from_nadir = 90 + torch.rad2deg(lat)
    depth = depth * (1 + bump * torch.sin(7 * lon) * (from_nadir < 8))
    return depth, normal, from_nadir


def test_the_cap_below_the_camera_continues_the_level_floor_around_it():
    h = 1.4
    exact, normal, from_nadir = floor_room(h)
    bumpy, _, _ = floor_room(h, bump=0.07)
    bent = normal.clone()
    bent[:, from_nadir < 8] = torch.tensor([0.6, 0.8, 0.0], dtype=torch.float64)[:, None]
    depth, n, height = floor_under_camera(bumpy[None], bent[None])
    assert height == pytest.approx(h, rel=1e-9)
    cap = from_nadir < NADIR_CAP_DEG
    assert torch.allclose(depth[0][:, cap], exact[:, cap], rtol=1e-9)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)[:, None]
    assert torch.allclose(n[0][:, cap], up.expand(3, int(cap.sum())), atol=1e-12)
    # past the blend nothing moves; within it the depth stays between the two
    past = from_nadir >= NADIR_CAP_DEG + NADIR_BLEND_DEG
    assert torch.equal(depth[0][:, past], bumpy[:, past]) and torch.equal(n[0][:, past], bent[:, past])
    blend = ~cap & ~past
    lo, hi = torch.minimum(bumpy, exact)[:, blend], torch.maximum(bumpy, exact)[:, blend]
    assert bool(((depth[0][:, blend] >= lo - 1e-12) & (depth[0][:, blend] <= hi + 1e-12)).all())


def test_no_level_floor_around_the_cap_no_change():
    depth, normal, from_nadir = floor_room()
    ring = (from_nadir >= FLOOR_RING_DEG[0]) & (from_nadir < FLOOR_RING_DEG[1])
    slanted = normal.clone()  # a stair or a slope below the camera: the ring's normals 30 degrees off up
    slanted[:, ring] = torch.tensor([0.5, 0.75 ** 0.5, 0.0], dtype=torch.float64)[:, None]
    for d, n in ((depth, slanted), (depth * (1 + 0.3 * (from_nadir > 12)), normal)):  # a step: not planar
        out_d, out_n, height = floor_under_camera(d[None], n[None])
        assert height is None and out_d is not None
        assert torch.equal(out_d[0], d) and torch.equal(out_n[0], n)
