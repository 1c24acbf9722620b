"""The render benchmark's procedural scenes (:mod:`phyir.bench.render`): smooth random G-buffers
(normals facing the camera, base colour, roughness, metalness) and a probe grid (one probe per
``block x block`` pixels) lit by an ambient gradient plus a few bright sources at fixed 3D positions,
so probes vary smoothly across the grid."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.scene import PanoScene

SCENE_KINDS = ("glossy", "metal", "mixed")


def _smooth_field(g: torch.Generator, c: int, H: int, W: int, cells: tuple[int, int]) -> Tensor:
    """Smooth random field ``[c, H, W]`` in [0, 1]: bicubic upsampling of a coarse random grid."""
    coarse = torch.rand(1, c, *cells, generator=g, dtype=torch.float64)
    coarse = pano.circular_pad(coarse, (2, 2, 0, 0))
    up = F.interpolate(coarse, size=(H, W + 4 * W // cells[1]), mode="bicubic", align_corners=False)
    off = 2 * W // cells[1]
    return up[0, :, :, off:off + W].clamp(0, 1)


def bench_scene(kind: str = "glossy", H: int = 128, W: int = 256, block: int = 2,
                probe_size: tuple[int, int] = (16, 32), seed: int = 0) -> PanoScene:
    """A procedural :class:`PanoScene` of ``kind`` ("glossy", "metal" or "mixed")."""
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown bench scene {kind!r}; expected one of {SCENE_KINDS}")
    g = torch.Generator().manual_seed(seed)
    dirs = pano.directions(H, W, dtype=torch.float64)
    depth = 1.5 + 2.0 * _smooth_field(g, 1, H, W, (4, 8))
    # normals: facing the camera, tilted by a smooth random field, kept away from grazing
    tilt = (_smooth_field(g, 3, H, W, (8, 16)) - 0.5) * 2.4
    n = F.normalize(-dirs + tilt, dim=0)
    nv = (n * -dirs).sum(0, keepdim=True)
    n = torch.where(nv < 0.1, F.normalize(n + (0.1 - nv + 0.05) * -dirs, dim=0), n)
    albedo = 0.15 + 0.8 * _smooth_field(g, 3, H, W, (6, 12))
    r = _smooth_field(g, 1, H, W, (6, 12))
    m = _smooth_field(g, 1, H, W, (6, 12))
    masks = {}
    if kind == "glossy":
        rough, metal = 0.2 + 0.4 * r, torch.zeros_like(m)
    elif kind == "metal":
        rough, metal = 0.1 + 0.4 * r, torch.ones_like(m)
    else:
        rough, metal = r, (m > 0.6).double()
        e = _smooth_field(g, 1, H, W, (6, 12))
        masks["emission"] = (e > 0.85).float()
        masks["invalid"] = (e < 0.08).float()
    probes = _probes(g, dirs, depth, H // block, W // block, probe_size)
    image = torch.zeros(3, H, W)
    return PanoScene(image=image, depth=depth.float(), normal=n.float(), albedo=albedo.float(),
                     roughness=rough.float(), metallic=metal.float(), probes=probes.float(),
                     masks=masks, meta={"bench": kind})


def _probes(g: torch.Generator, dirs: Tensor, depth: Tensor, Hp: int, Wp: int,
            size: tuple[int, int]) -> Tensor:
    H, W = dirs.shape[-2:]
    # probe positions: the surface point at the centre of each block
    centres = pano.resize_area(dirs * depth, Hp, Wp)  # [3, Hp, Wp] block-mean points
    pos = centres.permute(1, 2, 0).reshape(-1, 1, 1, 3)  # [N, 1, 1, 3]
    h, w = size
    d = pano.directions(h, w, dtype=torch.float64).permute(1, 2, 0)  # [h, w, 3]
    # ambient: sky-ish gradient, warmer below
    up = d[..., 1:2]
    amb = 0.25 + 0.15 * up + torch.tensor([0.05, 0.03, 0.0], dtype=torch.float64) * (1 - up)
    out = amb.expand(pos.shape[0], h, w, 3).clone()
    for _ in range(3):
        src = (torch.rand(3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([6.0, 1.5, 6.0])
        src[1] += 1.5
        col = 0.6 + 0.4 * torch.rand(3, generator=g, dtype=torch.float64)
        power = 40.0 + 60.0 * float(torch.rand(1, generator=g))
        to = src - pos  # [N,1,1,3]
        dist = to.norm(dim=-1, keepdim=True).clamp(min=0.3)
        c = (to / dist * d).sum(-1, keepdim=True)
        kappa = (dist / 0.25) ** 2  # ~ source radius 0.25 m
        out += power / dist**2 * col * torch.exp(kappa * (c - 1))
    return out.reshape(Hp, Wp, h, w, 3).permute(0, 1, 4, 2, 3).contiguous()


def shaded_mask(scene: PanoScene) -> Tensor:
    """``[1, H, W]``: one where the benchmark measures errors (neither emissive nor invalid), else zero."""
    m = torch.ones_like(scene.image[:1])
    for name in ("emission", "invalid"):
        if name in scene.masks:
            m = m * (scene.masks[name] <= 0.5)
    return m
