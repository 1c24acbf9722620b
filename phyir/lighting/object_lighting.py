"""Lighting of an inserted object: the probe at its 3D position and what the shaders need from it.

* :class:`ProbeField` interpolates a scene's probe grid at any 3D point: the probes sit at the
  positions of :func:`phyir.lighting.projection.probe_positions`; a point takes the ``k`` nearest, weighted
  by a Wendland kernel whose radius is the distance to the (k+1)-th nearest, so the weights (and the
  lighting of an object being dragged) change continuously.
* :func:`irradiance_map` is irradiance / pi of a probe per normal direction by quadrature of the
  probe's bilinear interpolant (``SUPERSAMPLE``^2 points per texel): the radiance
  :func:`phyir.shading.render.shade_env` integrates, at the precision the GLSL comparison needs (SH up to
  band 4 is 1-3% off on real HDR probes with small bright lamps).
* :func:`probe_mips` is the mip pyramid the object shader samples (area-weighted 2x2 boxes).
* :func:`object_lighting` assembles all of it for one object, with the dominant lights of
  :mod:`phyir.lighting.extract` placed in 3D by marching the depth panorama from the object
  (:class:`phyir.lighting.projection.DepthSurface`), for shadows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import torch
from torch import Tensor

from phyir import pano
from phyir.color import LUMA, luminance
from phyir.lighting.extract import Light, extract_lights
from phyir.lighting.projection import DepthSurface, probe_positions
from phyir.scene import PanoScene, SceneError

SUPERSAMPLE = 4
IRRADIANCE_SIZE = (32, 64)
PEAK_TEXELS = 8  # brightest texels the object shader integrates exactly (4 samples each)
PEAK_THRESHOLD = 2.0  # x the mean luminance
NEIGHBOURS = 8
FAR_LIGHT = 30.0  # metres: lights whose ray leaves the depth surface are put this far away


# ---------------------------------------------------------------------------------------------
# probe maps


@lru_cache(maxsize=4)
def quadrature(h: int, w: int, s: int = SUPERSAMPLE) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Fine directions ``[3, F]`` (``s``^2 per texel), their solid angles ``[F]`` and the
    bilinear taps (indices, weights ``[F, 4]``) of an h x w probe at them."""
    hf, wf = h * s, w * s
    d = pano.directions(hf, wf, dtype=torch.float64).reshape(3, -1)
    omega = pano.solid_angles(hf, wf, dtype=torch.float64).reshape(-1)
    jf = (torch.arange(wf, dtype=torch.float64) + 0.5) / s
    i_f = (torch.arange(hf, dtype=torch.float64) + 0.5) / s
    vv, uu = torch.meshgrid(i_f, jf, indexing="ij")
    idx, wgt = pano.bilinear_taps(uu.reshape(-1), vv.reshape(-1), h, w)
    return d, omega, idx, wgt


@lru_cache(maxsize=4)
def _texels(h: int, w: int) -> tuple[Tensor, Tensor]:
    """Texel-centre directions ``[3, h*w]`` and solid angles ``[h*w]`` of an h x w probe."""
    return (pano.directions(h, w, dtype=torch.float64).reshape(3, -1),
            pano.solid_angles(h, w, dtype=torch.float64).reshape(-1))


def _cosine_rows(h: int, w: int, r: Tensor) -> Tensor:
    """``[R, h*w]`` float32: irradiance / pi at unit directions ``r [R, 3]`` (rows sum to one)."""
    d, omega, idx, wgt = quadrature(h, w)
    op = torch.zeros(r.shape[0], h * w, dtype=torch.float64)
    for a in range(0, r.shape[0], 256):
        k = (r[a:a + 256].double() @ d).clamp(min=0) * omega  # [rows, F]
        for t in range(4):
            op[a:a + 256].index_add_(1, idx[:, t], k * wgt[:, t])
    return (op / op.sum(1, keepdim=True)).float()  # cos-weighted mean: constants stay constant


