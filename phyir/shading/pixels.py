"""Flat pixels: the G-buffer in the channels-last layout every shading path of
:mod:`phyir.shading.render` works on, and the scatter of per-class results back into it."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor


@dataclass
class Pixels:
    """Flat, channels-last pixel inputs: ``n, v [P, 3]``, ``base [P, 3]``, ``rough, metal [P, 1]``."""

    n: Tensor
    v: Tensor
    base: Tensor
    rough: Tensor
    metal: Tensor
    skip: Tensor  # [P] bool: no shading at all
    per_image: int  # pixels per image: pixel p draws the samples of pixel p % per_image


def flat(t: Tensor, B: int, C: int) -> Tensor:
    """``[B?, C|1, H, W]`` -> channels-last ``[B*H*W, C]``."""
    t = t.reshape(-1, *t.shape[-3:]) if t.dim() == 4 else t[None]
    return t.expand(B, C, *t.shape[-2:]).permute(0, 2, 3, 1).reshape(-1, C).contiguous()


def unflat(t: Tensor, B: int, H: int, W: int, batched: bool) -> Tensor:
    """Channels-last ``[B*H*W, C]`` -> ``[B, C, H, W]``, or ``[C, H, W]`` unless ``batched`` (:func:`flat`'s
    inverse)."""
    out = t.reshape(B, H, W, -1).permute(0, 3, 1, 2)
    return out if batched else out[0]


def flatten_pixels(normal: Tensor, view: Tensor, base_color: Tensor, roughness: Tensor, metallic: Tensor,
                   B: int, extra_skip: Tensor | None, dt: torch.dtype) -> Pixels:
    """The :class:`Pixels` of a G-buffer (``[B?, C, H, W]`` layers, in ``dt``): unit normals, pixels to
    skip (non-finite, ~zero normal, back-facing, or ``extra_skip [B*H*W]``) zeroed."""
    n = flat(normal.to(dt), B, 3)
    v = F.normalize(flat(view.to(dt), B, 3), dim=-1)
    base, rough, metal = (flat(x.to(dt), B, c) for x, c in ((base_color, 3), (roughness, 1), (metallic, 1)))
    with torch.no_grad():
        norm = torch.linalg.vector_norm(n, dim=-1)
        finite = torch.isfinite(torch.cat((n, v, base, rough, metal), -1)).all(-1)
        skip = ~finite | (norm < 1e-6)
    n = F.normalize(torch.where(skip[:, None], 0.0, n), dim=-1)
    with torch.no_grad():
        skip = skip | ((n * v).sum(-1) <= 0)
        if extra_skip is not None:
            skip = skip | extra_skip

    def clean(x: Tensor) -> Tensor:
        return torch.where(skip[:, None], 0.0, x)

    return Pixels(clean(n), v, clean(base), clean(rough), clean(metal), skip, n.shape[0] // B)


def select(t: Tensor, idx: Tensor) -> Tensor:
    """Rows ``idx`` of a flat per-pixel tensor."""
    return t.index_select(0, idx)


def assemble(P: int, idx: list[Tensor], d: list[Tensor], s: list[Tensor], dev, dt) -> tuple[Tensor, Tensor]:
    """(diffuse, specular) ``[P, 3]``: the parts ``d``, ``s`` scattered to their pixel rows ``idx``, zero
    elsewhere."""
    diffuse = torch.zeros(P, 3, device=dev, dtype=dt)
    spec = torch.zeros(P, 3, device=dev, dtype=dt)
    if idx:
        i = torch.cat(idx)
        diffuse = diffuse.index_add(0, i, torch.cat(d))
        spec = spec.index_add(0, i, torch.cat(s))
    return diffuse, spec
