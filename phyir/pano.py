"""Equirectangular geometry: the single implementation of the panorama mapping (docs/conventions.md).

Pixel (i, j) of an H x W panorama has centre direction
    lon = 2*pi*(j + 0.5)/W - pi,  lat = pi/2 - pi*(i + 0.5)/H,
    d = (cos(lat) sin(lon), sin(lat), -cos(lat) cos(lon)),
so the image centre looks along -z, column 3W/4 along +x and the top row toward +y (y up).
Continuous pixel coordinates (u, v) = (j + 0.5, i + 0.5) at pixel centres; u in [0, W), v in [0, H).
All functions accept optional leading batch dimensions and work on any device.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

# ---------------------------------------------------------------------------------------------
# pixel <-> angles <-> direction


def lonlat_to_dir(lon: Tensor, lat: Tensor, dim: int = 0) -> Tensor:
    """Unit direction for longitude/latitude (radians), stacked along ``dim``."""
    c = torch.cos(lat)
    return torch.stack((c * torch.sin(lon), torch.sin(lat), -c * torch.cos(lon)), dim=dim)


def dir_to_lonlat(d: Tensor, dim: int = 0) -> tuple[Tensor, Tensor]:
    """Longitude in (-pi, pi] and latitude in [-pi/2, pi/2] of (not necessarily unit) directions."""
    x, y, z = d.unbind(dim)
    lon = torch.atan2(x, -z)
    r = torch.sqrt(x * x + z * z)
    lat = torch.atan2(y, r)
    return lon, lat


def uv_to_lonlat(u: Tensor, v: Tensor, H: int, W: int) -> tuple[Tensor, Tensor]:
    """Continuous pixel coordinates (u along width, v along height) to longitude/latitude."""
    return 2 * math.pi * u / W - math.pi, math.pi / 2 - math.pi * v / H


def lonlat_to_uv(lon: Tensor, lat: Tensor, H: int, W: int) -> tuple[Tensor, Tensor]:
    """Longitude/latitude to continuous pixel coordinates (u wraps into [0, W))."""
    u = torch.remainder((lon + math.pi) * (W / (2 * math.pi)), W)
    v = (math.pi / 2 - lat) * (H / math.pi)
    return u, v


def dir_to_uv(d: Tensor, H: int, W: int, dim: int = 0) -> tuple[Tensor, Tensor]:
    """Direction to continuous pixel coordinates of an H x W panorama."""
    return lonlat_to_uv(*dir_to_lonlat(d, dim), H, W)


def uv_to_dir(u: Tensor, v: Tensor, H: int, W: int, dim: int = 0) -> Tensor:
    return lonlat_to_dir(*uv_to_lonlat(u, v, H, W), dim=dim)


def pixel_lonlat(H: int, W: int, device=None, dtype=torch.float32) -> tuple[Tensor, Tensor]:
    """Longitude and latitude of every pixel centre, each [H, W]."""
    j = torch.arange(W, device=device, dtype=torch.float64) + 0.5
    i = torch.arange(H, device=device, dtype=torch.float64) + 0.5
    lon, lat = uv_to_lonlat(j, i, H, W)
    lat, lon = torch.meshgrid(lat, lon, indexing="ij")
    return lon.to(dtype), lat.to(dtype)


def directions(H: int, W: int, device=None, dtype=torch.float32) -> Tensor:
    """Unit direction of every pixel centre, [3, H, W] (computed in float64, then cast)."""
    j = torch.arange(W, device=device, dtype=torch.float64) + 0.5
    i = torch.arange(H, device=device, dtype=torch.float64) + 0.5
    lon, lat = uv_to_lonlat(j, i, H, W)
    lat, lon = torch.meshgrid(lat, lon, indexing="ij")
    return lonlat_to_dir(lon, lat, dim=0).to(dtype)


def solid_angles(H: int, W: int, device=None, dtype=torch.float32) -> Tensor:
    """Exact solid angle of every pixel, [H, W]; sums to 4*pi."""
    edges = math.pi / 2 - math.pi * torch.arange(H + 1, device=device, dtype=torch.float64) / H
    band = torch.sin(edges[:-1]) - torch.sin(edges[1:])
    return (band * (2 * math.pi / W))[:, None].expand(H, W).to(dtype).contiguous()


# ---------------------------------------------------------------------------------------------
# depth <-> points


def depth_to_points(depth: Tensor) -> Tensor:
    """Radial depth [..., 1, H, W] to camera-centred world points [..., 3, H, W]."""
    H, W = depth.shape[-2:]
    return depth * directions(H, W, depth.device, depth.dtype)


def points_to_uv(points: Tensor, H: int, W: int, dim: int = 0) -> tuple[Tensor, Tensor, Tensor]:
    """World points to (u, v, radial distance) in an H x W panorama seen from the origin."""
    return (*dir_to_uv(points, H, W, dim), torch.linalg.vector_norm(points, dim=dim))


def normals_from_depth(depth: Tensor) -> Tensor:
    """Unit normals [..., 3, H, W] from radial depth [..., 1, H, W], facing the camera.

    Cross product of one-sided differences of the 3D points; the longitude neighbours wrap around
    the seam.  In each direction the side whose points continue most straight (smaller second
    difference relative to the step) is used, so creases (wall corners, object edges) don't
    smear across the discontinuity.  The pole rows use their only side.
    """
    p = depth_to_points(depth)
    H = p.shape[-2]
    def col(k):  # p at column j + k (wraps)
        return torch.roll(p, -k, dims=-1)
    def row(k):
        return p[..., (torch.arange(H, device=p.device) + k).clamp(0, H - 1), :]
    du = _straighter_side(col(1) - p, col(2) - col(1), p - col(-1), col(-1) - col(-2))
    # rows: steps past a pole don't exist; the side missing fewer of them is used
    i = torch.arange(H, device=p.device, dtype=p.dtype)[:, None]
    missing_down = (i >= H - 2).to(p.dtype) + (i >= H - 1).to(p.dtype)
    missing_up = (i <= 1).to(p.dtype) + (i <= 0).to(p.dtype)
    dv = _straighter_side(row(1) - p, row(2) - row(1), p - row(-1), row(-1) - row(-2),
                          missing_down, missing_up)
    n = torch.cross(dv, du, dim=-3)
    n = n / _norm(n).clamp_min(1e-12)
    # face the camera: the normal points against the viewing ray
    flip = (n * p).sum(-3, keepdim=True) > 0
    return torch.where(flip, -n, n)


SIDE_SHARPNESS = 8.0  # normals_from_depth: how sharply the straighter side wins (4: a box room's
# creases smear 1.3 % of pixels past 1 degree, 8: 0.5 %)
SIDE_TIE = 1e-6  # bend (relative to the step) below which two sides count as equally straight


def _straighter_side(a1: Tensor, a2: Tensor, b1: Tensor, b2: Tensor, missing_a: Tensor | float = 0.0,
                     missing_b: Tensor | float = 0.0) -> Tensor:
    """The step a1 (followed by a2) or b1 (followed by b2) whose continuation bends least, blended
    smoothly: weights 1 / (1 + (cost / other cost)^SIDE_SHARPNESS), so at a crease (one side bending
    ten times more) the other side keeps a weight of 1e-8, while near a tie the two sides average
    instead of one flipping to the other on the last bit of the input (a hard choice made the
    depth-only fallback of predict move 5 % under a 1e-7 change of the input). ``missing_*`` count
    the steps a side lacks (past a pole): the side missing fewer wins outright."""
    # squared bends (no square root, whose gradient is infinite where a side is exactly straight)
    bend_a = _sq(a2 - a1) / (_sq(a1) + 1e-24) + SIDE_TIE ** 2
    bend_b = _sq(b2 - b1) / (_sq(b1) + 1e-24) + SIDE_TIE ** 2
    # clamped so the power stays finite in float32 (and gradients too): 1e4 ** 8 gives a weight of 1e-32
    ratio = (bend_a / bend_b).clamp(1e-8, 1e8)
    w_a = 1 / (1 + ratio.pow(SIDE_SHARPNESS / 2))
    ma, mb = torch.as_tensor(missing_a, dtype=w_a.dtype), torch.as_tensor(missing_b, dtype=w_a.dtype)
    w_a = torch.where(ma < mb, torch.ones_like(w_a), torch.where(ma > mb, torch.zeros_like(w_a), w_a))
    return w_a * a1 + (1 - w_a) * b1


def _sq(x: Tensor) -> Tensor:
    return (x * x).sum(-3, keepdim=True)


def _norm(x: Tensor) -> Tensor:
    # sqrt of a sum: torch's CPU vector_norm over a non-innermost axis is ~20x slower
    return torch.sqrt((x * x).sum(-3, keepdim=True))


# ---------------------------------------------------------------------------------------------
# sampling an equirect image at continuous coordinates


def bilinear_taps(u: Tensor, v: Tensor, h: int, w: int) -> tuple[Tensor, Tensor]:
    """The four texels and weights of a bilinear look-up in an ``h x w`` equirect image.

    ``u``/``v`` are continuous pixel coordinates of any shape ``S``; returns flat row-major texel
    indices (long) and weights, each ``[*S, 4]``, ordered (y0,x0), (y0,x1), (y1,x0), (y1,x1).
    Wraps in longitude, clamps at the poles; the weights are differentiable in ``u``/``v``.
    """
    x = u - 0.5
    y = (v - 0.5).clamp(0, h - 1)
    x0 = torch.floor(x)
    y0 = torch.floor(y).clamp(max=max(h - 2, 0))
    fx, fy = x - x0, y - y0
    x0 = torch.remainder(x0.long(), w)
    x1 = torch.remainder(x0 + 1, w)
    y0 = y0.long()
    y1 = (y0 + 1).clamp(max=h - 1)
    idx = torch.stack((y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1), dim=-1)
    wgt = torch.stack(((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy), dim=-1)
    return idx, wgt


def sample_bilinear(img: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear look-up of ``img [*B, C, h, w]`` at continuous pixel coordinates ``u, v [*B, *S]``.

    Wraps in longitude, clamps at the poles.  ``u``/``v`` carry exactly img's batch dims ``*B``
    first (use an empty ``*B`` for an unbatched image); returns ``[*B, C, *S]``.
    """
    h, w = img.shape[-2:]
    nb = img.dim() - 3
    S = u.shape[nb:]
    idx, wgt = bilinear_taps(u, v, h, w)
    flat = img.flatten(-2)  # [*B, C, h*w]
    C = flat.shape[-2]

    def take(k: int) -> Tensor:
        i = idx[..., k].reshape(*idx.shape[:nb], 1, -1).expand(*flat.shape[:-1], -1)
        return torch.gather(flat, -1, i).reshape(*flat.shape[:-1], *S) * wgt[..., k].unsqueeze(nb)

    out = take(0) + take(1) + take(2) + take(3)
    assert out.shape[nb] == C
    return out


