"""Vectorised ray-primitive intersection in torch (CPU or CUDA) for the synthetic rooms.

Four primitive kinds, each stored as a few tensors so one matrix product tests a chunk of rays
against all primitives of a kind:

* quads: rectangles (centre ``c``, unit edge axes ``ex``, ``ey``, half sizes), normal ``ex x ey``,
  optionally one-sided (only rays travelling against the normal hit them; the room shell, so the
  outside of an L-shaped room never occludes light entering through its windows);
* boxes rotated about +y (centre, half sizes, yaw);
* vertical capped cylinders (centre, radius, half height);
* spheres.

Primitives are numbered globally in that order (quads, boxes, cylinders, spheres).  Everything but
the quads belongs to a culling group (one piece of furniture) with an axis-aligned bounding box: a
ray tests a group's primitives only if it enters the group's box before its current closest hit.

After the closest hit is known, :func:`surface_at` gives the point, the outward normal, the face
index, chart coordinates ``st`` in [0,1]^2 of that face (for light maps) and metric texture
coordinates ``uv``.  :func:`chart_to_surface` is its inverse (texel centres of light maps) and
:func:`surface_distance` an independent distance-to-surface function (tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor

EPS = 1e-4  # minimum hit distance (metres)
CHUNK = 16384  # rays per batch: keeps [chunk, primitives] temporaries in cache
INF = float("inf")

QUAD, BOX, CYL, SPH = 0, 1, 2, 3
FACES = {QUAD: 1, BOX: 6, CYL: 3, SPH: 1}  # chart faces per kind


@dataclass
class Prims:
    """All primitives of a scene in one frame (see the module doc)."""

    q_c: Tensor  # [Q,3]
    q_ex: Tensor  # [Q,3]
    q_ey: Tensor  # [Q,3]
    q_h: Tensor  # [Q,2] half sizes along ex, ey
    q_one_sided: Tensor  # [Q] bool
    q_uv0: Tensor  # [Q,2] texture coordinate at the quad's (-hx,-hy) corner
    b_c: Tensor  # [B,3]
    b_h: Tensor  # [B,3]
    b_yaw: Tensor  # [B]
    c_c: Tensor  # [C,3]
    c_r: Tensor  # [C]
    c_hh: Tensor  # [C]
    s_c: Tensor  # [S,3]
    s_r: Tensor  # [S]
    group: Tensor  # [P] culling group of each primitive (-1: quads, always tested)
    g_lo: Tensor  # [G,3]
    g_hi: Tensor  # [G,3]

    def __post_init__(self):
        self.derive()

    def derive(self) -> None:
        """(Re)compute the tensors derived from the fields; call again after changing a field."""
        self.q_n = torch.linalg.cross(self.q_ex, self.q_ey)
        # o @ q_mat = (o.n, o.ex, o.ey) for every quad
        self.q_mat = torch.cat((self.q_n, self.q_ex, self.q_ey), 0).T.contiguous()  # [3,3Q]
        self.q_off = torch.cat(((self.q_c * self.q_n).sum(1), (self.q_c * self.q_ex).sum(1),
                                (self.q_c * self.q_ey).sum(1)))
        c, s = torch.cos(self.b_yaw), torch.sin(self.b_yaw)
        z, one = torch.zeros_like(c), torch.ones_like(c)
        # rows of R^T: world -> local axes (rotation about +y, pano.yaw_matrix convention)
        self.b_ax = torch.stack((torch.stack((c, z, -s), 1), torch.stack((z, one, z), 1),
                                 torch.stack((s, z, c), 1)), 1)  # [B,3(local axis),3(world)]
        self.b_mat = self.b_ax.permute(2, 1, 0).reshape(3, -1).contiguous()  # [3, 3B] axis-major
        self.b_off = torch.einsum("bkw,bw->kb", self.b_ax, self.b_c).reshape(-1)
        self.counts = (len(self.q_c), len(self.b_c), len(self.c_c), len(self.s_c))
        self.offsets = (0, self.counts[0], sum(self.counts[:2]), sum(self.counts[:3]))
        self.n_prims = sum(self.counts)
        kind = torch.zeros(self.n_prims, dtype=torch.long, device=self.q_c.device)
        for k in (BOX, CYL, SPH):
            kind[self.offsets[k]:self.offsets[k] + self.counts[k]] = k
        self.kind = kind
        g = self.group.tolist()
        self.members = []  # per group: local indices of its boxes, cylinders, spheres
        for gi in range(len(self.g_lo)):
            m = []
            for k in (BOX, CYL, SPH):
                ids = [i - self.offsets[k] for i in range(self.offsets[k], self.offsets[k] + self.counts[k])
                       if g[i] == gi]
                m.append(torch.tensor(ids, dtype=torch.long, device=self.q_c.device))
            self.members.append(m)

    @property
    def device(self) -> torch.device:
        return self.q_c.device

    def to(self, device) -> Prims:
        kw = {f.name: getattr(self, f.name).to(device) for f in fields(self)}
        return Prims(**kw)

    def local_index(self, pid: Tensor, kind: int) -> Tensor:
        return pid - self.offsets[kind]


# ---------------------------------------------------------------------------------------------
# intersection


def intersect(prims: Prims, o: Tensor, d: Tensor, tmax: Tensor | float | None = None,
              skip: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Closest hit of rays ``o, d [N,3]`` (unit d): ``(t [N], pid [N])``; misses give (inf, -1).

    ``tmax`` bounds the search (shadow rays); ``skip [N]`` is a primitive id each ray ignores
    (-1 for none), used to test visibility of a point on an emitter without hitting the emitter.
    """
    N = o.shape[0]
    t_out = torch.full((N,), INF, device=o.device)
    p_out = torch.full((N,), -1, dtype=torch.long, device=o.device)
    if tmax is None:
        tmax_t = torch.full((N,), INF, device=o.device)
    elif isinstance(tmax, Tensor):
        tmax_t = tmax.to(o.dtype).expand(N)
    else:
        tmax_t = torch.full((N,), float(tmax), device=o.device)
    for a in range(0, N, CHUNK):
        b = min(N, a + CHUNK)
        sk = None if skip is None else skip[a:b]
        t, p = _intersect_chunk(prims, o[a:b], d[a:b], tmax_t[a:b].clone(), sk)
        t_out[a:b], p_out[a:b] = t, p
    return t_out, p_out