@lru_cache(maxsize=8)
def _irradiance_operator(h: int, w: int, hl: int, wl: int) -> Tensor:
    """``[hl*wl, h*w]``: irradiance / pi at the texel centres of an hl x wl map."""
    return _cosine_rows(h, w, pano.directions(hl, wl, dtype=torch.float64).reshape(3, -1).T)


@lru_cache(maxsize=8)
def _irradiance_rows(h: int, w: int, dirs: tuple[tuple[float, float, float], ...]) -> Tensor:
    return _cosine_rows(h, w, torch.tensor(dirs, dtype=torch.float64))


def irradiance_map(probe: Tensor, size: tuple[int, int] = IRRADIANCE_SIZE) -> Tensor:
    """Irradiance / pi ``[..., 3, hl, wl]`` of probes ``[..., 3, h, w]`` at the texel centres of a map."""
    h, w = probe.shape[-2:]
    op = _irradiance_operator(h, w, *size).to(probe.device, probe.dtype)
    return (probe.reshape(*probe.shape[:-2], h * w) @ op.T).reshape(*probe.shape[:-2], *size)


def irradiance_at(probe: Tensor, dirs: tuple[tuple[float, float, float], ...]) -> Tensor:
    """Irradiance / pi ``[len(dirs), 3]`` of a probe ``[3, h, w]`` at unit directions ``dirs``."""
    h, w = probe.shape[-2:]
    return (probe.reshape(3, h * w).float() @ _irradiance_rows(h, w, tuple(dirs)).T).T


