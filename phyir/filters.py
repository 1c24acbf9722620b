"""Image filters on equirect panoramas (wrapping in longitude): box sums, the guided filter and
guided upsampling — the one implementation each, for GSNet and for inference."""

from __future__ import annotations

import torch
from torch import Tensor

from phyir import pano


def box_sum(x: Tensor, r: int) -> Tensor:
    """Sum over (2r+1)^2 windows of [..., H, W] via cumulative sums: wraps in longitude, rows outside
    the image count as zero.  O(1) per pixel whatever r."""
    H, W = x.shape[-2:]
    if 2 * r + 1 > W:
        raise ValueError(f"box_sum: radius {r} too large for width {W}")
    c = torch.cumsum(torch.cat((x[..., W - r:], x, x[..., :r]), dim=-1), dim=-1)
    c = torch.cat((torch.zeros_like(c[..., :1]), c), dim=-1)
    s = c[..., 2 * r + 1:] - c[..., :W]
    # rows: C[k] = cumsum up to row clamp(k - r, 0, H), so window row sums are C[i+2r+1] - C[i]
    c = torch.cumsum(s, dim=-2)
    c = torch.cat((torch.zeros_like(c[..., :1, :]).expand(*c.shape[:-2], r + 1, W), c,
                   c[..., -1:, :].expand(*c.shape[:-2], r, W)), dim=-2)
    return c[..., 2 * r + 1:, :] - c[..., :H, :]


def box_mean(x: Tensor, r: int) -> Tensor:
    """Mean over the (2r+1)^2 window around each pixel (truncated at the poles)."""
    H = x.shape[-2]
    i = torch.arange(H, device=x.device)
    rows = (i + r + 1).clamp(max=H) - (i - r).clamp(min=0)
    return box_sum(x, r) / (rows * (2 * r + 1)).to(x.dtype)[:, None]


def guided_filter(guide: Tensor, src: Tensor, eps: Tensor | float, r: int = 2) -> Tensor:
    """He et al.'s guided filter of ``src`` [B,C,H,W] by a one-channel ``guide`` [B,1,H,W].

    ``eps`` is a float or a per-pixel map [B,1,H,W] (applied at each window centre).
    """
    C = src.shape[1]
    m = box_mean(torch.cat((guide, guide * guide, src, guide * src), 1), r)  # one pass for all means
    mg, mgg, ms, mgs = m[:, :1], m[:, 1:2], m[:, 2:2 + C], m[:, 2 + C:]
    a = (mgs - mg * ms) / ((mgg - mg * mg).clamp(min=0) + eps)
    b = ms - a * mg
    mab = box_mean(torch.cat((a, b), 1), r)
    return mab[:, :C] * guide + mab[:, C:]


def guided_upsample(src: Tensor, guide_lo: Tensor, guide_hi: Tensor, r: int, eps: Tensor | float) -> Tensor:
    """Fast guided-filter upsampling (He & Sun 2015) of ``src [C,h,w]`` to the size of ``guide_hi
    [1,H,W]``: the local linear model src ≈ a·guide + b is fitted at low resolution (windows of
    (2r+1)², wrapping in longitude), its coefficients are upsampled, and applied to the full-resolution
    guide, so edges of the output follow edges of the image.  ``eps`` is a float or a map [1,h,w] at
    the low resolution (a large value makes the output the window's mean there, ignoring the image)."""
    H, W = guide_hi.shape[-2:]
    g, p = guide_lo, src
    m = box_mean(torch.cat((g, g * g, p, g * p)), r)
    C = p.shape[0]
    mg, mgg, mp, mgp = m[:1], m[1:2], m[2:2 + C], m[2 + C:]
    a = (mgp - mg * mp) / ((mgg - mg * mg).clamp_min(0) + eps)
    b = mp - a * mg
    ab = pano.resize_area(box_mean(torch.cat((a, b)), r), H, W)
    return ab[:C].mul_(guide_hi).add_(ab[C:])  # in place: a 360 camera's layers are 66 MB a channel
