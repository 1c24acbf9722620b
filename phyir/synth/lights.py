"""Light sources of the synthetic rooms: area emitters, window portals onto a sky, and the sun.

* Area lights: emissive quads (ceiling panels, one-sided), spheres (bulbs, globes) and capped
  cylinders (lamp shades) of constant radiance.
* Portals: the window openings.  A ray leaving the room through one sees the exterior: a sky
  gradient (zenith, horizon, ground), sampled by area over the window.
* The sun: a disc of angular radius ``SUN_RADIUS`` that reaches the room only through portals.

Next-event estimation picks one source per sample with probabilities proportional to
power / distance^2 at the shading point (mixed with a uniform share so no source is starved) and
samples it in solid angle with a cosine warp (quads: panels and portals, given the receiver's
normal), by area (cylinders), by the subtended cone (spheres) or by the sun's cone.
:meth:`Lights.pdf` gives the same densities for directions found by BSDF sampling (MIS).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from phyir.shading.sampling import local_to_world, sample_linear
from phyir.synth import geometry as G

AREA, PORTAL, SUN = 0, 1, 2
# angular radius: a hazy sun ~ one 16x32 probe texel wide (11.25 deg), so probes hold it as well
# as the image (soft shadow edges, no sub-texel disc); sun/sunlit-floor radiance ~ 1e2-1e3
SUN_RADIUS = math.radians(6.0)
UNIFORM_SHARE = 0.1  # part of the light-selection probability spread uniformly
COS_FLOOR = 0.01  # smallest corner weight of the cosine warp (pbrt-v4's), keeps the density > 0


@dataclass
class Sky:
    """The exterior seen through windows (room or camera frame), linear RGB radiance."""

    zenith: np.ndarray
    horizon: np.ndarray
    ground: np.ndarray
    sun_dir: np.ndarray | None = None  # unit vector toward the sun
    sun_radiance: np.ndarray | None = None

    @staticmethod
    def random(rng: np.random.Generator, sun: bool) -> Sky:
        inten = float(rng.uniform(3, 12))
        haze = float(rng.uniform(0, 1))
        zen = np.array((0.35, 0.55, 1.0)) * (1 - haze) + np.array((0.8, 0.85, 0.95)) * haze
        sky = Sky(zenith=zen * inten, horizon=np.array((1.0, 0.96, 0.92)) * 1.1 * inten,
                  ground=np.array((0.45, 0.42, 0.36)) * float(rng.uniform(0.3, 0.8)) * inten)
        if sun:
            el = math.radians(float(rng.uniform(10, 60)))
            az = float(rng.uniform(-math.pi, math.pi))
            sky.sun_dir = np.array((math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)))
            e_sun = float(rng.uniform(6, 20)) * inten  # irradiance at normal incidence
            omega = 2 * math.pi * (1 - math.cos(SUN_RADIUS))
            sky.sun_radiance = np.array((1.0, 0.95, 0.85)) * e_sun / omega
        return sky

    def rotated(self, R: np.ndarray) -> Sky:
        return Sky(self.zenith, self.horizon, self.ground,
                   None if self.sun_dir is None else R @ self.sun_dir, self.sun_radiance)


class Lights:
    """Tensors of all sources of one scene (see the module doc)."""

    @staticmethod
    def build(P: G.Prims, emit: list, sky: Sky | None, device=None) -> Lights:
        """``emit``: [(global prim id, PrimSpec)] of area lights and portals."""
        L = Lights()
        rows = []
        for pid, spec in emit:
            rows.append((PORTAL if spec.portal else AREA, pid,
                         (0.0, 0.0, 0.0) if spec.portal else tuple(spec.emit)))
        has_sun = sky is not None and sky.sun_dir is not None and any(r[0] == PORTAL for r in rows)
        if has_sun:
            rows.append((SUN, -1, tuple(sky.sun_radiance)))
        n = len(rows)
        dev = P.device
        L.kind = torch.tensor([r[0] for r in rows], dtype=torch.long, device=dev)
        L.pid = torch.tensor([r[1] for r in rows], dtype=torch.long, device=dev)
        L.radiance = torch.tensor([r[2] for r in rows], dtype=torch.float32, device=dev).reshape(n, 3)
        L.gkind = torch.where(L.pid >= 0, P.kind[L.pid.clamp(min=0)], -1)
        # geometry, one row per light (unused fields zero)
        z3 = torch.zeros(n, 3, device=dev)
        L.c, L.ex, L.ey, L.nq = z3.clone(), z3.clone(), z3.clone(), z3.clone()
        L.h = torch.zeros(n, 2, device=dev)
        L.r, L.hh, L.area = (torch.zeros(n, device=dev) for _ in range(3))
        for li, (_, pid, _) in enumerate(rows):
            if pid < 0:
                continue
            k = int(P.kind[pid])
            i = pid - P.offsets[k]
            if k == G.QUAD:
                L.c[li], L.ex[li], L.ey[li], L.nq[li] = P.q_c[i], P.q_ex[i], P.q_ey[i], P.q_n[i]
                L.h[li] = P.q_h[i]
                L.area[li] = 4 * P.q_h[i].prod()
            elif k == G.SPH:
                L.c[li], L.r[li] = P.s_c[i], P.s_r[i]
                L.area[li] = 4 * math.pi * P.s_r[i] ** 2
            elif k == G.CYL:
                L.c[li], L.r[li], L.hh[li] = P.c_c[i], P.c_r[i], P.c_hh[i]
                L.area[li] = 2 * math.pi * P.c_r[i] * 2 * P.c_hh[i] + 2 * math.pi * P.c_r[i] ** 2
            else:
                raise ValueError("boxes cannot be emitters")
        # sky
        def f(a):
            return torch.tensor(np.asarray(a, dtype=np.float32), device=dev)
        if sky is None:
            sky = Sky(np.zeros(3), np.zeros(3), np.zeros(3))
        L.zenith, L.horizon, L.ground = f(sky.zenith), f(sky.horizon), f(sky.ground)
        L.has_sun = has_sun
        L.sun_dir = f(sky.sun_dir if has_sun else (0.0, 1.0, 0.0))
        L.sun_cos = math.cos(SUN_RADIUS)
        L.sun_omega = 2 * math.pi * (1 - L.sun_cos)
        L.sun_index = n - 1 if has_sun else -1
        # bounding spheres and powers for light selection
        bound = torch.where(L.gkind == G.QUAD, L.h.norm(dim=1), torch.sqrt(L.r ** 2 + L.hh ** 2))
        mean_rad = L.radiance.mean(1)
        sky_mean = float((L.zenith + L.horizon).mean() / 2)
        power = torch.where(L.kind == PORTAL, sky_mean * L.area * math.pi, mean_rad * L.area * math.pi)
        L.centre, L.bound = L.c.clone(), bound
        portal = L.kind == PORTAL
        if has_sun:
            pc = L.c[portal]
            L.centre[-1] = pc.mean(0)
            L.bound[-1] = ((pc - pc.mean(0)).norm(dim=1) + bound[portal]).max()
            e_sun = float(L.radiance[-1].mean()) * L.sun_omega
            power[-1] = e_sun * float(L.area[portal].sum()) * 0.5
            L.sun_weight = math.pi * e_sun * 0.5  # see select_probs
        L.power = power
        L.prim_light = torch.full((P.n_prims,), -1, dtype=torch.long, device=dev)
        L.prim_light[L.pid[L.pid >= 0]] = torch.nonzero(L.pid >= 0).squeeze(1)
        L.n = n
        return L

    # -- radiance -----------------------------------------------------------------------------
    def sky(self, w: Tensor) -> Tensor:
        """Sky radiance ``[N,3]`` in directions ``w [N,3]`` (leaving the room), without the sun."""
        y = w[:, 1:2]
        up = self.horizon + (self.zenith - self.horizon) * y.clamp(min=0).sqrt()
        down = self.horizon + (self.ground - self.horizon) * (-y * 8).clamp(0, 1)
        return torch.where(y >= 0, up, down)

    def sun(self, w: Tensor) -> Tensor:
        if not self.has_sun:
            return torch.zeros_like(w)
        inside = (w @ self.sun_dir) >= self.sun_cos
        return torch.where(inside[:, None], self.radiance[self.sun_index], 0.0)

    def emitted(self, li: Tensor, w: Tensor) -> tuple[Tensor, Tensor]:
        """(area/sky radiance, sun radiance) seen along ``w`` on hitting light ``li`` (portals: the sky)."""
        portal = (self.kind[li] == PORTAL)[:, None]
        le = torch.where(portal, self.sky(w), self.radiance[li])
        sun = torch.where(portal, self.sun(w), 0.0)
        return le, sun

    # -- selection ----------------------------------------------------------------------------
    def select_probs(self, x: Tensor) -> Tensor:
        """Light-selection probabilities ``[N, n]`` at points ``x [N,3]``.

        Area lights and portals: power / distance^2.  The sun: pi x its irradiance where the ray
        from ``x`` toward the sun passes through a window (:meth:`sun_through_window`), else only the
        uniform share — most points of a sunny room never see the sun, and sun samples there were
        wasted (the noisiest rooms).  Any deterministic choice keeps the estimator unbiased: BSDF
        sampling covers the rest with MIS, and :meth:`pdf` / :meth:`pdf_sun` use the same numbers.
        """
        d2 = ((x[:, None] - self.centre[None]) ** 2).sum(2)
        w = self.power / torch.maximum(d2, self.bound ** 2 + 1e-4)
        if self.has_sun:
            w = w.clone()
            w[:, self.sun_index] = self.sun_weight * self.sun_through_window(x).float()
        w = w / w.sum(1, keepdim=True).clamp(min=1e-30)
        return (1 - UNIFORM_SHARE) * w + UNIFORM_SHARE / self.n

    def sun_through_window(self, x: Tensor) -> Tensor:
        """``[N]`` bool: the ray from ``x`` toward the sun crosses a window, its rectangle widened by
        the sun disc's footprint (occluders ignored)."""
        d = self.sun_dir
        hit = torch.zeros(len(x), dtype=torch.bool, device=x.device)
        tan_r = math.tan(SUN_RADIUS)
        for li in torch.nonzero(self.kind == PORTAL).squeeze(1).tolist():
            dn = float(d @ self.nq[li])
            if abs(dn) < 1e-6:
                continue
            t = ((self.c[li] - x) @ self.nq[li]) / dn
            y = x + t[:, None] * d - self.c[li]
            m = t.abs() * tan_r / abs(dn)
            hit |= (t > 0) & ((y @ self.ex[li]).abs() <= self.h[li, 0] + m) & \
                ((y @ self.ey[li]).abs() <= self.h[li, 1] + m)
        return hit

    # -- sampling -----------------------------------------------------------------------------
    def quad_weights(self, x: Tensor, n: Tensor, li: Tensor) -> Tensor:
        """Corner weights ``[N,4]`` of the bilinear warp of quad ``li`` seen from ``x`` with normal
        ``n``: the receiver's cosine toward each corner (at least ``COS_FLOOR``; a zero normal gives
        no cosine preference), times the sky's luminance there for windows.  Sampling a panel or
        window uniformly in solid angle leaves the cosine and the sky gradient in the estimator
        (a window seen from the floor spans cosines 0.2-0.9): warping by their bilinear fit over the
        corners takes most of it out (Hart et al. 2020)."""
        cd = _rect_corner_dirs(x, self.c[li], self.ex[li], self.ey[li], self.nq[li], self.h[li])
        w = (cd * n[:, None]).sum(2).clamp(min=COS_FLOOR)
        portal = self.kind[li] == PORTAL
        if bool(portal.any()):
            lum = self.sky(cd.reshape(-1, 3)).mean(1).reshape(-1, 4)
            lum = lum / lum.amax(1, keepdim=True).clamp(min=1e-30)
            w = torch.where(portal[:, None], w * lum.clamp(min=COS_FLOOR), w)
        return w

    def sample(self, x: Tensor, u: Tensor, n: Tensor | None = None, group: int = 1):
        """One light sample per point: ``(li, w, dist, le, pdf, is_sun)``.

        ``u [N,3]`` uniforms; ``pdf`` is the solid-angle density including the selection
        probability (0 where the sample is invalid, e.g. the back of a one-sided panel); ``le`` is
        the radiance the source sends toward ``x`` (sky or sun radiance for portals/the sun).
        With the receivers' normals ``n``, quads are sampled by :meth:`quad_weights`' bilinear warp
        of their spherical rectangle (pass the same ``n`` to :meth:`pdf`).  ``group``: the rows
        come in runs of ``group`` with the same ``x`` and ``n`` (a pixel's samples), whose
        selection probabilities and quad set-ups are then computed once per run.
        """
        N = len(x)
        if N % group:
            raise ValueError(f"{N} rows do not come in groups of {group}")
        probs = self.select_probs(x[::group])
        if group > 1:
            probs = probs.repeat_interleave(group, 0)
        cdf = probs.cumsum(1)
        li = torch.searchsorted(cdf, (u[:, 0:1] * cdf[:, -1:]).contiguous()).squeeze(1).clamp(max=self.n - 1)
        psel = probs.gather(1, li[:, None]).squeeze(1)
        lo = torch.where(li > 0, cdf.gather(1, (li - 1).clamp(min=0)[:, None]).squeeze(1), 0.0)
        u0 = ((u[:, 0] * cdf[:, -1] - lo) / psel.clamp(min=1e-12)).clamp(0, 1 - 1e-6)
        u1, u2 = u[:, 1], u[:, 2]
        w = torch.zeros(N, 3, device=x.device)
        w[:, 1] = 1
        dist = torch.full((N,), float("inf"), device=x.device)
        pdf = torch.zeros(N, device=x.device)
        gk = self.gkind[li]
        # quads (panels, portals): uniform in the subtended solid angle
        m = torch.nonzero(gk == G.QUAD).squeeze(1)
        if m.numel():
            i = li[m]
            a, b, pw = u1[m], u2[m], 1.0
            frame = None
            if group > 1:  # set-ups once per (run, light) pair
                uk, inv = torch.unique((m // group) * self.n + i, return_inverse=True)
                r, j = (uk // self.n) * group, uk % self.n
                frame = tuple(t[inv] for t in _rect_frame(x[r], self.c[j], self.ex[j], self.ey[j],
                                                          self.nq[j], self.h[j]))
                wq = None if n is None else self.quad_weights(x[r], n[r], j)[inv]
            elif n is not None:
                wq = self.quad_weights(x[m], n[m], i)
            if n is not None:
                a, b = _bilinear_warp(a, b, wq)
                pw = _bilinear_pdf(a, b, wq)
            w[m], dist[m], pdf[m] = _rect_sample(x[m], self.c[i], self.ex[i], self.ey[i], self.nq[i],
                                                 self.h[i], a, b, frame)
            pdf[m] = pdf[m] * pw
        # spheres: uniform in the subtended cone
        m = torch.nonzero(gk == G.SPH).squeeze(1)
        if m.numel():
            i = li[m]
            wc, dm, pm = _cone_sample(x[m], self.c[i], self.r[i], u1[m], u2[m])
            w[m], dist[m], pdf[m] = wc, dm, pm
        # cylinders: uniform by area over side and caps
        m = torch.nonzero(gk == G.CYL).squeeze(1)
        if m.numel():
            i = li[m]
            y, n = _cyl_point(self.c[i], self.r[i], self.hh[i], u0[m], u1[m], u2[m])
            w[m], dist[m], pdf[m] = _area_pdf(x[m], y, n, self.area[i], one_sided=True)
        # the sun: uniform in its cone
        is_sun = self.kind[li] == SUN
        m = torch.nonzero(is_sun).squeeze(1)
        if m.numel():
            cos_t = 1 - u1[m] * (1 - self.sun_cos)
            sin_t = torch.sqrt((1 - cos_t * cos_t).clamp(min=0))
            phi = 2 * math.pi * u2[m]
            loc = torch.stack((sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t), 1)
            w[m] = local_to_world(loc, self.sun_dir.expand(len(m), 3))
            pdf[m] = 1.0 / self.sun_omega
        kind = self.kind[li]
        le = torch.where((kind == AREA)[:, None], self.radiance[li], 0.0)
        le = torch.where((kind == PORTAL)[:, None], self.sky(w), le)
        le = torch.where((kind == SUN)[:, None], self.radiance[li], le)
        return li, w, dist, le, pdf * psel, is_sun

    def pdf(self, x: Tensor, li: Tensor, y: Tensor, w: Tensor, n: Tensor | None = None) -> Tensor:
        """Density of :meth:`sample` (with the same normals ``n``) choosing direction ``w`` toward
        point ``y`` on light ``li``."""
        psel = self.select_probs(x).gather(1, li[:, None]).squeeze(1)
        gk = self.gkind[li]
        out = torch.zeros(len(x), device=x.device)
        d2 = ((y - x) ** 2).sum(1)
        m = torch.nonzero(gk == G.QUAD).squeeze(1)
        if m.numel():
            i = li[m]
            frame = _rect_frame(x[m], self.c[i], self.ex[i], self.ey[i], self.nq[i], self.h[i])
            omega = frame[5].float()
            cos_l = -(w[m] * self.nq[i]).sum(1)
            out[m] = torch.where((cos_l > 0) & (omega > 0), 1.0 / omega.clamp(min=1e-30), 0.0)
            if n is not None:
                a, b = _rect_invert(x[m], self.c[i], self.ex[i], self.ey[i], self.nq[i], self.h[i], y[m],
                                    frame)
                out[m] = out[m] * _bilinear_pdf(a.float(), b.float(), self.quad_weights(x[m], n[m], i))
        m = torch.nonzero(gk == G.SPH).squeeze(1)
        if m.numel():
            i = li[m]
            out[m] = 1.0 / _cone_solid_angle(x[m], self.c[i], self.r[i])
        m = torch.nonzero(gk == G.CYL).squeeze(1)
        if m.numel():
            i = li[m]
            n = _cyl_normal(y[m], self.c[i], self.r[i], self.hh[i])
            cos_l = -(w[m] * n).sum(1)
            out[m] = torch.where(cos_l > 0, d2[m] / (self.area[i] * cos_l.clamp(min=1e-8)), 0.0)
        return out * psel

    def pdf_sun(self, x: Tensor, w: Tensor) -> Tensor:
        """Density of sampling the sun in direction ``w`` (zero outside its disc)."""
        if not self.has_sun:
            return torch.zeros(len(x), device=x.device)
        psel = self.select_probs(x)[:, self.sun_index]
        inside = (w @ self.sun_dir) >= self.sun_cos
        return torch.where(inside, psel / self.sun_omega, 0.0)


def _rect_frame(x, c, ex, ey, n, h):
    """Spherical-rectangle set-up (Urena et al. 2013) of one-sided quads seen from ``x``, in float64:
    the rectangle's corner coordinates (x0, x1, y0, y1, z0 < 0) in the frame (ex, ey, -n) at ``x``,
    its solid angle ``S`` (0 from behind the emitting side) and the constants b0, b1, k."""
    def f(t):
        return t.double()
    x, c, ex, ey, n, h = map(f, (x, c, ex, ey, n, h))
    d = c - x
    z0 = (d * n).sum(1)  # < 0 on the emitting side (n points into the room)
    x0 = (d * ex).sum(1) - h[:, 0]
    y0 = (d * ey).sum(1) - h[:, 1]
    x1, y1 = x0 + 2 * h[:, 0], y0 + 2 * h[:, 1]
    z = z0.clamp(max=-1e-9)
    S, b0, b1, k = _sph_rect(x0, x1, y0, y1, z)
    S = torch.where(z0 < -1e-9, S, 0.0)
    return x0, x1, y0, y1, z, S, b0, b1, k


def _sph_rect(x0, x1, y0, y1, z):
    """Solid angle and Urena's constants (b0, b1, k) of the rectangle [x0,x1] x [y0,y1] at depth z < 0."""
    # normals of the spherical rectangle's edges (frame with z = +n so that z0 < 0)
    n0 = torch.stack((torch.zeros_like(z), z, -y0), 1)
    n1 = torch.stack((-z, torch.zeros_like(z), x1), 1)
    n2 = torch.stack((torch.zeros_like(z), -z, y1), 1)
    n3 = torch.stack((z, torch.zeros_like(z), -x0), 1)
    n0, n1, n2, n3 = (v / v.norm(dim=1, keepdim=True) for v in (n0, n1, n2, n3))
    def ac(a, b):
        return torch.acos((-(a * b).sum(1)).clamp(-1, 1))
    g0, g1, g2, g3 = ac(n0, n1), ac(n1, n2), ac(n2, n3), ac(n3, n0)
    k = 2 * math.pi - g2 - g3
    S = (g0 + g1 - k).clamp(min=0)
    return S, n0[:, 2], n2[:, 2], k


def _rect_invert(x, c, ex, ey, n, h, y, frame: tuple | None = None) -> tuple[Tensor, Tensor]:
    """The inverse of :func:`_rect_sample`: the uniforms ``(u1, u2)`` that map to point ``y`` on the
    quad (float64): u1 is the solid-angle fraction of the sub-rectangle left of ``y``, u2 the
    fraction of the height-sine range along its column; ``frame``: :func:`_rect_frame` of these
    rows if already known."""
    x0, x1, y0, y1, z, S, _, _, _ = _rect_frame(x, c, ex, ey, n, h) if frame is None else frame
    d = y.double() - x.double()
    xu = (d * ex.double()).sum(1).clamp(min=x0, max=x1)
    yv = (d * ey.double()).sum(1).clamp(min=y0, max=y1)
    S_left = _sph_rect(x0, xu, y0, y1, z)[0]
    u1 = (S_left / S.clamp(min=1e-30)).clamp(0, 1)
    dd2 = xu * xu + z * z
    h0, h1 = y0 / torch.sqrt(dd2 + y0 * y0), y1 / torch.sqrt(dd2 + y1 * y1)
    hv = yv / torch.sqrt(dd2 + yv * yv)
    u2 = ((hv - h0) / (h1 - h0).clamp(min=1e-30)).clamp(0, 1)
    return u1, u2


def _rect_corner_dirs(x, c, ex, ey, n, h) -> Tensor:
    """Unit directions ``[N,4,3]`` from ``x`` to the quad's corners in the order of the unit square
    of :func:`_rect_sample`: (x0,y0), (x1,y0), (x0,y1), (x1,y1)."""
    d = c - x
    z0 = (d * n).sum(1, keepdim=True)
    xs = ((d * ex).sum(1, keepdim=True) - h[:, :1], (d * ex).sum(1, keepdim=True) + h[:, :1])
    ys = ((d * ey).sum(1, keepdim=True) - h[:, 1:], (d * ey).sum(1, keepdim=True) + h[:, 1:])
    v = torch.stack([xs[i] * ex + ys[j] * ey + z0 * n for j in (0, 1) for i in (0, 1)], 1)
    return v / v.norm(dim=2, keepdim=True).clamp(min=1e-12)


def _bilinear_warp(u1: Tensor, u2: Tensor, w: Tensor) -> tuple[Tensor, Tensor]:
    """Warp uniforms to the bilinear density with corner values ``w [N,4]`` (order of
    :func:`_rect_corner_dirs`; Hart et al. 2020, as in pbrt-v4's spherical rectangles)."""
    below_one = 1 - 1e-6
    b = sample_linear(u2, w[:, 0] + w[:, 1], w[:, 2] + w[:, 3]).clamp(max=below_one)
    a = sample_linear(u1, torch.lerp(w[:, 0], w[:, 2], b), torch.lerp(w[:, 1], w[:, 3], b))
    return a.clamp(max=below_one), b


def _bilinear_pdf(a: Tensor, b: Tensor, w: Tensor) -> Tensor:
    return 4 * ((1 - a) * (1 - b) * w[:, 0] + a * (1 - b) * w[:, 1] + (1 - a) * b * w[:, 2]
                + a * b * w[:, 3]) / w.sum(1).clamp(min=1e-30)


def _rect_solid_angle(x, c, ex, ey, n, h) -> Tensor:
    return _rect_frame(x, c, ex, ey, n, h)[5].float()


def _rect_sample(x, c, ex, ey, n, h, u1, u2, frame: tuple | None = None):
    """Direction uniform in the solid angle of the quad (Urena et al. 2013): ``(w, dist, pdf)``;
    ``frame``: :func:`_rect_frame` of these rows if already known."""
    x0, x1, y0, y1, z0, S, b0, b1, k = _rect_frame(x, c, ex, ey, n, h) if frame is None else frame
    u1, u2 = u1.double(), u2.double()
    au = u1 * S + k
    fu = (torch.cos(au) * b0 - b1) / torch.sin(au)
    cu = (torch.sign(fu) / torch.sqrt(fu * fu + b0 * b0)).clamp(-1, 1)
    cu = torch.where(fu == 0, 0.0, cu)
    xu = (-(cu * z0) / torch.sqrt((1 - cu * cu).clamp(min=1e-30))).clamp(x0, x1)
    dd = torch.sqrt(xu * xu + z0 * z0)
    h0 = y0 / torch.sqrt(dd * dd + y0 * y0)
    h1 = y1 / torch.sqrt(dd * dd + y1 * y1)
    hv = h0 + u2 * (h1 - h0)
    yv = torch.where(hv * hv < 1 - 1e-12, hv * dd / torch.sqrt((1 - hv * hv).clamp(min=1e-30)), y1)
    yv = yv.clamp(y0, y1)
    # the point on the quad, back in world space (ex, ey, n frame at x; z0 along n)
    x64 = x.double()
    y = x64 + xu[:, None] * ex.double() + yv[:, None] * ey.double() + z0[:, None] * n.double()
    v = y - x64
    dist = v.norm(dim=1).clamp(min=1e-12)
    w = (v / dist[:, None]).float()
    pdf = torch.where(S > 1e-12, 1.0 / S.clamp(min=1e-30), 0.0).float()
    return w, dist.float(), pdf


def _area_pdf(x, y, n, area, one_sided: bool):
    v = y - x
    d = v.norm(dim=1).clamp(min=1e-8)
    w = v / d[:, None]
    cos_l = -(w * n).sum(1)
    if not one_sided:
        cos_l = cos_l.abs()
    pdf = torch.where(cos_l > 1e-6, d * d / (area * cos_l.clamp(min=1e-6)), 0.0)
    return w, d, pdf


def _cone_solid_angle(x, c, r):
    d2 = ((c - x) ** 2).sum(1)
    sin2 = (r * r / d2.clamp(min=1e-12)).clamp(max=1)
    one_minus_cos = sin2 / (1 + torch.sqrt(1 - sin2))  # stable 1 - cos(theta_max)
    return 2 * math.pi * one_minus_cos.clamp(min=1e-12)


def _cone_sample(x, c, r, u1, u2):
    v = c - x
    d2 = (v * v).sum(1)
    D = d2.sqrt()
    axis = v / D[:, None]
    sin2 = (r * r / d2).clamp(max=1)
    omc = sin2 / (1 + torch.sqrt(1 - sin2))
    one_m_cos_t = u1 * omc
    cos_t = 1 - one_m_cos_t
    sin_t = torch.sqrt((one_m_cos_t * (2 - one_m_cos_t)).clamp(min=0))
    phi = 2 * math.pi * u2
    loc = torch.stack((sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t), 1)
    w = local_to_world(loc, axis)
    # distance to the near side of the sphere along w
    b = (w * v).sum(1)
    disc = (b * b - (d2 - r * r)).clamp(min=0)
    dist = b - disc.sqrt()
    pdf = torch.where(d2 > r * r, 1.0 / (2 * math.pi * omc.clamp(min=1e-12)), 0.0)
    return w, dist, pdf


def _cyl_point(c, r, hh, u0, u1, u2):
    side_a = 2 * math.pi * r * 2 * hh
    cap_a = math.pi * r * r
    f_side = side_a / (side_a + 2 * cap_a)
    side = u0 < f_side
    top = u0 >= f_side + (1 - f_side) / 2
    ang = 2 * math.pi * u1
    side_p = torch.stack((r * torch.cos(ang), (2 * u2 - 1) * hh, r * torch.sin(ang)), 1)
    rad = r * u2.sqrt()
    cap_y = torch.where(top, hh, -hh)
    cap_p = torch.stack((rad * torch.cos(ang), cap_y, rad * torch.sin(ang)), 1)
    p = torch.where(side[:, None], side_p, cap_p)
    side_n = torch.stack((torch.cos(ang), torch.zeros_like(ang), torch.sin(ang)), 1)
    cap_n = torch.zeros_like(side_n)
    cap_n[:, 1] = torch.where(top, 1.0, -1.0)
    return c + p, torch.where(side[:, None], side_n, cap_n)


def _cyl_normal(y, c, r, hh):
    q = y - c
    rad = torch.sqrt(q[:, 0] ** 2 + q[:, 2] ** 2)
    on_side = (rad - r).abs() <= (q[:, 1].abs() - hh).abs()
    side_n = torch.stack((q[:, 0], torch.zeros_like(rad), q[:, 2]), 1) / rad.clamp(min=1e-9)[:, None]
    cap_n = torch.zeros_like(q)
    cap_n[:, 1] = torch.sign(q[:, 1])
    return torch.where(on_side[:, None], side_n, cap_n)
