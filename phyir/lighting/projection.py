"""Projection-based lighting: light probes read from the panorama itself by ray-marching its depth.

For a 3D point X in the room and a direction d, the radiance arriving at X from d is, where the camera
saw that surface, the panorama's own HDR radiance at the point where the ray X + t d meets the depth
surface r = D(direction).  The depth panorama is a closed, star-shaped surface around the camera, so
a ray that starts in the camera's free space (r < D) always crosses it; the first crossing is
bracketed by marching, then refined by bisection and a final secant step.

Where the camera could not see the hit, the probe texel is *unseen* and takes a fallback (LNet's
probe):
- the crossing lies on a depth discontinuity: the bilinear depth surface spans the jump with a
  "skirt" along the camera rays; a ray crossing it enters the region hidden behind the nearer
  surface (behind furniture), where an unseen occluder may sit;
- the point X itself is not in the camera's free space (r >= D at X).

Each sub-ray's radiance is read from a mip pyramid of the panorama at the level whose pixel matches
the ray's footprint on the surface (as the camera sees it), so a texel covering a small bright source
gets its area average rather than a point sample.  Texels can also be supersampled with s x s rays.
Limits: radiance is the camera's view of the surface, exact for diffuse surfaces only; unseen texels
are only as good as the fallback.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.color import clean_radiance, exposure_scale
from phyir.scene import PROBE_OFFSET, PanoScene, SceneError

# ---------------------------------------------------------------------------------------------
# textures: equirect images padded by one column on each side so grid_sample wraps in longitude


def _pad(img: Tensor) -> Tensor:
    """[C,H,W] -> [1,C,H,W+2] with wrapped columns (rows clamp via grid_sample's border mode)."""
    return pano.circular_pad(img[None], (1, 1, 0, 0))


def _lookup(tex: Tensor, u: Tensor, v: Tensor, mode: str = "bilinear") -> Tensor:
    """Look up a padded texture [1,C,H,W+2] at continuous pixel coordinates u, v [M] -> [C, M]."""
    H, Wp = tex.shape[-2:]
    gx = (u + 1) * (2 / Wp) - 1
    gy = v * (2 / H) - 1
    grid = torch.stack((gx, gy), -1).view(1, 1, -1, 2).to(tex.dtype)
    out = F.grid_sample(tex, grid, mode=mode, padding_mode="border", align_corners=False)
    return out[0, :, 0]


def _norm0(p: Tensor) -> Tensor:
    """Length of vectors along axis 0 of [3,...] (linalg.vector_norm over a leading axis is ~20x slower)."""
    x, y, z = p.unbind(0)
    return torch.sqrt(x * x + y * y + z * z)


def _unit0(p: Tensor) -> Tensor:
    return p / _norm0(p).clamp_min(1e-12)


MIN_GRAZING_DEG = 10.0
# the radiance mips start at most this many rows (0.18 degrees a pixel): a probe texel or a viewer
# look-up covers degrees, and a 360-camera JPEG's full 2880 rows cost seconds and a gigabyte here
MAX_MIP_HEIGHT = 1024


def jump_threshold(H: int, min_grazing_deg: float = MIN_GRAZING_DEG) -> float:
    """Relative depth step between neighbouring pixels (of an H-row panorama) above which a surface
    counts as discontinuous: a continuous surface seen at grazing angle γ steps by about Δθ / tan γ."""
    return (math.pi / H) / math.tan(math.radians(min_grazing_deg))


def _cell_jump(depth: Tensor) -> Tensor:
    """Relative depth jump max/min - 1 over each bilinear cell [1,H,W] (cell (i,j) spans pixel
    centres (i..i+1, j..j+1), wrapping in longitude, clamped at the bottom row)."""
    d = depth.clamp_min(1e-6)
    right = torch.roll(d, -1, dims=-1)
    down = torch.cat((d[:, 1:], d[:, -1:]), dim=1)
    diag = torch.roll(down, -1, dims=-1)
    stack = torch.stack((d, right, down, diag))
    return stack.amax(0) / stack.amin(0) - 1


@dataclass
class DepthSurface:
    """A panorama prepared for ray marching (depth) and filtered radiance look-ups (image mips).

    Build once per scene with :meth:`from_scene` and reuse it for many queries (e.g. the viewer
    moving an inserted object).
    """

    depth_tex: Tensor  # [1,1,Hm,Wm+2] radial depth at the marching resolution
    jump_tex: Tensor  # [1,1,Hm,Wm+2] relative depth jump of the cell whose top-left is each pixel
    normal_tex: Tensor  # [1,3,Hm,Wm+2] surface normals (footprint foreshortening)
    mips: list[Tensor]  # [1,3,H_l,W_l+2] radiance, level 0 = the input resolution
    r_bound: float  # radius of a sphere around the camera containing the whole depth surface
    jump_threshold: float  # cells with a larger relative jump are discontinuities
    sources: BrightSources | None = None  # bright radiance splatted instead of ray-sampled
    # mips and sources are stored x this (median luminance -> KEY): sums of extreme HDR radiance
    # over many rays stay inside float32's range; project_probes gives results in the scene's units
    radiance_scale: float = 1.0

    @staticmethod
    def from_scene(scene: PanoScene, *, march_height: int = 256, min_grazing_deg: float = MIN_GRAZING_DEG,
                   bright_factor: float = 8.0, max_sources: int = 64) -> DepthSurface:
        """``march_height``: depth rows used for marching (the depth is area-downsampled to at most
        this); ``min_grazing_deg``: surfaces seen by the camera at a grazing angle below this are
        treated as discontinuities (a jump of more than Δθ / tan(angle) between neighbouring pixels).
        Radiance above ``bright_factor`` times the panorama's mean becomes at most ``max_sources``
        point sources (see :func:`bright_sources`); ``bright_factor=inf`` turns that off.
        """
        if scene.batched:
            raise SceneError("projection: expected an unbatched scene")
        if scene.depth is None:
            raise SceneError("projection: the scene has no depth")
        depth = scene.depth.float()
        H, W = depth.shape[-2:]
        Hm = min(H, march_height)
        Wm = round(W * Hm / H)
        dm = pano.resize_area(depth, Hm, Wm) if (Hm, Wm) != (H, W) else depth
        dm = torch.nan_to_num(dm, nan=0.0).clamp_min(1e-3)
        img = clean_radiance(scene.image)
        scale = float(exposure_scale(img))
        img = (img * scale).contiguous()  # ours: the bright sources are taken out of it in place
        # (unit normals where they are used: the bright pixels' and the march grid's, not a full-size copy)
        normal = pano.normals_from_depth(depth) if scene.normal is None else scene.normal
        sources = None
        if math.isfinite(bright_factor):
            sources = _take_bright_sources(img, depth, normal, bright_factor, max_sources)
        if img.shape[-2] > MAX_MIP_HEIGHT:  # finer than any look-up's footprint (bright sources: above)
            size = (MAX_MIP_HEIGHT, round(W * MAX_MIP_HEIGHT / H))  # a channel at a time: 66 MB, not 200
            img = torch.cat([pano.resize_area(c[None], *size) for c in img])
        mips = [_pad(img)]
        while img.shape[-2] >= 4 and img.shape[-2] % 2 == 0 and img.shape[-1] % 2 == 0:
            img = F.avg_pool2d(img[None], 2)[0]
            mips.append(_pad(img))
        jump = _cell_jump(dm)
        nm = _unit0(torch.nan_to_num(pano.resize_area(normal.float(), Hm, Wm)))
        return DepthSurface(
            depth_tex=_pad(dm), jump_tex=_pad(jump), normal_tex=_pad(nm), mips=mips,
            r_bound=float(dm.max()) * 1.02 + 1e-3,
            jump_threshold=jump_threshold(Hm, min_grazing_deg),
            sources=sources, radiance_scale=scale,
        )

    @property
    def march_size(self) -> tuple[int, int]:
        return self.depth_tex.shape[-2], self.depth_tex.shape[-1] - 2

    # -- geometry ------------------------------------------------------------------------------
    def gap(self, p: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """f = |p| - D(dir p) for points p [3,M] (negative in the camera's free space), and u, v."""
        Hm, Wm = self.march_size
        u, v = pano.dir_to_uv(p, Hm, Wm, dim=0)
        return _norm0(p) - _lookup(self.depth_tex, u, v)[0], u, v

    def trace(self, origins: Tensor, dirs: Tensor, *, steps: int = 32, power: float = 1.5,
              refine: int = 7) -> tuple[Tensor, Tensor]:
        """First crossing of rays ``origins + t dirs`` ([3,M] each, unit dirs) with the depth surface.

        Returns ``t [M]`` (the hit distance, NaN where none was found) and ``seen [M]`` (bool: the ray
        starts in the camera's free space and hits a continuous part of the surface).
        Samples t_k = t_exit (k/steps)^power, denser near the origin where the nearby surface is.
        """
        M = origins.shape[1]
        dev, dt = origins.device, origins.dtype
        # the ray leaves the bounding sphere at t_exit; there r > D, so a crossing precedes it
        b = (origins * dirs).sum(0)
        c = (origins * origins).sum(0) - self.r_bound**2
        t_exit = -b + torch.sqrt((b * b - c).clamp_min(0))
        f0 = self.gap(origins)[0]
        # step index of the first sample past the surface (0 = none yet); the bracket is (k-1, k)
        k_hit = torch.zeros(M, dtype=torch.int16, device=dev)
        # The marching set; finished rays stay in it (masked by `done`) until enough have finished
        # to pay for compaction: gathers cost more than a few elementwise ops.
        idx = torch.nonzero(f0 < 0).squeeze(1)  # rays starting in unseen space never count
        o, d, te = origins[:, idx], dirs[:, idx], t_exit[idx]
        done = torch.zeros(idx.numel(), dtype=torch.bool, device=dev)
        kh = torch.zeros(idx.numel(), dtype=torch.int16, device=dev)
        for k in range(1, steps + 1):
            f = self.gap(o + (te * (k / steps) ** power) * d)[0]
            new = (f >= 0) & ~done
            kh.masked_fill_(new, k)
            done |= new
            if k == steps or int(done.sum()) > 0.5 * done.numel():
                k_hit[idx[done]] = kh[done]
                live = ~done
                idx, o, d, te, kh = idx[live], o[:, live], d[:, live], te[live], kh[live]
                done = done[live]
                if idx.numel() == 0:
                    break
        found = torch.nonzero(k_hit > 0).squeeze(1)
        kf = k_hit[found].to(dt)
        te = t_exit[found]
        lo, hi = te * ((kf - 1) / steps) ** power, te * (kf / steps) ** power
        o, d = origins[:, found], dirs[:, found]
        for _ in range(refine):  # bisection: the bracket shrinks 2^refine times
            mid = 0.5 * (lo + hi)
            up = self.gap(o + mid * d)[0] >= 0
            hi = torch.where(up, mid, hi)
            lo = torch.where(up, lo, mid)
        t_hit = 0.5 * (lo + hi)
        _, u, v = self.gap(o + t_hit * d)
        # a crossing on a skirt between depth layers enters space the camera did not see
        continuous = _lookup(self.jump_tex, u - 0.5, v - 0.5, mode="nearest")[0] <= self.jump_threshold
        t_out = torch.full((M,), math.nan, device=dev, dtype=dt)
        t_out[found] = t_hit
        seen = torch.zeros(M, dtype=torch.bool, device=dev)
        seen[found] = continuous
        return t_out, seen

    # -- radiance ------------------------------------------------------------------------------
    def footprint(self, points: Tensor, dirs: Tensor, t: Tensor, omega: Tensor) -> Tensor:
        """Solid angle [M] that the camera sees of the surface patch a ray cone of solid angle
        ``omega`` cuts at distance ``t`` along ``dirs`` at ``points`` [3,M]: omega t² / r² times the
        foreshortening ratio cos(camera) / cos(ray) (clamped to [1/8, 8] at grazing angles)."""
        Hm, Wm = self.march_size
        u, v = pano.dir_to_uv(points, Hm, Wm, dim=0)
        n = _lookup(self.normal_tex, u, v)
        r = _norm0(points).clamp_min(1e-6)
        cos_cam = (n * points).sum(0).abs() / r
        cos_ray = (n * dirs).sum(0).abs()
        ratio = (cos_cam / cos_ray.clamp_min(1e-6)).clamp(0.125, 8.0)
        return omega * (t / r) ** 2 * ratio

    def radiance(self, points: Tensor, footprint: Tensor) -> Tensor:
        """Panorama radiance [3,M] at surface points [3,M], area-averaged over ``footprint`` [M]: the
        solid angle (as seen by the camera) each look-up should cover.  Trilinear in the mip levels."""
        H0, W0 = self.mips[0].shape[-2], self.mips[0].shape[-1] - 2
        u, v = pano.dir_to_uv(points, H0, W0, dim=0)  # (the distance is not needed)
        lat = math.pi / 2 - math.pi * v / H0
        pix = (2 * math.pi / W0) * (math.pi / H0) * torch.cos(lat).clamp_min(1.0 / H0)
        level = (0.5 * torch.log2(footprint.clamp_min(1e-30) / pix)).clamp(0, len(self.mips) - 1)
        out = torch.zeros(3, points.shape[1], device=points.device, dtype=points.dtype)
        for lv, tex in enumerate(self.mips):
            w = 1 - (level - lv).abs()
            sel = torch.nonzero(w > 0).squeeze(1)
            if sel.numel() == 0:
                continue
            s = 2.0**-lv  # continuous coordinates scale with the level's size
            out[:, sel] += w[sel] * _lookup(tex, u[sel] * s, v[sel] * s).to(out.dtype)
        return out


# ---------------------------------------------------------------------------------------------
# bright sources: splatted with exact power instead of ray-sampled


@dataclass
class BrightSources:
    """Small bright regions of the panorama as point sources [3,S] each: the power-weighted centroid
    ``pos``, mean ``normal`` and ``power`` = sum of radiance x surface area (W/sr per channel)."""

    pos: Tensor
    normal: Tensor
    power: Tensor

    def __len__(self) -> int:
        return self.pos.shape[1]


FACING_COS = 0.2  # a visible surface faces the camera: normals turned further away are not trusted


def facing_normals(normal: Tensor, points: Tensor, min_cos: float = FACING_COS) -> Tensor:
    """Normals ``[3,...]`` of surface ``points`` the camera sees, with those that face away from the
    camera (cos below ``min_cos``, impossible for a visible surface: a collapsed normal layer, a lamp
    predicted as floor) replaced by the direction to the camera.  Keeps a light's power finite and
    its emission toward the camera, where the camera did see it."""
    to_cam = -_unit0(points)
    ok = (normal * to_cam).sum(0, keepdim=True) >= min_cos
    return torch.where(ok, normal, to_cam)


def bright_sources(image: Tensor, depth: Tensor, normal: Tensor, factor: float = 8.0,
                   max_sources: int = 64) -> tuple[Tensor, BrightSources | None]:
    """Split ``image [3,H,W]`` into a base image and point sources for its bright part.

    A pixel whose luminance (channel mean) exceeds ``factor`` times the panorama's mean (over solid
    angle) keeps ``factor * mean`` of it in the base (colour preserved); the excess, times the
    surface area the pixel covers (Ω r² / cos), is gathered into the cells of a coarse grid (32 rows,
    halved until at most ``max_sources`` cells are lit).  Ray-sampling a texel that covers a small
    lamp is a gamble (hit or miss, or a filtered look-up that is wrong at grazing angles); splatting
    each source's power into the texel of its direction, after a visibility ray, is exact in energy.
    """
    base = image.clone(memory_format=torch.contiguous_format)
    return base, _take_bright_sources(base, depth, normal, factor, max_sources)


def _take_bright_sources(image: Tensor, depth: Tensor, normal: Tensor, factor: float,
                         max_sources: int) -> BrightSources | None:
    """:func:`bright_sources`, the excess taken out of ``image`` in place (a large panorama's copy
    costs hundreds of MB); ``image`` must be contiguous."""
    H, W = image.shape[-2:]
    omega = pano.solid_angles(H, W, image.device)
    lum = image.mean(0)
    thr = factor * float((lum * omega).sum() / omega.sum())
    # only the bright pixels (a small share of a large panorama) are turned into points and areas
    idx = torch.nonzero((lum > thr).reshape(-1)).squeeze(1)
    if idx.numel() == 0:  # (a black panorama has thr = 0 and no excess anywhere)
        return None
    flat = image.view(3, -1)
    excess = flat[:, idx] * (1 - thr / lum.reshape(-1)[idx])
    rows, cols = idx // W, idx % W
    d = depth.reshape(-1)[idx].float().clamp_min(1e-3)
    pts = d * pano.uv_to_dir(cols.double() + 0.5, rows.double() + 0.5, H, W, dim=0).float()
    n = facing_normals(_unit0(torch.nan_to_num(normal.reshape(3, -1)[:, idx].float())), pts)
    cos_cam = ((n * pts).sum(0).abs() / d).clamp_min(0.1)
    area = omega.reshape(-1)[idx] * d * d / cos_cam
    e = excess * area  # [3,M] radiance x area
    w = e.mean(0)  # centroid weights
    flat[:, idx] -= excess
    Hs = min(H, 32)
    while True:
        Ws = max(1, round(W * Hs / H))
        cell = rows * Hs // H * Ws + cols * Ws // W
        lit = torch.bincount(cell[w > 0], minlength=Hs * Ws) > 0
        if int(lit.sum()) <= max_sources or Hs <= 2:
            break
        Hs //= 2

    def pool(x: Tensor) -> Tensor:  # [C,M] -> [C, cells] sums
        out = torch.zeros(x.shape[0], Hs * Ws, device=x.device, dtype=x.dtype)
        return out.index_add_(1, cell, x)

    keep = torch.nonzero(lit).squeeze(1)
    wsum = pool(w[None])[:, keep]
    pos = pool(pts * w)[:, keep] / wsum
    nrm = _unit0(pool(n * w)[:, keep])
    power = pool(e)[:, keep]
    return BrightSources(pos, nrm, power)


# ---------------------------------------------------------------------------------------------
# probes


def probe_positions(depth: Tensor, normal: Tensor | None, grid: tuple[int, int],
                    offset: float = PROBE_OFFSET) -> Tensor:
    """3D positions [Hp,Wp,3] of a probe grid over a panorama (docs/conventions.md).

    Probe (a, b) sits at the surface point seen through the centre of block (a, b), moved ``offset``
    along the normal.  The centre's depth is bilinear, except across a depth jump (see
    :func:`jump_threshold`) where the nearest surface is taken so the probe doesn't float between
    foreground and background.  The normal is the nearest pixel's (``normal`` or, when None, normals
    from the depth); see :func:`offset_direction`.  Blocks may be fractional (any grid, any size).
    """
    Hp, Wp = grid
    H, W = depth.shape[-2:]
    dev = depth.device
    u = ((torch.arange(Wp, device=dev, dtype=torch.float32) + 0.5) * (W / Wp))[None].expand(Hp, Wp)
    v = ((torch.arange(Hp, device=dev, dtype=torch.float32) + 0.5) * (H / Hp))[:, None].expand(Hp, Wp)
    d = depth.float()
    bil = pano.sample_bilinear(d, u, v)[0]
    # the four pixels around the centre (the centre is a pixel corner when blocks are even-sized)
    i0 = (v - 0.5).floor().long().clamp(0, H - 1)
    j0 = torch.remainder((u - 0.5).floor().long(), W)
    i1 = (i0 + 1).clamp(max=H - 1)
    j1 = torch.remainder(j0 + 1, W)
    corners = torch.stack([d[0, i, j] for i in (i0, i1) for j in (j0, j1)])
    near = corners.amin(0)
    r = torch.where(corners.amax(0) > (1 + jump_threshold(H)) * near, near, bil)
    view = pano.uv_to_dir(u, v, H, W, dim=-1)
    n = pano.normals_from_depth(d) if normal is None else normal.float()
    ni = v.floor().long().clamp(0, H - 1)
    nj = torch.remainder(u.floor().long(), W)
    return r[..., None] * view + offset * offset_direction(n[:, ni, nj].movedim(0, -1), view)


def offset_direction(normal: Tensor, view: Tensor) -> Tensor:
    """Unit direction [...,3] to move a probe off the surface: the normal, or straight back toward
    the camera (-view) where the normal doesn't face the camera by at least 0.2 (a predicted normal
    can be wrong; the probe must stay in the space the camera saw)."""
    n = F.normalize(normal, dim=-1)
    facing = (n * view).sum(-1, keepdim=True) < -0.2
    return torch.where(facing, n, -view)


def surface_points(scene: PanoScene, u: Tensor, v: Tensor, offset: float = PROBE_OFFSET) -> Tensor:
    """3D points [N,3] on the surface seen at continuous pixel coordinates (u, v) [N], moved
    ``offset`` along the normal — where to put probes for chosen pixels."""
    H, W = scene.size
    r = pano.sample_bilinear(scene.depth.float(), u, v)[0]
    n = pano.normals_from_depth(scene.depth.float()) if scene.normal is None else scene.normal.float()
    view = pano.uv_to_dir(u, v, H, W, dim=-1)
    return r[:, None] * view + offset * offset_direction(pano.sample_bilinear(n, u, v).T, view)


def project_probes(scene: PanoScene | DepthSurface, points: Tensor, probe_size: tuple[int, int] = (16, 32),
                   fallback: Tensor | None = None, *, supersample: int = 1, steps: int = 32,
                   max_rays: int = 1 << 18) -> tuple[Tensor, Tensor]:
    """Light probes at 3D ``points [N,3]`` read from the panorama by projection.

    Returns ``probes [N,3,h,w]`` and ``visible [N,1,h,w]``: the solid-angle share of each texel whose
    rays hit surface the camera saw (each texel is traced with ``supersample``² rays).  Where a texel is
    partly or wholly unseen its unseen share comes from ``fallback [N,3,h,w]`` (e.g. LNet's probes):
    ``probe = visible * projected + (1 - visible) * fallback``; without a fallback that share is 0.
    Rays are processed ``max_rays`` at a time.
    """
    surf = scene if isinstance(scene, DepthSurface) else DepthSurface.from_scene(scene)
    dev = surf.depth_tex.device
    pts = points.to(dev, torch.float32).reshape(-1, 3)
    N = pts.shape[0]
    h, w = probe_size
    s = supersample
    hs, ws = h * s, w * s
    dirs = pano.directions(hs, ws, dev).reshape(3, -1)  # [3,R]
    omega = pano.solid_angles(hs, ws, dev).reshape(-1)  # [R]
    R = dirs.shape[1]
    per_chunk = max(1, max_rays // R)
    rad = torch.zeros(N, 3, hs, ws, device=dev)
    seen = torch.zeros(N, 1, hs, ws, device=dev)
    for start in range(0, N, per_chunk):
        x = pts[start:start + per_chunk]
        n = x.shape[0]
        o = x.T[:, :, None].expand(3, n, R).reshape(3, -1)
        d = dirs[:, None].expand(3, n, R).reshape(3, -1)
        t, ok = surf.trace(o, d, steps=steps)
        idx = torch.nonzero(ok).squeeze(1)
        hit = o[:, idx] + t[idx] * d[:, idx]
        footprint = surf.footprint(hit, d[:, idx], t[idx], omega.repeat(n)[idx])
        L = torch.zeros(3, n * R, device=dev)
        L[:, idx] = surf.radiance(hit, footprint)
        rad[start:start + n] = L.view(3, n, hs, ws).transpose(0, 1)
        seen[start:start + n] = ok.view(n, 1, hs, ws).float()
    # texel = solid-angle-weighted average of its sub-rays
    wgt = omega.view(1, 1, hs, ws)
    vis = _box(seen * wgt, s) / _box(wgt.expand_as(seen), s)
    proj = _box(rad * seen * wgt, s) / _box(seen * wgt, s).clamp_min(1e-30)
    if fallback is None:
        probes = vis * proj
    else:
        fb = fallback.to(dev, torch.float32).reshape(N, 3, h, w) * surf.radiance_scale
        probes = vis * proj + (1 - vis) * fb
    if surf.sources is not None:
        probes = probes + _splat_sources(surf, pts, (h, w), steps, max_rays)
    return probes / surf.radiance_scale, vis


def _splat_sources(surf: DepthSurface, pts: Tensor, probe_size: tuple[int, int], steps: int,
                   max_rays: int) -> Tensor:
    """Radiance [N,3,h,w] of the bright sources seen from each point: each source that faces the
    point and that a ray from it reaches (nothing nearer in the way, nothing unseen on the way) adds
    power x cos / t² (its solid angle times radiance, at most 2π's worth) to the texel of its direction."""
    src = surf.sources
    dev = pts.device
    h, w = probe_size
    N, S = pts.shape[0], len(src)
    omega = pano.solid_angles(h, w, dev)
    out = torch.zeros(N, 3, h * w, device=dev)
    per_chunk = max(1, max_rays // S)
    for start in range(0, N, per_chunk):
        x = pts[start:start + per_chunk]
        n = x.shape[0]
        delta = src.pos[:, None, :] - x.T[:, :, None]  # [3,n,S] point -> source
        dist = _norm0(delta.reshape(3, -1)).clamp_min(1e-6)
        d = delta.reshape(3, -1) / dist
        cos_src = -(src.normal[:, None, :].expand(3, n, S).reshape(3, -1) * d).sum(0)
        t, ok = surf.trace(x.T[:, :, None].expand(3, n, S).reshape(3, -1), d.contiguous(), steps=steps)
        reach = ok & (t >= 0.95 * dist - 0.02) & (cos_src > 0)
        solid = (cos_src.clamp_min(0) / (dist * dist)).clamp(max=2 * math.pi)  # per unit power
        contrib = src.power[:, None, :].expand(3, n, S).reshape(3, -1) * (solid * reach)
        u, v = pano.dir_to_uv(d, h, w, dim=0)
        i = v.long().clamp(0, h - 1)
        j = u.long().clamp(0, w - 1)
        texel = i * w + j
        contrib = contrib / omega.reshape(-1)[texel]
        flat = (torch.arange(n, device=dev).repeat_interleave(S) * (h * w) + texel)
        acc = torch.zeros(3, n * h * w, device=dev).index_add_(1, flat, contrib)
        out[start:start + n] = acc.view(3, n, h * w).transpose(0, 1)
    return out.view(N, 3, h, w)


def _box(x: Tensor, s: int) -> Tensor:
    return x if s == 1 else F.avg_pool2d(x, s) * (s * s)


def projected_probe_grid(scene: PanoScene, fallback_grid: Tensor | None = None, *,
                         grid: tuple[int, int] | None = None, probe_size: tuple[int, int] | None = None,
                         return_visible: bool = False, **kwargs) -> Tensor | tuple[Tensor, Tensor]:
    """Projected probes ``[Hp,Wp,3,h,w]`` for a probe grid (positions from :func:`probe_positions`).

    The grid and probe size come from ``fallback_grid [Hp,Wp,3,h,w]`` unless given.  With
    ``return_visible`` also returns the visible share ``[Hp,Wp,1,h,w]``.  ``kwargs`` go to
    :func:`project_probes` (supersample, steps, max_rays).
    """
    if fallback_grid is not None:
        Hp, Wp, _, h, w = fallback_grid.shape
        grid = grid or (Hp, Wp)
        probe_size = probe_size or (h, w)
    if grid is None or probe_size is None:
        raise ValueError("projected_probe_grid: give fallback_grid or both grid and probe_size")
    Hp, Wp = grid
    if scene.normal is None:  # computed once for the positions and the surface
        scene = scene.replace(normal=pano.normals_from_depth(scene.depth.float()))
    pos = probe_positions(scene.depth, scene.normal, grid)
    fb = None if fallback_grid is None else fallback_grid.reshape(Hp * Wp, 3, *probe_size)
    probes, vis = project_probes(scene, pos.reshape(-1, 3), probe_size, fb, **kwargs)
    probes = probes.view(Hp, Wp, 3, *probe_size)
    vis = vis.view(Hp, Wp, 1, *probe_size)
    return (probes, vis) if return_visible else probes