def probe_mips(probe: Tensor) -> list[Tensor]:
    """Levels ``[3, h/2^k, w/2^k]`` of a probe, halving while both sizes are even: 2 x 2 boxes weighted
    by texel solid angle (what :func:`phyir.pano.resize_area` computes, without its per-call cost)."""
    levels = [probe]
    while levels[-1].shape[-2] % 2 == 0 and levels[-1].shape[-1] % 2 == 0 and levels[-1].shape[-2] > 1:
        x = levels[-1]
        h, w = x.shape[-2:]
        a = pano.solid_angles(h, 1, dtype=x.dtype)[:, 0]  # per row
        num = (x * a[:, None]).reshape(*x.shape[:-2], h // 2, 2, w // 2, 2).sum((-3, -1))
        den = a.reshape(h // 2, 2).sum(1)[:, None] * 2
        levels.append(num / den)
    return levels


def peak_samples(probe: Tensor, max_texels: int = PEAK_TEXELS, threshold: float = PEAK_THRESHOLD
                 ) -> tuple[Tensor, Tensor, Tensor]:
    """Split a probe ``[3, h, w]`` for glossy shading: ``(directions [K, 3], power [K, 3], residual)``.

    Of the ``max_texels`` texels with the most luminous power above ``threshold`` x the mean
    luminance, the part above that level becomes point samples: the bilinear tent of a texel is
    integrated with 2 x 2 samples at +-0.5 texel, each carrying a quarter of its peak radiance times
    the solid angle of a texel at the sample's latitude.  ``residual`` is the probe without them:
    residual's bilinear interpolant plus the samples is the probe's radiance, so filtered importance
    sampling of the (smoother) residual plus the samples integrates lamps a few texels wide exactly
    where sampling alone needs hundreds of directions.
    """
    h, w = probe.shape[-2:]
    p = probe.double().clamp(min=0)
    omega = pano.solid_angles(h, w, dtype=torch.float64)
    lum = luminance(p)
    level = threshold * float((lum * omega).sum()) / (4 * math.pi)
    excess = (lum - level).clamp(min=0)
    power = (excess * omega).reshape(-1)
    k = int(min(max_texels, int((power > 0).sum())))
    if k == 0:
        return torch.zeros(0, 3), torch.zeros(0, 3), probe.clone()
    idx = torch.topk(power, k).indices
    i, j = idx // w, idx % w
    share = (excess / lum.clamp(min=1e-300)).reshape(-1)[idx]  # peak share of the texel's radiance
    peak = p.reshape(3, -1)[:, idx] * share  # [3, k]
    residual = p.reshape(3, -1).clone()
    residual[:, idx] -= peak
    offs = torch.tensor([-0.5, 0.5], dtype=torch.float64)
    du, dv = torch.meshgrid(offs, offs, indexing="ij")
    u = (j[:, None].double() + 0.5 + du.reshape(1, -1))  # [k, 4]
    v = (i[:, None].double() + 0.5 + dv.reshape(1, -1)).clamp(1e-6, h - 1e-6)
    dirs = pano.uv_to_dir(u, v, h, w, dim=-1)  # [k, 4, 3]
    lat = math.pi / 2 - math.pi * v / h
    om = (2 * math.pi / w) * (math.pi / h) * torch.cos(lat)  # [k, 4]
    pw = 0.25 * peak.T[:, None, :] * om[..., None]  # [k, 4, 3]
    return (dirs.reshape(-1, 3).float(), pw.reshape(-1, 3).float(),
            residual.reshape(3, h, w).to(probe.dtype))


# ---------------------------------------------------------------------------------------------
# probes in 3D


class ProbeField:
    """A scene's probe grid as probes at 3D points, interpolated anywhere (see the module doc)."""

    interpolates = True  # probes blended from elsewhere: near lights need the distance correction

    def __init__(self, scene: PanoScene, k: int = NEIGHBOURS):
        if scene.batched:
            raise SceneError("ProbeField: expected an unbatched scene")
        if scene.probes is None or scene.depth is None:
            raise SceneError("ProbeField: the scene needs probes and depth")
        Hp, Wp, _, h, w = scene.probes.shape
        self.positions = probe_positions(scene.depth, scene.normal, (Hp, Wp)).reshape(-1, 3).double()
        self.probes = scene.probes.reshape(Hp * Wp, 3, h, w).float()
        self.k = min(k, self.positions.shape[0])

    def weights(self, point: Tensor) -> tuple[Tensor, Tensor]:
        """Indices and weights (summing to one) of the probes lighting ``point [3]``."""
        d = torch.linalg.vector_norm(self.positions - point.double().reshape(1, 3), dim=1)
        if self.k >= d.numel():
            idx = torch.arange(d.numel())
            return idx, torch.full((d.numel(),), 1.0 / d.numel(), dtype=torch.float64)
        near, idx = torch.topk(d, self.k + 1, largest=False)
        radius = near[-1].clamp(min=1e-9)
        q = (near[:-1] / radius).clamp(max=1)
        wgt = (1 - q) ** 4 * (4 * q + 1)  # Wendland C2: zero at the (k+1)-th probe
        if float(wgt.sum()) <= 0:  # equidistant probes
            wgt = torch.ones_like(wgt)
        return idx[:-1], wgt / wgt.sum()

    def probe_at(self, point: Tensor) -> Tensor:
        idx, wgt = self.weights(point)
        return torch.einsum("k,kchw->chw", wgt.float(), self.probes[idx])


@dataclass
class PlacedLight:
    """A dominant light placed in the room: ``position`` on the depth surface (or far away)."""

    light: Light
    position: Tensor  # [3]
    distance: float  # from the object's centre


AXES = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0),
        (0.0, 0.0, -1.0))  # the ambient cube's order (shaders/composite.frag)
# an object's ambient occlusion fades out at this many bounding radii: on the floor a sphere's form
# factor falls as (r/d)^3, and the floor beyond 3 radii still holds a third of its occlusion
HALO = 5.0
N_HALO = 26  # points of the halo sphere that open place_lights' reach points