def _take_min(t: Tensor, t_best: Tensor, p_best: Tensor, offset: int, ids: Tensor | None = None):
    """Fold candidate distances ``t [n,k]`` (inf = no hit) into the running best."""
    if t.shape[1] == 0:
        return
    tm, arg = t.min(1)
    better = tm < t_best
    t_best.copy_(torch.where(better, tm, t_best))
    pid = (arg if ids is None else ids[arg]) + offset
    p_best.copy_(torch.where(better, pid, p_best))


def _skip_mask(t: Tensor, skip: Tensor | None, first_pid: int | Tensor) -> Tensor:
    if skip is None:
        return t
    pid = (first_pid if isinstance(first_pid, Tensor) else
           torch.arange(t.shape[1], device=t.device) + first_pid)
    return torch.where(skip[:, None] == pid[None], INF, t)


def _intersect_chunk(P: Prims, o: Tensor, d: Tensor, t_best: Tensor, skip: Tensor | None):
    N = o.shape[0]
    p_best = torch.full((N,), -1, dtype=torch.long, device=o.device)
    Q = P.counts[QUAD]
    if Q:
        t = _quad_t(P, o, d, t_best)
        _take_min(_skip_mask(t, skip, 0), t_best, p_best, 0)
    if len(P.g_lo) == 0:
        return t_best, p_best
    # group bounding boxes
    inv = 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
    t0 = (P.g_lo[None] - o[:, None]) * inv[:, None]
    t1 = (P.g_hi[None] - o[:, None]) * inv[:, None]
    tn = torch.minimum(t0, t1).amax(2)
    tf = torch.maximum(t0, t1).amin(2)
    enter = (tf >= tn.clamp(min=0)) & (tf > EPS)  # [N,G]
    tn = tn.clamp(min=0)
    for g, (bi, ci, si) in enumerate(P.members):
        idx = torch.nonzero(enter[:, g] & (tn[:, g] < t_best)).squeeze(1)
        if idx.numel() == 0:
            continue
        oo, dd, tb = o[idx], d[idx], t_best[idx]
        pb = p_best[idx]
        sk = None if skip is None else skip[idx]
        if bi.numel():
            _take_min(_skip_mask(_box_t(P, bi, oo, dd, tb), sk, bi + P.offsets[BOX]), tb, pb,
                      P.offsets[BOX], bi)
        if ci.numel():
            _take_min(_skip_mask(_cyl_t(P, ci, oo, dd, tb), sk, ci + P.offsets[CYL]), tb, pb,
                      P.offsets[CYL], ci)
        if si.numel():
            _take_min(_skip_mask(_sph_t(P, si, oo, dd, tb), sk, si + P.offsets[SPH]), tb, pb,
                      P.offsets[SPH], si)
        t_best[idx] = tb
        p_best[idx] = pb
    return t_best, p_best