def sample_dir(img: Tensor, d: Tensor, dim: int = 0) -> Tensor:
    """Bilinear look-up of equirect ``img [..., C, h, w]`` in directions ``d`` (vector axis ``dim``)."""
    h, w = img.shape[-2:]
    u, v = dir_to_uv(d, h, w, dim)
    return sample_bilinear(img, u, v)


# ---------------------------------------------------------------------------------------------
# padding, rotation, resampling


def circular_pad(x: Tensor, pad: int | tuple[int, int, int, int]) -> Tensor:
    """Pad [..., H, W] for convolutions: wrap in longitude, replicate at the poles.

    ``pad`` is an int or (left, right, top, bottom).
    """
    l, r, t, b = (pad,) * 4 if isinstance(pad, int) else pad
    if l or r:
        x = torch.cat([x[..., x.shape[-1] - l :]] * bool(l) + [x] + [x[..., :r]] * bool(r), dim=-1)
    if t or b:
        x = torch.cat([x[..., :1, :].expand(*x.shape[:-2], t, x.shape[-1])] * bool(t) + [x]
                      + [x[..., -1:, :].expand(*x.shape[:-2], b, x.shape[-1])] * bool(b), dim=-2)
    return x


def yaw_matrix(angle: float, dtype=torch.float32, device=None) -> Tensor:
    """Rotation about +y by ``angle`` radians (right-handed; +x toward -z for angle > 0)."""
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=dtype, device=device)