@dataclass
class ObjectLighting:
    """Everything the object and shadow shaders need for one object at one position."""

    centre: Tensor  # [3]
    probe: Tensor  # [3, h, w]
    mips: list[Tensor]  # probe_mips(probe)
    irradiance: Tensor  # [3, 32, 64] irradiance / pi
    spec_mips: list[Tensor]  # the probe without its peak samples (glossy shading)
    peak_dirs: Tensor  # [K, 3]
    peak_power: Tensor  # [K, 3]
    ambient: Tensor  # [6, 3] irradiance / pi around +-x, +-y, +-z (an ambient cube)
    ambient_residual: Tensor  # [6, 3] the same without the dominant lights
    ambient_bounce: Tensor  # [6, 3] the ambient cube the object's own surface gets (support_shadowed)
    residual: Tensor  # [3, h, w] the probe without its dominant lights (what occlusion removes)
    lights: list[PlacedLight] = field(default_factory=list)
    reach: Tensor | None = None  # [P, 3] points bounding what the object changes (halo, shadows)
    marched_from: Tensor | None = None  # [3] the centre the lights were placed from (reuse_lights)


def _fibonacci(n: int) -> Tensor:
    k = torch.arange(n, dtype=torch.float64)
    z = 1 - 2 * (k + 0.5) / n
    phi = k * math.pi * (3 - math.sqrt(5))
    r = torch.sqrt(1 - z * z)
    return torch.stack([r * torch.cos(phi), z, r * torch.sin(phi)], 1)


def _halo(centre: Tensor, radius: float) -> Tensor:
    """The first :data:`N_HALO` reach points: a shell of ``HALO`` radii around ``centre`` (float64)."""
    return centre + HALO * radius * _fibonacci(N_HALO)


def place_lights(lights: list[Light], centre: Tensor, surface: DepthSurface | None, radius: float = 0.0,
                 rays: int = 12, steps: int = 32) -> tuple[list[PlacedLight], Tensor]:
    """Put each light where its direction from ``centre`` meets the depth surface; with the object's
    bounding ``radius`` also return the reach points: a halo sphere of :data:`HALO` radii and, per
    light, where ``rays`` rays past the object's silhouette (away from the light) meet the scene.
    One march of the depth surface (``steps`` steps) for all rays."""
    c = centre.double().reshape(1, 3)
    halo = _halo(c, radius)
    if not lights:
        return [], halo
    dirs = torch.stack([lt.direction.double() for lt in lights])  # [L, 3]
    origins, rays_d = [c.expand(len(lights), 3)], [dirs]
    t_ring = torch.linspace(0, 2 * math.pi, rays + 1, dtype=torch.float64)[:-1]
    for d in dirs:
        a = torch.linalg.cross(d, torch.tensor([0.0, 1.0, 0.0] if abs(float(d[1])) < 0.9 else [1.0, 0.0, 0.0],
                                               dtype=torch.float64))
        a = a / a.norm()
        b = torch.linalg.cross(d, a)
        origins.append(c + 1.5 * radius * (torch.cos(t_ring)[:, None] * a + torch.sin(t_ring)[:, None] * b))
        rays_d.append((-d).expand(rays, 3))
    o, dd = torch.cat(origins), torch.cat(rays_d)
    if surface is not None:
        t, _ = surface.trace(o.T.float().contiguous(), dd.T.float().contiguous(), steps=steps)
        t = t.double()
    else:
        t = torch.full((o.shape[0],), math.nan, dtype=torch.float64)
    out = []
    for k, lt in enumerate(lights):
        dist = float(t[k]) if math.isfinite(float(t[k])) and float(t[k]) > 0 else FAR_LIGHT
        out.append(PlacedLight(lt, (c[0] + dist * dirs[k]).float(), dist))
    n = len(lights)
    far = float(surface.r_bound) * 2 if surface is not None else FAR_LIGHT
    shadow = o[n:] + torch.nan_to_num(t[n:], nan=far)[:, None] * dd[n:]
    return out, torch.cat([halo, shadow])


