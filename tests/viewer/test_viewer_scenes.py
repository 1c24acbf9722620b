"""Small analytic scenes for the viewer tests (imported by the other test_viewer* modules).

``box_room``: the camera inside an axis-aligned box; depth, normals and materials are exact, the
image is a point light's diffuse shading, and probe (a, b) is a sky-like map scaled by
``1 + a + b/4`` so every probe of the grid differs.
"""

from __future__ import annotations

import torch

from phyir import pano
from phyir.scene import PanoScene

ROOM_LO = (-2.0, -1.5, -4.0)
ROOM_HI = (3.0, 1.2, 2.5)
FACE_COLOURS = ((0.8, 0.3, 0.2), (0.2, 0.6, 0.3), (0.9, 0.9, 0.8), (0.4, 0.3, 0.2), (0.3, 0.4, 0.8),
                (0.7, 0.7, 0.3))


def box_room(H: int = 64, W: int = 128, grid: tuple[int, int] = (4, 8),
             probe: tuple[int, int] = (8, 16)) -> PanoScene:
    d = pano.directions(H, W, dtype=torch.float64)
    lo = torch.tensor(ROOM_LO, dtype=torch.float64)[:, None, None]
    hi = torch.tensor(ROOM_HI, dtype=torch.float64)[:, None, None]
    big = torch.full_like(d, 1e9)
    t = torch.minimum(torch.where(d > 1e-9, hi / d.clamp(min=1e-9), big),
                      torch.where(d < -1e-9, lo / d.clamp(max=-1e-9), big))
    depth, axis = t.min(0)
    sign = torch.gather(torch.sign(d), 0, axis[None])[0]
    normal = torch.zeros_like(d).scatter_(0, axis[None], -sign[None])
    face = axis * 2 + (sign > 0).long()
    albedo = torch.tensor(FACE_COLOURS, dtype=torch.float64)[face].permute(2, 0, 1)
    rough = (0.2 + 0.12 * face.double())[None]
    metal = (face == 5).double()[None] * 0.8
    p = depth[None] * d
    to_light = torch.tensor([0.5, 1.0, -1.0], dtype=torch.float64)[:, None, None] - p
    dist = to_light.norm(dim=0, keepdim=True)
    cos = ((to_light / dist) * normal).sum(0, keepdim=True).clamp(min=0)
    image = albedo * (0.05 + 3.0 * cos / dist**2)
    Hp, Wp = grid
    pd = pano.directions(*probe, dtype=torch.float64)
    env = 0.2 + 2.0 * pd[1].clamp(min=0) ** 4
    scale = 1 + torch.arange(Hp, dtype=torch.float64)[:, None] + 0.25 * torch.arange(Wp, dtype=torch.float64)
    tint = torch.tensor([1.0, 0.8, 0.6], dtype=torch.float64)
    probes = scale[:, :, None, None, None] * tint[:, None, None] * env
    return PanoScene(image=image.float(), depth=depth[None].float(), normal=normal.float(),
                     albedo=albedo.float(), roughness=rough.float(), metallic=metal.float(),
                     probes=probes.float(), meta={"name": "box room"}).validate()


def cheap_render(scene: PanoScene) -> dict[str, torch.Tensor]:
    """Stands in for phyir.shading.render.render_scene where its cost (seconds on 2 cores) buys nothing."""
    diffuse = scene.albedo * scene.image.mean(0, keepdim=True)
    specular = 0.1 * scene.roughness.expand(3, -1, -1) * scene.image
    return {"diffuse": diffuse, "specular": specular, "image": diffuse + specular}


def test_box_room_depth_is_the_distance_to_the_walls():
    sc = box_room(32, 64)
    pts = pano.depth_to_points(sc.depth.double())
    lo, hi = torch.tensor(ROOM_LO, dtype=torch.float64), torch.tensor(ROOM_HI, dtype=torch.float64)
    lo3, hi3 = lo[:, None, None], hi[:, None, None]
    on_wall = ((pts - lo3).abs().amin(0) < 1e-6) | ((pts - hi3).abs().amin(0) < 1e-6)
    assert on_wall.all()
    assert ((pts >= lo3 - 1e-6) & (pts <= hi3 + 1e-6)).all()
    assert sc.probes.shape == (4, 8, 3, 8, 16)
    assert float(sc.probes[3, 7].mean() / sc.probes[0, 0].mean()) == 1 + 3 + 7 / 4