def _valid(t: Tensor, ok: Tensor, t_best: Tensor) -> Tensor:
    return torch.where(ok & (t > EPS) & (t < t_best[:, None]), t, INF)


def _quad_t(P: Prims, o: Tensor, d: Tensor, t_best: Tensor) -> Tensor:
    Q = P.counts[QUAD]
    op = o @ P.q_mat - P.q_off  # [N,3Q]: (o-c).n, (o-c).ex, (o-c).ey
    dp = d @ P.q_mat
    on, oa, ob = op[:, :Q], op[:, Q:2 * Q], op[:, 2 * Q:]
    dn, da, db = dp[:, :Q], dp[:, Q:2 * Q], dp[:, 2 * Q:]
    safe = torch.where(dn.abs() < 1e-12, torch.full_like(dn, 1e-12), dn)
    t = -on / safe
    a = oa + t * da
    b = ob + t * db
    ok = (a.abs() <= P.q_h[:, 0]) & (b.abs() <= P.q_h[:, 1])
    ok &= ~P.q_one_sided | (dn < 0)
    return _valid(t, ok, t_best)


def _box_t(P: Prims, bi: Tensor, o: Tensor, d: Tensor, t_best: Tensor) -> Tensor:
    B = P.counts[BOX]
    cols = torch.cat((bi, bi + B, bi + 2 * B))
    k = len(bi)
    ol = o @ P.b_mat[:, cols] - P.b_off[cols]  # [n,3k] local origin, axis-major
    dl = d @ P.b_mat[:, cols]
    dl = torch.where(dl.abs() < 1e-12, torch.full_like(dl, 1e-12), dl)
    h = P.b_h[bi].T.reshape(-1)  # axis-major half sizes [3k]
    t0 = (-h - ol) / dl
    t1 = (h - ol) / dl
    tn = torch.minimum(t0, t1)
    tf = torch.maximum(t0, t1)
    tn = torch.maximum(torch.maximum(tn[:, :k], tn[:, k:2 * k]), tn[:, 2 * k:])
    tf = torch.minimum(torch.minimum(tf[:, :k], tf[:, k:2 * k]), tf[:, 2 * k:])
    t = torch.where(tn > EPS, tn, tf)
    return _valid(t, tf >= tn, t_best)


def _cyl_t(P: Prims, ci: Tensor, o: Tensor, d: Tensor, t_best: Tensor) -> Tensor:
    c, r, hh = P.c_c[ci], P.c_r[ci], P.c_hh[ci]
    ox = o[:, 0:1] - c[:, 0]
    oy = o[:, 1:2] - c[:, 1]
    oz = o[:, 2:3] - c[:, 2]
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]
    a = (dx * dx + dz * dz).clamp(min=1e-12)
    b = ox * dx + oz * dz
    cc = ox * ox + oz * oz - r * r
    disc = b * b - a * cc
    sq = disc.clamp(min=0).sqrt()
    best = torch.full_like(ox, INF)
    for t in ((-b - sq) / a, (-b + sq) / a):
        y = oy + t * dy
        best = torch.minimum(best, _valid(t, (disc >= 0) & (y.abs() <= hh), t_best))
    sdy = torch.where(dy.abs() < 1e-12, torch.full_like(dy, 1e-12), dy)
    for cap in (hh, -hh):
        t = (cap - oy) / sdy
        x, z = ox + t * dx, oz + t * dz
        best = torch.minimum(best, _valid(t, x * x + z * z <= r * r, t_best))
    return best


