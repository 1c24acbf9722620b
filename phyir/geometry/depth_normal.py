"""Depth–normal consistency on the panorama grid.

A plane with normal n through neighbouring pixels i, j satisfies n·P_i = n·P_j with P = r d, so
    log r_j - log r_i = log(-n·d_i) - log(-n·d_j):
normals predict the steps of log depth between neighbours. :func:`log_depth_steps` gives those steps
(the one formula, also used by the training loss), :func:`refine_depth` solves for the log depth that
follows them where depth and normals agree on a surface and stays near the predicted depth (a
screened Poisson problem, solved by conjugate gradients), so walls and floors come out planar.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.filters import guided_upsample

GRAZING = 0.08  # |n·d| below which a step is too ill-conditioned to use
CREASE_COS = 0.9  # neighbours whose normals differ by more than ~25° are not one surface


@dataclass(frozen=True)
class Steps:
    """Log-depth steps to the next column (wrapping) and the next row, with their weights in [0, 1]
    (0: no usable step). All [..., 1, H, W]; the last row's vertical step has weight 0."""

    gx: Tensor
    wx: Tensor
    gy: Tensor
    wy: Tensor


def _next_col(x: Tensor) -> Tensor:
    return torch.roll(x, -1, dims=-1)


def _next_row(x: Tensor) -> Tensor:
    return torch.cat((x[..., 1:, :], x[..., -1:, :]), dim=-2)


def _step(n_a: Tensor, n_b: Tensor, d_a: Tensor, d_b: Tensor) -> tuple[Tensor, Tensor]:
    n = F.normalize(n_a + n_b, dim=-3, eps=1e-8)
    ca = -(n * d_a).sum(-3, keepdim=True)
    cb = -(n * d_b).sum(-3, keepdim=True)
    same = ((n_a * n_b).sum(-3, keepdim=True) - CREASE_COS).clamp(0, 1) / (1 - CREASE_COS)
    ok = (ca > GRAZING) & (cb > GRAZING)
    g = torch.log(ca.clamp_min(GRAZING)) - torch.log(cb.clamp_min(GRAZING))
    return g, same * ok.to(g.dtype)


def log_depth_steps(normal: Tensor) -> Steps:
    """The steps of log radial depth that unit normals ``[..., 3, H, W]`` (facing the camera) imply."""
    H, W = normal.shape[-2:]
    d = pano.directions(H, W, normal.device, normal.dtype)
    gx, wx = _step(normal, _next_col(normal), d, _next_col(d))
    gy, wy = _step(normal, _next_row(normal), d, _next_row(d))
    last = torch.zeros_like(wy)
    last[..., -1, :] = 1
    return Steps(gx, wx, gy, wy * (1 - last))


def forward_differences(z: Tensor) -> tuple[Tensor, Tensor]:
    """Differences to the next column (wrapping) and the next row (0 in the last), as :class:`Steps`."""
    return _next_col(z) - z, _next_row(z) - z


def _div(fx: Tensor, fy: Tensor) -> Tensor:
    """Adjoint of :func:`forward_differences` (fy's last row must be 0)."""
    up = torch.cat((torch.zeros_like(fy[..., :1, :]), fy[..., :-1, :]), dim=-2)
    return torch.roll(fx, 1, dims=-1) - fx + up - fy


def occlusion_edges(log_depth: Tensor, normal: Tensor, tau: float) -> Tensor:
    """Where a log depth ``[..., 1, H, W]`` steps away from the surface its ``normal`` ``[..., 3, H, W]``
    describe, in [0, 1] per pixel: 1 - the :func:`agreement` falloff of either step touching the pixel,
    widened by one pixel.  ~0 inside surfaces and across creases the depth follows, ~1 at occlusion
    edges, where the depth may jump with the image."""
    steps = log_depth_steps(normal.to(log_depth.dtype))
    zx, zy = forward_differences(log_depth)
    ox = 1 - 1 / (1 + ((zx - steps.gx) / tau) ** 4)
    oy = 1 - 1 / (1 + ((zy - steps.gy) / tau) ** 4)
    oy[..., -1, :] = 0  # the last row has no step
    prev_row = torch.cat((torch.zeros_like(oy[..., :1, :]), oy[..., :-1, :]), dim=-2)
    edge = torch.maximum(torch.maximum(ox, torch.roll(ox, 1, dims=-1)), torch.maximum(oy, prev_row))
    lead = edge.shape[:-2]
    wide = F.max_pool2d(F.pad(edge.reshape(-1, 1, *edge.shape[-2:]), (1, 1, 0, 0), mode="circular"), 3, 1,
                        padding=(1, 0))
    return wide.reshape(*lead, *edge.shape[-2:])