def reuse_lights(lights: list[Light], centre: Tensor, radius: float, previous: ObjectLighting,
                 max_angle: float = 0.15) -> tuple[list[PlacedLight], Tensor, Tensor] | None:
    """:func:`place_lights` without marching, for an object being dragged: each light keeps the room
    position of the ``previous`` lighting's light seen from ``centre`` within ``max_angle`` radians
    of its direction (lamps don't move with the object), and the shadow reach points move with the
    object.  Returns ``(placed, reach, marched_from)``, or None when a light has no match or the
    object is more than ``radius`` away from where the lights were last marched (the reach points
    would be stale)."""
    start = previous.marched_from if previous.marched_from is not None else previous.centre
    c = centre.double().reshape(3)
    if previous.reach is None or float((c - start.double()).norm()) > radius:
        return None
    if not previous.lights:
        return ([], _halo(c, radius), start) if not lights else None
    pos = torch.stack([pl.position.double() for pl in previous.lights])  # [L', 3]
    dist = (pos - c).norm(dim=1)
    seen = (pos - c) / dist.clamp(min=1e-9)[:, None]
    out = []
    for lt in lights:
        cos = seen @ lt.direction.double()
        k = int(cos.argmax())
        if float(cos[k]) < math.cos(max_angle):
            return None
        out.append(PlacedLight(lt, pos[k].float(), float(dist[k])))
    shift = c - previous.centre.double()
    reach = torch.cat([_halo(c, radius), previous.reach[N_HALO:].double() + shift])
    return out, reach, start


def correct_light_distance(field: ProbeField, centre: Tensor, probe: Tensor, placed: list[PlacedLight]
                           ) -> Tensor:
    """Near lights seen from the probes that were blended are brighter seen from ``centre`` when it is
    nearer to them (the inverse-square law): each placed light's part of the probe and its power
    are scaled by sum_i w_i |L - p_i|^2 / |L - centre|^2 over the blended probes (clamped to
    [1/4, 4]).  Returns the corrected probe; ``placed`` is updated in place."""
    idx, wgt = field.weights(centre)
    pos = field.positions[idx]  # [k, 3]
    c = centre.double().reshape(1, 3)
    for pl in placed:
        if pl.light.peak is None or pl.distance >= FAR_LIGHT:
            continue
        lp = pl.position.double().reshape(1, 3)
        near = float(((lp - c) ** 2).sum())
        seen = float((wgt * ((lp - pos) ** 2).sum(1)).sum())
        k = min(max(seen / max(near, 1e-9), 0.25), 4.0)
        probe = probe + (k - 1) * pl.light.peak.to(probe.dtype)
        pl.light.power = pl.light.power * k
        pl.light.peak = pl.light.peak * k
    return probe.clamp(min=0)


