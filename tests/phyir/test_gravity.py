"""phyir.gravity: normals near level or plumb are pulled onto gravity's directions exactly, smoothly,
only toward a side the camera can see, and slanted surfaces past the tolerances keep theirs."""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.gravity import LEVEL_DEG, PLUMB_DEG, snap_normals

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