def upsample_depth(depth: Tensor, guide_lo: Tensor, guide_hi: Tensor, *, normal: Tensor | None, r: int,
                   eps: float, tau: float, surface_eps: float) -> Tensor:
    """Radial ``depth [1,h,w]`` at the size of ``guide_hi [1,H,W]`` by guided upsampling of its log
    (:func:`phyir.filters.guided_upsample`, ``guide_lo`` the guide at the depth's size).  With the
    ``normal [3,h,w]`` that describe the depth, it follows the image's edges only at
    :func:`occlusion_edges`: inside surfaces the regulariser is ``eps + surface_eps``, so there the
    depth is the window's smooth mean and texture does not print into it."""
    z = torch.log(depth.clamp_min(1e-4))
    reg: Tensor | float = eps
    if normal is not None:
        reg = eps + (1 - occlusion_edges(z, normal.to(z.dtype), tau)) * surface_eps
    return torch.exp(guided_upsample(z, guide_lo, guide_hi, r, reg))


def agreement(log_depth: Tensor, steps: Steps, tau: float) -> tuple[Tensor, Tensor]:
    """Step weights times 1 / (1 + (e / tau)^4), e the depth's own step less the normals': ~0 past
    ``tau``, at occlusion edges, where no surface joins the two pixels (a fast falloff: a slower,
    Cauchy one, let small objects drift ~5 % toward the wall behind them)."""
    zx, zy = forward_differences(log_depth)
    ex, ey = zx - steps.gx, zy - steps.gy
    return steps.wx / (1 + (ex / tau) ** 4), steps.wy / (1 + (ey / tau) ** 4)


def refine_depth(depth: Tensor, normal: Tensor, *, anchor: float = 0.02, tau: float = 0.05,
                 iters: int = 200) -> Tensor:
    """Radial depth ``[..., 1, H, W]`` made consistent with ``normal`` ``[..., 3, H, W]``.

    Minimises ``sum w (grad z - g)^2 + anchor * sum cos(lat) (z - z0)^2`` over log depth z, with g the
    normals' steps, z0 the input's log depth and w the steps' weights times their :func:`agreement`
    with z0 (so occlusion edges stay where the depth put them). ``anchor`` sets how far
    (~1/sqrt(anchor) pixels at the equator) the normals may reshape the depth.
    """
    z0 = torch.log(depth.clamp_min(1e-6))
    steps = log_depth_steps(normal.to(z0.dtype))
    wx, wy = agreement(z0, steps, tau)
    # the anchor per unit solid angle: a pixel near a pole covers cos(latitude) of an equator pixel's
    # view, and there the network's depth is least reliable (the tripod, the stitch, the distortion)
    H, W = depth.shape[-2:]
    a = anchor * torch.cos(pano.pixel_lonlat(H, W, z0.device, z0.dtype)[1])[:, :1]
    def apply(z: Tensor) -> Tensor:
        zx, zy = forward_differences(z)
        return a * z + _div(wx * zx, wy * zy)
    b = a * z0 + _div(wx * steps.gx, wy * steps.gy)
    z = _conjugate_gradients(apply, b, z0, iters)
    return torch.exp(z)


def _conjugate_gradients(apply, b: Tensor, x: Tensor, iters: int, rtol: float = 1e-5) -> Tensor:
    """Solves apply(x) = b for a symmetric positive definite operator, batched over leading dims."""
    dims = tuple(range(-3, 0))
    r = b - apply(x)
    p = r
    rr = (r * r).sum(dims, keepdim=True)
    stop = rtol ** 2 * (b * b).sum(dims, keepdim=True)
    for _ in range(iters):
        if bool((rr <= stop).all()):
            break
        ap = apply(p)
        alpha = rr / (p * ap).sum(dims, keepdim=True).clamp_min(1e-30)
        x = x + alpha * p
        r = r - alpha * ap
        rr_new = (r * r).sum(dims, keepdim=True)
        p = r + (rr_new / rr.clamp_min(1e-30)) * p
        rr = rr_new
    return x