def _sph_t(P: Prims, si: Tensor, o: Tensor, d: Tensor, t_best: Tensor) -> Tensor:
    c, r = P.s_c[si], P.s_r[si]
    oc = o @ c.T  # [n,k]
    b = (d * o).sum(1, keepdim=True) - d @ c.T
    cc = (o * o).sum(1, keepdim=True) - 2 * oc + (c * c).sum(1) - r * r
    disc = b * b - cc
    sq = disc.clamp(min=0).sqrt()
    t0, t1 = -b - sq, -b + sq
    t = torch.where(t0 > EPS, t0, t1)
    return _valid(t, disc >= 0, t_best)


# ---------------------------------------------------------------------------------------------
# surface attributes at hits


@dataclass
class Surface:
    p: Tensor  # [N,3] points
    n: Tensor  # [N,3] outward unit normals (quads: their normal)
    face: Tensor  # [N] chart face
    st: Tensor  # [N,2] chart coordinates in [0,1]
    uv: Tensor  # [N,2] texture coordinates in metres


def surface_at(P: Prims, pid: Tensor, p: Tensor) -> Surface:
    """Attributes of hit points ``p [N,3]`` on primitives ``pid [N]`` (all valid)."""
    N = len(pid)
    dev = p.device
    n = torch.zeros(N, 3, device=dev)
    face = torch.zeros(N, dtype=torch.long, device=dev)
    st = torch.zeros(N, 2, device=dev)
    uv = torch.zeros(N, 2, device=dev)
    kind = P.kind[pid]
    for k in (QUAD, BOX, CYL, SPH):
        m = torch.nonzero(kind == k).squeeze(1)
        if m.numel() == 0:
            continue
        li = pid[m] - P.offsets[k]
        nn, ff, ss, uu = _SURF[k](P, li, p[m])
        n[m], face[m], st[m], uv[m] = nn, ff, ss, uu
    return Surface(p, n, face, st, uv)


def _quad_surf(P, i, p):
    q = p - P.q_c[i]
    a = (q * P.q_ex[i]).sum(1)
    b = (q * P.q_ey[i]).sum(1)
    h = P.q_h[i]
    st = torch.stack(((a / h[:, 0] + 1) / 2, (b / h[:, 1] + 1) / 2), 1).clamp(0, 1)
    uv = torch.stack((a + h[:, 0], b + h[:, 1]), 1) + P.q_uv0[i]
    return P.q_n[i], torch.zeros_like(i), st, uv


# box face f: axis f // 2, sign + for even f; chart axes (the two other local axes)
_BOX_OTHER = torch.tensor([[1, 2], [1, 2], [0, 2], [0, 2], [0, 1], [0, 1]])


def _box_surf(P, i, p):
    ax = P.b_ax[i]  # [n,3,3]
    loc = torch.einsum("nkw,nw->nk", ax, p - P.b_c[i])
    h = P.b_h[i]
    rel = loc / h
    axis = rel.abs().argmax(1)
    sign = torch.gather(rel, 1, axis[:, None]).squeeze(1) >= 0
    face = axis * 2 + (~sign).long()
    nl = torch.zeros_like(loc)
    nl.scatter_(1, axis[:, None], torch.where(sign, 1.0, -1.0)[:, None])
    n = torch.einsum("nkw,nk->nw", ax, nl)
    other = _BOX_OTHER.to(p.device)[face]
    lo = torch.gather(loc, 1, other)
    ho = torch.gather(h, 1, other)
    st = ((lo / ho + 1) / 2).clamp(0, 1)
    return n, face, st, lo + ho


def _cyl_surf(P, i, p):
    c, r, hh = P.c_c[i], P.c_r[i], P.c_hh[i]
    q = p - c
    rad = torch.sqrt(q[:, 0] ** 2 + q[:, 2] ** 2)
    on_side = (rad - r).abs() <= (q[:, 1].abs() - hh).abs()
    top = q[:, 1] > 0
    face = torch.where(on_side, 0, torch.where(top, 1, 2))
    ang = torch.atan2(q[:, 2], q[:, 0])
    side_n = torch.stack((q[:, 0], torch.zeros_like(rad), q[:, 2]), 1) / rad.clamp(min=1e-9)[:, None]
    cap_n = torch.zeros_like(q)
    cap_n[:, 1] = torch.where(top, 1.0, -1.0)
    n = torch.where(on_side[:, None], side_n, cap_n)
    side_st = torch.stack(((ang + math.pi) / (2 * math.pi), (q[:, 1] / hh + 1) / 2), 1)
    cap_st = torch.stack(((q[:, 0] / r + 1) / 2, (q[:, 2] / r + 1) / 2), 1)
    st = torch.where(on_side[:, None], side_st, cap_st).clamp(0, 1)
    side_uv = torch.stack(((ang + math.pi) * r, q[:, 1] + hh), 1)
    uv = torch.where(on_side[:, None], side_uv, q[:, [0, 2]] + r[:, None])
    return n, face, st, uv


