"""An analytic box room for the insertion tests: exact depth, normals and albedo, a ceiling lamp,
probes read back from the panorama by projection (phyir.lighting.projection).

Camera at the origin; room x in [-3, 3], y in [-1.5, 1.5] (floor at y = -1.5), z in [-4, 2]; a
table box x in [-0.5, 0.5], y in [-1.5, -0.8], z in [-2.6, -1.6]; a lamp: a disc of radius 0.35 m
on the ceiling above (0, 1.5, -1.0).
"""

from __future__ import annotations

import numpy as np
import torch

from phyir import pano
from phyir.lighting.projection import projected_probe_grid
from phyir.scene import PanoScene

ROOM_LO, ROOM_HI = np.array([-3.0, -1.5, -4.0]), np.array([3.0, 1.5, 2.0])
TABLE_LO, TABLE_HI = np.array([-0.5, -1.5, -2.6]), np.array([0.5, -0.8, -1.6])
FLOOR_Y, TABLE_Y = -1.5, -0.8
LAMP_CENTRE, LAMP_RADIUS, LAMP_RADIANCE = np.array([0.0, 1.5, -1.0]), 0.35, 40.0


def _box_hits(d: np.ndarray, lo: np.ndarray, hi: np.ndarray, inside: bool):
    """Distance and outward-axis normal of rays from the origin meeting an axis-aligned box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = lo[:, None] / d
        t2 = hi[:, None] / d
    tmin = np.where(np.isnan(np.minimum(t1, t2)), -np.inf, np.minimum(t1, t2))
    tmax = np.where(np.isnan(np.maximum(t1, t2)), np.inf, np.maximum(t1, t2))
    if inside:  # leaving the room: the nearest exit plane
        t = tmax.min(0)
        axis = tmax.argmin(0)
        hit = np.ones_like(t, bool)
    else:
        t = tmin.max(0)
        axis = tmin.argmax(0)
        hit = (t <= tmax.min(0)) & (t > 0)
    n = np.zeros_like(d)
    n[axis, np.arange(d.shape[1])] = -np.sign(d[axis, np.arange(d.shape[1])])
    return t, n, hit


def box_room(H: int = 64, W: int = 128, grid: tuple[int, int] = (8, 16), probe_size=(8, 16)) -> PanoScene:
    d = pano.directions(H, W, dtype=torch.float64).reshape(3, -1).numpy()
    t, n, _ = _box_hits(d, ROOM_LO, ROOM_HI, True)
    tt, nt, ht = _box_hits(d, TABLE_LO, TABLE_HI, False)
    use = ht & (tt < t)
    t = np.where(use, tt, t)
    n = np.where(use[None], nt, n)
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
