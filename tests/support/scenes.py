"""The box room of the tests: exact depth and normals from ``phyir.synth.analytic`` (the one box-room
geometry of the project), in two variants chosen by ``box_room(..., variant=...)``:

``variant="insert"`` (the default; the insertion, placement and lighting tests)
    Camera at the origin; room ``ROOM_LO..ROOM_HI``: x in [-3, 3], y in [-1.5, 1.5] (floor at
    ``FLOOR_Y`` = -1.5), z in [-4, 2]; a table box ``TABLE_LO..TABLE_HI``: x in [-0.5, 0.5], y in
    [-1.5, -0.8] (top at ``TABLE_Y``), z in [-2.6, -1.6]; a lamp: a disc of radius ``LAMP_RADIUS``
    = 0.35 m on the ceiling above (0, 1.5, -1.0).  The image is the lamp's diffuse light (cosine
    falloff, no shadows) plus a little ambient; the probes are read back from that panorama by
    projection (``phyir.lighting.projection``).  Default probe grid 8x16.

``variant="viewer"`` (the viewer tests)
    Camera inside the box ``VIEWER_ROOM_LO..VIEWER_ROOM_HI``, no furniture; each face has its own
    colour (``FACE_COLOURS``) and roughness, the +z face is metallic; the image is a point light's
    diffuse shading, and probe (a, b) is a sky-like map scaled by ``1 + a + b/4`` so every probe of
    the grid differs (synthetic probes, no projection).  Default probe grid 4x8.
"""

from __future__ import annotations

import numpy as np
import torch

from phyir import pano
from phyir.lighting.projection import projected_probe_grid
from phyir.scene import PanoScene
from phyir.synth import analytic

# the insertion room
ROOM_LO, ROOM_HI = np.array([-3.0, -1.5, -4.0]), np.array([3.0, 1.5, 2.0])
TABLE_LO, TABLE_HI = np.array([-0.5, -1.5, -2.6]), np.array([0.5, -0.8, -1.6])
FLOOR_Y, TABLE_Y = -1.5, -0.8
LAMP_CENTRE, LAMP_RADIUS, LAMP_RADIANCE = np.array([0.0, 1.5, -1.0]), 0.35, 40.0

# the viewer room
VIEWER_ROOM_LO = (-2.0, -1.5, -4.0)
VIEWER_ROOM_HI = (3.0, 1.2, 2.5)
FACE_COLOURS = ((0.8, 0.3, 0.2), (0.2, 0.6, 0.3), (0.9, 0.9, 0.8), (0.4, 0.3, 0.2), (0.3, 0.4, 0.8),
                (0.7, 0.7, 0.3))

VARIANTS = ("insert", "viewer")