def _sph_surf(P, i, p):
    c, r = P.s_c[i], P.s_r[i]
    n = (p - c) / r[:, None]
    n = n / torch.linalg.vector_norm(n, dim=1, keepdim=True)
    lon = torch.atan2(n[:, 0], -n[:, 2])
    lat = torch.asin(n[:, 1].clamp(-1, 1))
    st = torch.stack(((lon + math.pi) / (2 * math.pi), lat / math.pi + 0.5), 1).clamp(0, 1)
    uv = torch.stack(((lon + math.pi) * r, (lat + math.pi / 2) * r), 1)
    return n, torch.zeros_like(i), st, uv


_SURF = {QUAD: _quad_surf, BOX: _box_surf, CYL: _cyl_surf, SPH: _sph_surf}


def chart_to_surface(P: Prims, pid: Tensor, face: Tensor, st: Tensor) -> tuple[Tensor, Tensor]:
    """Points and outward normals ``[N,3]`` at chart coordinates ``st`` of ``face`` of ``pid``."""
    N = len(pid)
    p = torch.zeros(N, 3, device=st.device)
    n = torch.zeros(N, 3, device=st.device)
    kind = P.kind[pid]
    s, t = st[:, 0], st[:, 1]
    for k in (QUAD, BOX, CYL, SPH):
        m = torch.nonzero(kind == k).squeeze(1)
        if m.numel() == 0:
            continue
        i = pid[m] - P.offsets[k]
        sm, tm, fm = s[m], t[m], face[m]
        if k == QUAD:
            h = P.q_h[i]
            pm = (P.q_c[i] + P.q_ex[i] * ((2 * sm - 1) * h[:, 0])[:, None]
                  + P.q_ey[i] * ((2 * tm - 1) * h[:, 1])[:, None])
            nm = P.q_n[i]
        elif k == BOX:
            h = P.b_h[i]
            axis = fm // 2
            sign = torch.where(fm % 2 == 0, 1.0, -1.0)
            loc = torch.zeros(len(i), 3, device=st.device)
            loc.scatter_(1, axis[:, None], (sign * torch.gather(h, 1, axis[:, None]).squeeze(1))[:, None])
            other = _BOX_OTHER.to(st.device)[fm]
            ho = torch.gather(h, 1, other)
            loc.scatter_(1, other, torch.stack(((2 * sm - 1), (2 * tm - 1)), 1) * ho)
            nl = torch.zeros_like(loc)
            nl.scatter_(1, axis[:, None], sign[:, None])
            ax = P.b_ax[i]
            pm = torch.einsum("nkw,nk->nw", ax, loc) + P.b_c[i]
            nm = torch.einsum("nkw,nk->nw", ax, nl)
        elif k == CYL:
            c, r, hh = P.c_c[i], P.c_r[i], P.c_hh[i]
            ang = sm * 2 * math.pi - math.pi
            side = fm == 0
            ca, sa = torch.cos(ang), torch.sin(ang)
            y_side = (2 * tm - 1) * hh
            side_q = torch.stack((r * ca, y_side, r * sa), 1)
            cap_y = torch.where(fm == 1, hh, -hh)
            cap_q = torch.stack(((2 * sm - 1) * r, cap_y, (2 * tm - 1) * r), 1)
            pm = c + torch.where(side[:, None], side_q, cap_q)
            side_n = torch.stack((ca, torch.zeros_like(ca), sa), 1)
            cap_n = torch.zeros_like(side_n)
            cap_n[:, 1] = torch.where(fm == 1, 1.0, -1.0)
            nm = torch.where(side[:, None], side_n, cap_n)
        else:
            lon = sm * 2 * math.pi - math.pi
            lat = (tm - 0.5) * math.pi
            nm = torch.stack((torch.cos(lat) * torch.sin(lon), torch.sin(lat),
                              -torch.cos(lat) * torch.cos(lon)), 1)
            pm = P.s_c[i] + nm * P.s_r[i][:, None]
        p[m], n[m] = pm, nm
    return p, n