def support_shadowed(probe: Tensor, residual: Tensor, centre: Tensor, radius: float,
                     plane: tuple[Tensor, Tensor] | None, ambient: Tensor, lights: list[PlacedLight]
                     ) -> Tensor:
    """The ambient cube ``[6, 3]`` of the object's own surface: the probe with the support plane
    darkened by the object's shadow on it.  The probe was captured without the object, so it sees
    the floor under the object fully lit; what the object bounces onto its receivers (composite.frag)
    comes mostly from that floor.  A probe direction meeting the plane at ``p`` keeps the share
    ``1 - f(p)`` of its radiance, ``f`` the irradiance the bounding sphere hides at ``p``: its form
    factor (``sin^2 cos``) times the ``residual``'s irradiance plus each light it blocks, over the
    plane's irradiance (luminance, in [0, 1]); ``ambient``: the probe's cube, returned as it is
    without a plane."""
    if plane is None:
        return ambient.clone()
    h, w = probe.shape[-2:]
    d, omega = _texels(h, w)
    radiance = probe.double().reshape(3, -1)  # texel centres: the correction is smooth in direction
    c = centre.double().reshape(3, 1)
    q, n = (torch.as_tensor(x, dtype=torch.float64).reshape(3, 1) for x in plane)
    n = n / n.norm()
    height = float(((c - q) * n).sum())
    down = -(d * n).sum(0)  # cos toward the plane
    t = height / down.clamp(min=1e-6)
    hits = (down > 1e-3) & (height > 0)
    x = c + t * d  # [3, F] points on the plane
    to_c = c - x
    dist2 = (to_c * to_c).sum(0).clamp(min=1e-12)
    sin2 = (radius * radius / dist2).clamp(max=1.0)
    form = sin2 * (to_c * n).sum(0).clamp(min=0) / dist2.sqrt()
    luma = torch.tensor(LUMA, dtype=torch.float64)
    normal = (tuple(round(float(v), 3) for v in n[:, 0]),)
    e_res, e_all = (math.pi * float(luma @ irradiance_at(x, normal)[0].double()) for x in (residual, probe))
    hidden = form * e_res
    for pl in lights:
        ld = pl.light.direction.double().reshape(3, 1)
        cos_l = float((ld * n).sum())
        if cos_l <= 0:
            continue
        along = (to_c * ld).sum(0)  # the sphere's centre along the ray toward the light
        miss = (dist2 - along * along).clamp(min=0).sqrt()
        blocked = ((along > 0) & (miss < radius)).double()
        hidden = hidden + blocked * cos_l * float(luma @ pl.light.power.double())
    keep = torch.where(hits, 1 - (hidden / max(e_all, 1e-12)).clamp(0, 1), torch.ones_like(hidden))
    axes = torch.tensor(AXES, dtype=torch.float64)
    k = (axes @ d).clamp(min=0) * omega  # [6, F]
    return ((radiance * keep) @ k.T / k.sum(1)).T.to(ambient.dtype)


def object_lighting(field, centre: Tensor, surface: DepthSurface | None = None,
                    max_lights: int = 4, radius: float = 0.0, steps: int = 32,
                    support: tuple[Tensor, Tensor] | None = None, probe: Tensor | None = None,
                    previous: ObjectLighting | None = None) -> ObjectLighting:
    """The probe at ``centre`` from ``field`` (a :class:`ProbeField`: interpolated, its near lights corrected
    for the distance between the probes and ``centre``; or a
    :class:`phyir.lighting.at_point.LightAtPoint`: computed at the point), its maps and its placed
    dominant lights; ``radius``: the object's bounding radius (for the reach points), ``steps``: depth-
    marching steps, ``support``: (point, normal) of the surface the object rests on
    (:func:`support_shadowed`); ``probe``: ``field.probe_at(centre)`` when the caller has it already;
    ``previous``: the same object's lighting a moment ago (while it is dragged), whose lights are kept
    where they are (:func:`reuse_lights`)."""
    probe = field.probe_at(centre) if probe is None else probe
    lights, residual = extract_lights(probe, max_lights=max_lights)
    kept = None if previous is None else reuse_lights(lights, centre, radius, previous)
    if kept is None:
        placed, reach = place_lights(lights, centre, surface, radius, steps=steps)
        marched_from = centre.float()
    else:
        placed, reach, marched_from = kept
    if field.interpolates:
        probe = correct_light_distance(field, centre, probe, placed)
    dirs, power, spec = peak_samples(probe)
    ambient, ambient_res = irradiance_at(probe, AXES), irradiance_at(residual, AXES)
    bounce = support_shadowed(probe, residual, centre, radius, support, ambient, placed)
    return ObjectLighting(centre=centre.float(), probe=probe, mips=probe_mips(probe),
                          irradiance=irradiance_map(probe), spec_mips=probe_mips(spec), peak_dirs=dirs,
                          peak_power=power, ambient=ambient, ambient_residual=ambient_res,
                          ambient_bounce=bounce, residual=residual, lights=placed, reach=reach.float(),
                          marched_from=marched_from.float())