def room_with_table(H: int, W: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The insertion room's exact geometry: radial depth ``[1,H,W]``, normals ``[3,H,W]`` (float64)
    and where the table is seen ``[H,W]`` (bool)."""
    d = pano.directions(H, W, dtype=torch.float64)
    t, n, _ = analytic.box_hits(d, ROOM_LO, ROOM_HI, inside=True)
    tt, nt, ht = analytic.box_hits(d, TABLE_LO, TABLE_HI, inside=False)
    table = ht & (tt < t)
    return torch.where(table, tt, t)[None], torch.where(table, nt, n), table


def box_room(H: int = 64, W: int = 128, *, variant: str = "insert", grid: tuple[int, int] | None = None,
             probe_size: tuple[int, int] = (8, 16)) -> PanoScene:
    """The analytic box room as a complete scene (see the module's docstring for the two variants);
    ``grid``: the probe grid (default 8x16 for "insert", 4x8 for "viewer"), ``probe_size``: each probe's
    size."""
    if variant == "insert":
        return _insert_room(H, W, grid or (8, 16), probe_size)
    if variant == "viewer":
        return _viewer_room(H, W, grid or (4, 8), probe_size)
    raise ValueError(f"variant must be one of {VARIANTS}, not {variant!r}")


def _insert_room(H: int, W: int, grid: tuple[int, int], probe_size: tuple[int, int]) -> PanoScene:
    depth, normal, table = room_with_table(H, W)
    d = pano.directions(H, W, dtype=torch.float64).reshape(3, -1).numpy()
    t, n, use = depth.reshape(-1).numpy(), normal.reshape(3, -1).numpy(), table.reshape(-1).numpy()
    p = d * t
    albedo = np.where(use[None], np.array([[0.55], [0.35], [0.2]]), 0.0)
    floor = (~use) & (n[1] > 0.5)
    albedo = np.where(floor[None], np.array([[0.5], [0.45], [0.4]]), albedo)
    albedo = np.where(((~use) & ~floor)[None], np.array([[0.75], [0.75], [0.72]]), albedo)
    # diffuse radiance under the lamp (cosine falloff, no shadows) plus a little ambient
    to_l = LAMP_CENTRE[:, None] - p
    dist2 = (to_l**2).sum(0)
    cos_s = np.clip((n * to_l).sum(0) / np.sqrt(dist2), 0, None)
    cos_l = np.clip(to_l[1] / np.sqrt(dist2), 0, None)
    e = LAMP_RADIANCE * np.pi * LAMP_RADIUS**2 * cos_s * cos_l / dist2
    image = albedo * (e / np.pi + 0.15)
    lamp = (~use) & (np.abs(p[1] - ROOM_HI[1]) < 1e-6) & \
        (((p[0] - LAMP_CENTRE[0]) ** 2 + (p[2] - LAMP_CENTRE[2]) ** 2) < LAMP_RADIUS**2)
    image = np.where(lamp[None], LAMP_RADIANCE, image)

    def to_t(a, c):
        return torch.from_numpy(a.reshape(c, H, W).astype(np.float32))
    scene = PanoScene(image=to_t(image, 3), depth=to_t(t, 1), normal=to_t(n, 3), albedo=to_t(albedo, 3),
                      roughness=torch.ones(1, H, W), metallic=torch.zeros(1, H, W))
    probes = projected_probe_grid(scene, grid=grid, probe_size=probe_size, supersample=2)
    # unseen texels (none in a closed box) would be black; keep a floor of ambient
    return scene.replace(probes=probes.clamp(min=0)).validate()


def _viewer_room(H: int, W: int, grid: tuple[int, int], probe_size: tuple[int, int]) -> PanoScene:
    d = pano.directions(H, W, dtype=torch.float64)
    depth, normal = analytic.box_room(H, W, VIEWER_ROOM_LO, VIEWER_ROOM_HI)
    axis = normal.abs().argmax(0)
    face = axis * 2 + (torch.gather(normal, 0, axis[None])[0] < 0).long()  # the normal faces the camera
    albedo = torch.tensor(FACE_COLOURS, dtype=torch.float64)[face].permute(2, 0, 1)
    rough = (0.2 + 0.12 * face.double())[None]
    metal = (face == 5).double()[None] * 0.8
    p = depth * d
    to_light = torch.tensor([0.5, 1.0, -1.0], dtype=torch.float64)[:, None, None] - p
    dist = to_light.norm(dim=0, keepdim=True)
    cos = ((to_light / dist) * normal).sum(0, keepdim=True).clamp(min=0)
    image = albedo * (0.05 + 3.0 * cos / dist**2)
    Hp, Wp = grid
    pd = pano.directions(*probe_size, dtype=torch.float64)
    env = 0.2 + 2.0 * pd[1].clamp(min=0) ** 4
    scale = 1 + torch.arange(Hp, dtype=torch.float64)[:, None] + 0.25 * torch.arange(Wp, dtype=torch.float64)
    tint = torch.tensor([1.0, 0.8, 0.6], dtype=torch.float64)
    probes = scale[:, :, None, None, None] * tint[:, None, None] * env
    return PanoScene(image=image.float(), depth=depth.float(), normal=normal.float(),
                     albedo=albedo.float(), roughness=rough.float(), metallic=metal.float(),
                     probes=probes.float(), meta={"name": "box room"}).validate()


def lamp_probe(h: int = 16, w: int = 32) -> torch.Tensor:
    """An HDR indoor-like probe: warm floor, cool walls, a window and two lamps 2x2 texels wide
    (peak 40, ~100:1 over the walls; brighter single texels need far more than 1024 spp to converge)."""
    d = pano.directions(h, w)
    y = d[1]
    env = torch.stack([0.25 + 0.15 * y, 0.22 + 0.15 * y, 0.18 + 0.25 * y]).clamp(min=0.03)
    window = (d[0] > 0.55) & (y.abs() < 0.35)
    env = torch.where(window, torch.tensor([3.0, 3.5, 4.5])[:, None, None], env)
    env[:, 2:4, 5:7] = torch.tensor([40.0, 35.0, 25.0])[:, None, None]
    env[:, 4:6, 20:22] = torch.tensor([15.0, 15.0, 18.0])[:, None, None]
    return env