def face_extent(P: Prims, pid: int, face: int) -> tuple[float, float]:
    """Metric size (along s, along t) of one chart face: sets light-map resolutions."""
    k = int(P.kind[pid])
    i = pid - P.offsets[k]
    if k == QUAD:
        h = P.q_h[i]
        return 2 * float(h[0]), 2 * float(h[1])
    if k == BOX:
        h = P.b_h[i]
        o = _BOX_OTHER[face]
        return 2 * float(h[o[0]]), 2 * float(h[o[1]])
    if k == CYL:
        r, hh = float(P.c_r[i]), float(P.c_hh[i])
        return (2 * math.pi * r, 2 * hh) if face == 0 else (2 * r, 2 * r)
    r = float(P.s_r[i])
    return 2 * math.pi * r, math.pi * r


# ---------------------------------------------------------------------------------------------
# distance to the analytic surfaces (independent of the intersection code; used by tests)


def surface_distance(P: Prims, p: Tensor) -> Tensor:
    """Unsigned distance ``[N]`` from points ``p [N,3]`` to the nearest primitive surface."""
    best = torch.full((len(p),), INF, device=p.device)
    if P.counts[QUAD]:
        q = p[:, None] - P.q_c[None]
        a = (q * P.q_ex[None]).sum(2)
        b = (q * P.q_ey[None]).sum(2)
        h = (q * P.q_n[None]).sum(2)
        da = (a.abs() - P.q_h[:, 0]).clamp(min=0)
        db = (b.abs() - P.q_h[:, 1]).clamp(min=0)
        best = torch.minimum(best, torch.sqrt(da * da + db * db + h * h).amin(1))
    if P.counts[BOX]:
        loc = torch.einsum("bkw,nbw->nbk", P.b_ax, p[:, None] - P.b_c[None])
        q = loc.abs() - P.b_h[None]
        sdf = torch.linalg.vector_norm(q.clamp(min=0), dim=2) + q.amax(2).clamp(max=0)
        best = torch.minimum(best, sdf.abs().amin(1))
    if P.counts[CYL]:
        q = p[:, None] - P.c_c[None]
        rad = torch.sqrt(q[..., 0] ** 2 + q[..., 2] ** 2)
        dr = rad - P.c_r
        dy = q[..., 1].abs() - P.c_hh
        sdf = torch.sqrt(dr.clamp(min=0) ** 2 + dy.clamp(min=0) ** 2) + torch.maximum(dr, dy).clamp(max=0)
        best = torch.minimum(best, sdf.abs().amin(1))
    if P.counts[SPH]:
        dist = torch.linalg.vector_norm(p[:, None] - P.s_c[None], dim=2) - P.s_r
        best = torch.minimum(best, dist.abs().amin(1))
    return best


def intersect_one(P: Prims, pid: int, o: Tensor, d: Tensor) -> Tensor:
    """Hit distances ``[N]`` of rays against the single primitive ``pid`` (inf: miss)."""
    k = int(P.kind[pid])
    i = pid - P.offsets[k]
    inf = torch.full((len(o),), INF, device=o.device)
    if k == QUAD:
        n, c = P.q_n[i], P.q_c[i]
        dn = d @ n
        t = ((c - o) @ n) / torch.where(dn.abs() < 1e-12, torch.full_like(dn, 1e-12), dn)
        q = o + t[:, None] * d - c
        ok = ((q @ P.q_ex[i]).abs() <= P.q_h[i, 0]) & ((q @ P.q_ey[i]).abs() <= P.q_h[i, 1])
        ok &= (~P.q_one_sided[i]) | (dn < 0)
        return _valid(t[:, None], ok[:, None], inf).squeeze(1)
    idx = torch.tensor([i], device=o.device)
    fn = {BOX: _box_t, CYL: _cyl_t, SPH: _sph_t}[k]
    return fn(P, idx, o, d, inf).squeeze(1)