def rotate_vectors(m: Tensor, vec: Tensor, dim: int = -3) -> Tensor:
    """Apply a 3x3 matrix to the vector axis ``dim`` of ``vec``."""
    v = vec.movedim(dim, -1)
    return (v @ m.T.to(v)).movedim(-1, dim)


def yaw_shift_angle(shift: int, W: int) -> float:
    """World rotation (about +y) equivalent to rolling a panorama by ``shift`` columns to the right.

    Rolling right by one column moves the content seen at lon to lon + 2*pi/W; a point at lon has
    x = sin(lon), -z = cos(lon), i.e. rotation by -2*pi*shift/W with :func:`yaw_matrix`.
    """
    return -2 * math.pi * shift / W


def resize_area(x: Tensor, H: int, W: int) -> Tensor:
    """Resample [..., C, h, w] to H x W.

    Downsampling by integer factors is an exact box filter weighted by pixel solid angle (pixels
    near the poles cover less of the sphere), so the radiance integral sum(L * dOmega) is kept;
    other sizes use bilinear interpolation with longitude wrap (via padding), preceded by the same
    weighted box pre-filter when shrinking.
    """
    h, w = x.shape[-2:]
    if (h, w) == (H, W):
        return x
    lead = x.shape[:-3]
    y = x.reshape(-1, *x.shape[-3:])
    area = solid_angles(h, w, x.device, x.dtype)

    def area_pool(t: Tensor, k: tuple[int, int], ceil: bool = False) -> Tensor:
        return F.avg_pool2d(t * area, k, ceil_mode=ceil) / F.avg_pool2d(area[None, None], k, ceil_mode=ceil)

    if h % H == 0 and w % W == 0:
        y = area_pool(y, (h // H, w // W))
    else:
        if h > H or w > W:
            kh, kw = max(1, h // H), max(1, w // W)
            if kh > 1 or kw > 1:
                y = area_pool(y, (kh, kw), ceil=True)
        y = circular_pad(y, (1, 1, 0, 0))
        hh, ww = y.shape[-2:]
        # map target pixel centres to padded source coordinates
        j = (torch.arange(W, device=x.device, dtype=x.dtype) + 0.5) * ((ww - 2) / W) + 1 - 0.5
        i = (torch.arange(H, device=x.device, dtype=x.dtype) + 0.5) * (hh / H) - 0.5
        gx = (j + 0.5) / ww * 2 - 1
        gy = ((i + 0.5) / hh * 2 - 1).clamp(-1 + 1 / hh, 1 - 1 / hh)
        grid = torch.stack(torch.meshgrid(gy, gx, indexing="ij")[::-1], dim=-1)
        y = F.grid_sample(y, grid.expand(y.shape[0], H, W, 2), mode="bilinear",
                          padding_mode="border", align_corners=False)
    return y.reshape(*lead, *y.shape[-3:])


def perspective_dirs(H: int, W: int, fov_y_deg: float, yaw: float = 0.0, pitch: float = 0.0,
                     device=None, dtype=torch.float32) -> Tensor:
    """World directions [3, H, W] of a pinhole camera at the origin (looking along -z at yaw=pitch=0).

    ``yaw`` turns toward +x for positive values (radians); ``pitch`` looks up for positive values.
    """
    f = 0.5 * H / math.tan(math.radians(fov_y_deg) / 2)
    x = (torch.arange(W, device=device, dtype=dtype) + 0.5 - W / 2) / f
    y = (H / 2 - torch.arange(H, device=device, dtype=dtype) - 0.5) / f
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    d = F.normalize(torch.stack((xx, yy, -torch.ones_like(xx))), dim=0)
    cp, sp = math.cos(pitch), math.sin(pitch)
    pitch_m = torch.tensor([[1, 0, 0], [0, cp, -sp], [0, sp, cp]], dtype=dtype, device=device)
    # yaw toward +x: rotation by -yaw about +y in yaw_matrix's sense
    m = yaw_matrix(-yaw, dtype, device) @ pitch_m
    return rotate_vectors(m, d, dim=0)


def perspective_crop(img: Tensor, H: int, W: int, fov_y_deg: float = 60.0, yaw: float = 0.0,
                     pitch: float = 0.0) -> Tensor:
    """Render a pinhole view [..., C, H, W] of an equirect image (bilinear look-ups)."""
    d = perspective_dirs(H, W, fov_y_deg, yaw, pitch, img.device, img.dtype)
    return sample_dir(img, d, dim=0)
