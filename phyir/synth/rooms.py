"""Procedural rooms: shell with doors and windows, furniture from primitives, lights, camera.

:func:`generate_room` draws a :class:`Room` from a numpy Generator (so scene ``i`` of a dataset
depends only on its own seed).  A room lives in its own frame (floor at y = 0, footprint in
x, z >= 0); :meth:`Room.build` moves everything into the camera frame of the conventions (camera
at the origin, rotated by the camera's yaw) and packs it into tensors for the tracer.

Furniture items are lists of primitives in a local frame (x along the width, z along the depth,
y up from the floor; the back of wall-standing items at local +z) with an oriented bounding box
(OBB) used for placement: OBBs of different items never overlap, stay inside the room, and keep
door and window zones clear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from phyir.pano import yaw_matrix
from phyir.synth import geometry as G
from phyir.synth.lights import SUN_RADIUS, Lights, Sky
from phyir.synth.materials import MaterialTable, Palette

ROOM_WIDTH = (2.5, 9.0)
ROOM_HEIGHT = (2.4, 3.5)
CAMERA_HEIGHT = (1.2, 1.7)
CAMERA_CLEARANCE = 0.35  # metres from walls and furniture
SOURCES = (1, 6)


@dataclass
class PrimSpec:
    kind: int  # geometry.QUAD/BOX/CYL/SPH
    c: tuple  # centre
    size: tuple  # quad: (ex, ey, hx, hy); box: (hx, hy, hz, yaw); cyl: (r, hh); sphere: (r,)
    mat: int
    group: int = -1  # furniture item (culling group); -1 for shell quads
    emit: tuple | None = None  # radiance of an area light
    portal: bool = False  # window: shows the sky
    one_sided: bool = False
    uv0: tuple = (0.0, 0.0)


@dataclass
class Item:
    name: str
    centre: tuple  # OBB centre (room frame)
    half: tuple  # OBB half sizes (local x, y, z)
    yaw: float
    top: float | None = None  # height of a flat top that can carry small objects
    fixture: bool = False  # door/window frames: attached to the shell, not furniture


@dataclass
class Room:
    polygon: list  # [(x, z)] footprint vertices in order
    height: float
    prims: list = field(default_factory=list)
    items: list = field(default_factory=list)
    materials: list = field(default_factory=list)
    sky: Sky | None = None
    camera: tuple = (0.0, 1.5, 0.0)
    yaw: float = 0.0
    kind: str = "rect"
    reserved: list = field(default_factory=list)  # OBBs (centre, half, yaw) kept free

    # -- geometry helpers ---------------------------------------------------------------------
    def contains(self, x: float, z: float, margin: float = 0.0) -> bool:
        if not _in_polygon(self.polygon, x, z):
            return False
        return _dist_to_polygon_edges(self.polygon, x, z) >= margin

    def camera_matrix(self) -> np.ndarray:
        return yaw_matrix(self.yaw, dtype=torch.float64).numpy()

    def build(self, device=None) -> TraceScene:
        """Tensors in the camera frame for the tracer."""
        R = self.camera_matrix()
        cam = np.asarray(self.camera, dtype=np.float64)
        def tr(p):
            return R @ (np.asarray(p, dtype=np.float64) - cam)
        def rot(v):
            return R @ np.asarray(v, dtype=np.float64)
        quads, boxes, cyls, sphs = [], [], [], []
        for i, p in enumerate(self.prims):
            {G.QUAD: quads, G.BOX: boxes, G.CYL: cyls, G.SPH: sphs}[p.kind].append((i, p))
        order = [i for i, _ in quads + boxes + cyls + sphs]  # room prim index -> global order
        def f(x):
            return torch.tensor(np.asarray(x, dtype=np.float32).reshape(-1))

        def mat3(rows):
            return torch.tensor(np.asarray(rows, dtype=np.float32).reshape(-1, 3))

        def mat2(rows):
            return torch.tensor(np.asarray(rows, dtype=np.float32).reshape(-1, 2))

        cam_yaw = self.yaw
        n_groups = 1 + max([p.group for p in self.prims] + [-1])
        prims = G.Prims(
            q_c=mat3([tr(p.c) for _, p in quads]), q_ex=mat3([rot(p.size[0]) for _, p in quads]),
            q_ey=mat3([rot(p.size[1]) for _, p in quads]), q_h=mat2([p.size[2:4] for _, p in quads]),
            q_one_sided=torch.tensor([p.one_sided for _, p in quads], dtype=torch.bool),
            q_uv0=mat2([p.uv0 for _, p in quads]),
            b_c=mat3([tr(p.c) for _, p in boxes]), b_h=mat3([p.size[:3] for _, p in boxes]),
            b_yaw=f([p.size[3] + cam_yaw for _, p in boxes]),
            c_c=mat3([tr(p.c) for _, p in cyls]), c_r=f([p.size[0] for _, p in cyls]),
            c_hh=f([p.size[1] for _, p in cyls]),
            s_c=mat3([tr(p.c) for _, p in sphs]), s_r=f([p.size[0] for _, p in sphs]),
            group=torch.tensor([self.prims[i].group for i in order], dtype=torch.long),
            g_lo=torch.zeros(n_groups, 3), g_hi=torch.zeros(n_groups, 3))
        lo = np.full((n_groups, 3), np.inf)
        hi = np.full((n_groups, 3), -np.inf)
        for gi, i in enumerate(order):
            p = self.prims[i]
            if p.group < 0:
                continue
            a, b = _prim_bounds(prims, gi)
            lo[p.group] = np.minimum(lo[p.group], a)
            hi[p.group] = np.maximum(hi[p.group], b)
        prims.g_lo = torch.tensor(lo - 1e-3, dtype=torch.float32)
        prims.g_hi = torch.tensor(hi + 1e-3, dtype=torch.float32)
        prims._derive()
        prims = prims.to(device)
        prim_mat = torch.tensor([self.prims[i].mat for i in order], dtype=torch.long, device=device)
        emit = [(gi, self.prims[i]) for gi, i in enumerate(order)
                if self.prims[i].emit is not None or self.prims[i].portal]
        sky = self.sky.rotated(R) if self.sky is not None else None
        lights = Lights.build(prims, emit, sky, device)
        return TraceScene(prims, MaterialTable.from_list(self.materials, device), prim_mat, lights)

    def summary(self) -> dict:
        xs = [p[0] for p in self.polygon]
        zs = [p[1] for p in self.polygon]
        return {"kind": self.kind, "width": max(xs) - min(xs), "depth": max(zs) - min(zs),
                "height": self.height, "items": [it.name for it in self.items if not it.fixture]}


@dataclass
class TraceScene:
    prims: G.Prims
    materials: MaterialTable
    prim_mat: torch.Tensor
    lights: Lights

    @property
    def device(self):
        return self.prims.device


def _prim_bounds(P: G.Prims, gid: int) -> tuple[np.ndarray, np.ndarray]:
    k = int(P.kind[gid])
    i = gid - P.offsets[k]
    if k == G.BOX:
        c = P.b_c[i].double().numpy()
        ax = P.b_ax[i].double().numpy()  # rows: local axes in world
        ext = np.abs(ax.T) @ P.b_h[i].double().numpy()
        return c - ext, c + ext
    if k == G.CYL:
        c = P.c_c[i].double().numpy()
        r, hh = float(P.c_r[i]), float(P.c_hh[i])
        e = np.array([r, hh, r])
        return c - e, c + e
    if k == G.SPH:
        c = P.s_c[i].double().numpy()
        r = float(P.s_r[i])
        return c - r, c + r
    raise ValueError("quads have no culling group")


# ---------------------------------------------------------------------------------------------
# 2D helpers


def _in_polygon(poly, x, z) -> bool:
    inside = False
    n = len(poly)
    for i in range(n):
        x1, z1 = poly[i]
        x2, z2 = poly[(i + 1) % n]
        if (z1 > z) != (z2 > z):
            xi = x1 + (z - z1) * (x2 - x1) / (z2 - z1)
            if xi > x:
                inside = not inside
    return inside


def _dist_to_polygon_edges(poly, x, z) -> float:
    best = math.inf
    n = len(poly)
    for i in range(n):
        a = np.array(poly[i], float)
        b = np.array(poly[(i + 1) % n], float)
        p = np.array((x, z))
        t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0, 1)
        best = min(best, float(np.linalg.norm(p - (a + t * (b - a)))))
    return best


def obb_corners(centre, half, yaw) -> np.ndarray:
    """Footprint corners [4,2] (x, z) of an OBB."""
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hz = half[0], half[2]
    loc = np.array([[-hx, -hz], [hx, -hz], [hx, hz], [-hx, hz]])
    # local (x, z) -> world with R(yaw): x' = c x + s z, z' = -s x + c z
    return np.stack((c * loc[:, 0] + s * loc[:, 1] + centre[0],
                     -s * loc[:, 0] + c * loc[:, 1] + centre[2]), 1)


def obb_overlap(a: Item | tuple, b: Item | tuple, margin: float = 0.0) -> bool:
    """Do two y-rotated OBBs overlap (by more than -margin)? Separating-axis test."""
    ca, ha, ya = (a.centre, a.half, a.yaw) if isinstance(a, Item) else a
    cb, hb, yb = (b.centre, b.half, b.yaw) if isinstance(b, Item) else b
    if abs(ca[1] - cb[1]) >= ha[1] + hb[1] - 1e-9:  # stacking (touching in y) is allowed
        return False
    pa, pb = obb_corners(ca, ha, ya), obb_corners(cb, hb, yb)
    for poly in (pa, pb):
        for i in range(2):
            e = poly[i + 1] - poly[i]
            ax = np.array((-e[1], e[0])) / np.linalg.norm(e)
            ra, rb = pa @ ax, pb @ ax
            if ra.max() + margin <= rb.min() + 1e-9 or rb.max() + margin <= ra.min() + 1e-9:
                return False
    return True


def point_in_obb(p, item: Item, margin: float = 0.0) -> bool:
    c, s = math.cos(item.yaw), math.sin(item.yaw)
    dx, dy, dz = p[0] - item.centre[0], p[1] - item.centre[1], p[2] - item.centre[2]
    lx = c * dx - s * dz
    lz = s * dx + c * dz
    h = item.half
    return abs(lx) <= h[0] + margin and abs(dy) <= h[1] + margin and abs(lz) <= h[2] + margin


# ---------------------------------------------------------------------------------------------
# generation


def generate_room(rng: np.random.Generator) -> Room:
    """Draw one furnished, lit room with a camera."""
    for _ in range(20):
        room = _try_room(rng)
        if room is not None:
            return room
    raise RuntimeError("generate_room: could not place a camera in 20 attempts")


def _try_room(rng: np.random.Generator) -> Room | None:
    W = float(rng.uniform(*ROOM_WIDTH))
    D = float(rng.uniform(max(ROOM_WIDTH[0], 0.5 * W), min(ROOM_WIDTH[1], 1.6 * W)))
    H = float(rng.uniform(*ROOM_HEIGHT))
    if rng.random() < 0.35 and min(W, D) > 3.5:
        cw, cd = float(rng.uniform(0.3, 0.55) * W), float(rng.uniform(0.3, 0.55) * D)
        poly = [(0, 0), (W, 0), (W, D - cd), (W - cw, D - cd), (W - cw, D), (0, D)]
        rects = [(0, W, 0, D - cd), (0, W - cw, D - cd, D)]
        reentrant = {2, 3}
        kind = "L"
    else:
        poly = [(0, 0), (W, 0), (W, D), (0, D)]
        rects = [(0, W, 0, D)]
        reentrant = set()
        kind = "rect"
    room = Room(polygon=[(float(x), float(z)) for x, z in poly], height=H, kind=kind)
    pal = Palette(rng)
    b = _Builder(room, pal, rng)
    b.shell(rects, reentrant)
    b.furnish()
    b.lights()
    if not b.place_camera():
        return None
    room.materials = pal.materials
    return room


class _Builder:
    def __init__(self, room: Room, pal: Palette, rng: np.random.Generator):
        self.room, self.pal, self.rng = room, pal, rng
        self.walls = []  # (start (x,z), dir (x,z), inward normal (x,z), length, u offset)
        self.openings = {}  # wall index -> [(x0, x1, y0, y1, kind)]
        self.n_windows = 0
        self.n_lamps = 0
        self.group = 0

    # -- shell --------------------------------------------------------------------------------
    def shell(self, rects, reentrant):
        room, rng, pal = self.room, self.rng, self.pal
        H = room.height
        floor, ceil, wall = pal.floor(), pal.ceiling(), pal.wall()
        for x0, x1, z0, z1 in rects:
            cx, cz, hx, hz = (x0 + x1) / 2, (z0 + z1) / 2, (x1 - x0) / 2, (z1 - z0) / 2
            room.prims.append(PrimSpec(G.QUAD, (cx, 0.0, cz), ((1, 0, 0), (0, 0, -1), hx, hz), floor,
                                       one_sided=True, uv0=(x0, -z1)))
            room.prims.append(PrimSpec(G.QUAD, (cx, H, cz), ((1, 0, 0), (0, 0, 1), hx, hz), ceil,
                                       one_sided=True, uv0=(x0, z0)))
        poly = room.polygon
        u = 0.0
        for i in range(len(poly)):
            a, b = np.array(poly[i], float), np.array(poly[(i + 1) % len(poly)], float)
            L = float(np.linalg.norm(b - a))
            e = (b - a) / L
            n_in = np.array((-e[1], e[0]))
            mid = (a + b) / 2 + 0.01 * n_in
            if not _in_polygon(poly, *mid):
                n_in = -n_in
            self.walls.append((a, e, n_in, L, u))
            u += L
        # lighting plan: windows, panels, lamps
        n_src = int(rng.integers(SOURCES[0], SOURCES[1] + 1))
        n_win = int(min(rng.choice([0, 1, 1, 2, 2, 3]), n_src))
        self.plan = {"windows": n_win, "rest": n_src - n_win}
        candidates = [i for i in range(len(self.walls)) if i not in reentrant and self.walls[i][3] > 1.6]
        # door(s)
        for _ in range(1 if rng.random() < 0.85 else 2):
            i = int(rng.integers(len(self.walls)))
            w, h = float(rng.uniform(0.8, 1.0)), float(rng.uniform(2.0, min(2.2, H - 0.2)))
            self._add_opening(i, w, 0.0, h, "door")
        placed = 0
        for _ in range(n_win * 10):
            if placed == n_win or not candidates:
                break
            i = int(rng.choice(candidates))
            w = float(rng.uniform(0.7, min(2.4, self.walls[i][3] - 0.8)))
            sill = float(rng.uniform(0.5, 1.0))
            h = float(rng.uniform(1.0, min(1.8, H - sill - 0.25)))
            placed += self._add_opening(i, w, sill, sill + h, "window")
        self.n_windows = placed
        for i, (a, e, n_in, L, u0) in enumerate(self.walls):
            self._wall_pieces(i, a, e, n_in, L, u0, wall)

    def _add_opening(self, i, w, y0, y1, kind) -> bool:
        L = self.walls[i][3]
        if L < w + 0.6:
            return False
        ops = self.openings.setdefault(i, [])
        for _ in range(20):
            x0 = float(self.rng.uniform(0.3, L - 0.3 - w))
            if all(x0 + w + 0.3 <= o[0] or o[1] + 0.3 <= x0 for o in ops):
                ops.append((x0, x0 + w, y0, y1, kind))
                ops.sort()
                return True
        return False

    def _wall_pieces(self, i, a, e, n_in, L, u0, mat):
        room, H = self.room, self.room.height
        e3 = (float(e[0]), 0.0, float(e[1]))
        # normal = ex x ey must point inward: ex = e, ey = up gives (-e_z, 0, e_x)
        flip = (-e[1] * n_in[0] + e[0] * n_in[1]) < 0
        ex = tuple(-x for x in e3) if flip else e3

        def piece(x0, x1, y0, y1, m=mat, **kw):
            if x1 - x0 < 1e-6 or y1 - y0 < 1e-6:
                return
            xm = (x0 + x1) / 2
            c = (float(a[0] + e[0] * xm), (y0 + y1) / 2, float(a[1] + e[1] * xm))
            # texture u runs along the perimeter; with a flipped axis, the corner is at x1
            uv0 = (-(u0 + x1), y0) if flip else (u0 + x0, y0)
            room.prims.append(PrimSpec(G.QUAD, c, (ex, (0, 1, 0), (x1 - x0) / 2, (y1 - y0) / 2), m,
                                       one_sided=True, uv0=uv0, **kw))

        x = 0.0
        for x0, x1, y0, y1, kind in self.openings.get(i, []):
            piece(x, x0, 0.0, H)
            piece(x0, x1, 0.0, y0)
            piece(x0, x1, y1, H)
            x = x1
            if kind == "window":
                piece(x0, x1, y0, y1, m=self.pal.emitter_body(), portal=True)
                self._window_trim(a, e, n_in, x0, x1, y0, y1)
            else:
                self._door(a, e, n_in, x0, x1, y1)
        piece(x, L, 0.0, H)

    def _fixture(self, name, a, e, n_in, xm, ym, w, h, depth, parts):
        """Register an item attached to a wall at along-wall position xm, height ym."""
        c = a + e * xm + n_in * depth / 2
        yaw = math.atan2(-n_in[0], -n_in[1])
        self._add_item(Item(name, (float(c[0]), ym, float(c[1])), (w / 2, h / 2, depth / 2), yaw,
                            fixture=True), parts, base_y=ym - h / 2)

    def _window_trim(self, a, e, n_in, x0, x1, y0, y1):
        pal, rng = self.pal, self.rng
        frame = pal.plastic(glossy=False) if rng.random() < 0.6 else pal.wood()
        w, h = x1 - x0, y1 - y0
        t, d, D = 0.06, 0.04, 0.2  # frame width, frame depth, fixture depth (local +z: the wall)
        zf = D / 2 - d / 2
        parts = [("box", (-w / 2 - t / 2, h / 2 + t, zf), (t / 2, h / 2 + t, d / 2), frame),
                 ("box", (w / 2 + t / 2, h / 2 + t, zf), (t / 2, h / 2 + t, d / 2), frame),
                 ("box", (0, h + t * 1.5, zf), (w / 2, t / 2, d / 2), frame),
                 ("box", (0, t / 2, D / 2 - 0.08), (w / 2 + t, t / 2, 0.08), frame)]
        if rng.random() < 0.6:  # mullions
            parts.append(("box", (0, t + h / 2, zf), (0.025, h / 2, d / 2), frame))
            if rng.random() < 0.5:
                parts.append(("box", (0, t + h * 0.6, zf), (w / 2, 0.025, d / 2), frame))
        self._fixture("window", a, e, n_in, (x0 + x1) / 2, y0 + h / 2, w + 2 * t, h + 2 * t, D, parts)
        # keep a zone in front of the window free of tall furniture
        c = a + e * (x0 + x1) / 2 + n_in * 0.25
        self.room.reserved.append(((float(c[0]), (y0 + y1) / 2, float(c[1])), (w / 2, (y1 - y0) / 2, 0.25),
                                   math.atan2(-n_in[0], -n_in[1])))

    def _door(self, a, e, n_in, x0, x1, y1):
        pal = self.pal
        leaf = pal.wood() if self.rng.random() < 0.5 else pal.plastic(glossy=False)
        frame = pal.plastic(glossy=False)
        knob = pal.metal()
        w, h, t = x1 - x0, y1, 0.05
        parts = [("box", (0, h / 2, 0.04 - 0.01), (w / 2, h / 2, 0.01), leaf),
                 ("box", (-w / 2 - t / 2, (h + t) / 2, 0.02), (t / 2, (h + t) / 2, 0.02), frame),
                 ("box", (w / 2 + t / 2, (h + t) / 2, 0.02), (t / 2, (h + t) / 2, 0.02), frame),
                 ("box", (0, h + t / 2, 0.02), (w / 2, t / 2, 0.02), frame),
                 ("sph", (w / 2 - 0.08, 1.0, 0.04 - 0.02 - 0.035), (0.035,), knob)]
        # local +z runs toward the wall; the fixture box is 0.08 deep, its back on the wall plane
        self._fixture("door", a, e, n_in, (x0 + x1) / 2, (h + t) / 2, w + 2 * t, h + t, 0.08, parts)
        c = a + e * (x0 + x1) / 2 + n_in * 0.6
        self.room.reserved.append(((float(c[0]), h / 2, float(c[1])), (w / 2 + 0.1, h / 2, 0.55),
                                   math.atan2(-n_in[0], -n_in[1])))

    # -- items --------------------------------------------------------------------------------
    def _add_item(self, item: Item, parts, base_y: float = 0.0):
        """Append an item's primitives (local parts -> room frame) as one culling group."""
        room = self.room
        R = yaw_matrix(item.yaw, dtype=torch.float64).numpy()
        org = np.array((item.centre[0], base_y, item.centre[2]))
        for part in parts:
            kind, c, s, m = part[:4]
            emit = part[4] if len(part) > 4 else None
            p = R @ np.asarray(c, float) + org
            pc = tuple(float(x) for x in p)
            if kind == "box":
                room.prims.append(PrimSpec(G.BOX, pc, (*s, item.yaw), m, self.group, emit))
            elif kind == "cyl":
                room.prims.append(PrimSpec(G.CYL, pc, s, m, self.group, emit))
            else:
                room.prims.append(PrimSpec(G.SPH, pc, s, m, self.group, emit))
        room.items.append(item)
        self.group += 1

    def _fits(self, item: Item) -> bool:
        room = self.room
        corners = obb_corners(item.centre, item.half, item.yaw)
        if not all(room.contains(x, z, 0.0) for x, z in corners):
            return False
        for px, pz in room.polygon:  # a reentrant corner poking into the footprint
            if point_in_obb((px, item.centre[1], pz), item, -1e-6):
                return False
        if item.centre[1] + item.half[1] > room.height - 0.05:
            return False
        others = [(it.centre, it.half, it.yaw) for it in room.items] + room.reserved
        return not any(obb_overlap(item, o, 0.02) for o in others)

    def _place(self, name, half, parts, wall: bool, top=None, y_base=0.0, tries=40) -> Item | None:
        rng = self.rng
        hx, hy, hz = half
        for _ in range(tries):
            if wall:
                a, e, n_in, L, _ = self.walls[int(rng.integers(len(self.walls)))]
                if L < 2 * hx + 0.1:
                    continue
                xm = float(rng.uniform(hx + 0.02, L - hx - 0.02))
                c = a + e * xm + n_in * (hz + 0.01)
                yaw = math.atan2(-n_in[0], -n_in[1])
            else:
                xs = [p[0] for p in self.room.polygon]
                zs = [p[1] for p in self.room.polygon]
                c = np.array((rng.uniform(min(xs), max(xs)), rng.uniform(min(zs), max(zs))))
                yaw = float(rng.uniform(-math.pi, math.pi)) if rng.random() < 0.5 else \
                    float(rng.integers(4)) * math.pi / 2
            item = Item(name, (float(c[0]), y_base + hy, float(c[1])), (hx, hy, hz), yaw,
                        top=None if top is None else top + y_base)
            if self._fits(item):
                self._add_item(item, parts, base_y=y_base)
                return item
        return None

    def _place_on(self, name, half, parts) -> Item | None:
        """Put a small object on a table, cabinet or shelf top."""
        rng = self.rng
        supports = [it for it in self.room.items if it.top is not None]
        for _ in range(20):
            if not supports:
                return None
            s = supports[int(rng.integers(len(supports)))]
            fx, fz = s.half[0] - half[0] - 0.03, s.half[2] - half[2] - 0.03
            if fx <= 0 or fz <= 0:
                continue
            lx, lz = rng.uniform(-fx, fx), rng.uniform(-fz, fz)
            c, sn = math.cos(s.yaw), math.sin(s.yaw)
            x = s.centre[0] + c * lx + sn * lz
            z = s.centre[2] - sn * lx + c * lz
            item = Item(name, (x, s.top + half[1], z), half, s.yaw + float(rng.uniform(-0.5, 0.5)))
            if self._fits(item):
                self._add_item(item, parts, base_y=s.top)
                return item
        return None

    def furnish(self):
        rng, pal = self.rng, self.pal
        area = _polygon_area(self.room.polygon)
        n_items = int(np.clip(rng.poisson(2 + area / 6), 2, 12))
        makers = [_bed, _table, _shelf, _cabinet, _sofa, _rug, _cabinet, _table, _mirror, _art]
        weights = np.array([0.8, 1.2, 1.0, 1.2, 1.0, 0.6, 0.6, 0.4, 0.5, 0.6])
        for _ in range(n_items):
            mk = makers[int(rng.choice(len(makers), p=weights / weights.sum()))]
            name, half, parts, wall, top, y0 = mk(rng, pal)
            self._place(name, half, parts, wall, top, y0)
        for _ in range(int(rng.integers(1, 5))):
            mk = [_vase, _ball, _vase][int(rng.integers(3))]
            name, half, parts = mk(rng, pal)
            if self._place_on(name, half, parts) is None and name == "vase" and rng.random() < 0.5:
                self._place(name, half, parts, wall=False)

    # -- lights -------------------------------------------------------------------------------
    def lights(self):
        rng, pal, room = self.rng, self.pal, self.room
        rest = self.plan["rest"] + (self.plan["windows"] - self.n_windows)
        # dynamic range: a sky seen through a window is only ~20-80x the walls it lights, so a room
        # without the sun (whose disc is >= 10^2x the walls) always gets a compact artificial source
        sunny = self.n_windows > 0 and rng.random() < 0.65
        if not sunny:
            rest = max(rest, 1)
        n_lamps = int(rng.integers(0, min(2, rest) + 1))
        n_panels = rest - n_lamps
        body = pal.emitter_body()
        def tint():
            return _light_colour(rng)
        made_panels = 0
        for _ in range(n_panels * 20):
            if made_panels == n_panels:
                break
            w, d = float(rng.uniform(0.25, 0.9)), float(rng.uniform(0.25, 0.5))
            xs = [p[0] for p in room.polygon]
            zs = [p[1] for p in room.polygon]
            x, z = float(rng.uniform(min(xs), max(xs))), float(rng.uniform(min(zs), max(zs)))
            corners = [(x - w / 2, z - d / 2), (x + w / 2, z - d / 2), (x + w / 2, z + d / 2),
                       (x - w / 2, z + d / 2)]
            if not all(room.contains(cx, cz, 0.25) for cx, cz in corners):
                continue
            box = ((x, room.height - 0.05, z), (w / 2 + 0.1, 0.05, d / 2 + 0.1), 0.0)
            if any(obb_overlap(box, (it.centre, it.half, it.yaw)) for it in room.items):
                continue
            Le = float(rng.uniform(15, 45)) * tint()
            room.prims.append(PrimSpec(G.QUAD, (x, room.height - 0.005, z),
                                       ((1, 0, 0), (0, 0, 1), w / 2, d / 2), body, emit=tuple(Le),
                                       one_sided=True))
            room.items.append(Item("panel", box[0], box[1], 0.0, fixture=True))
            made_panels += 1
        for _ in range(n_lamps):
            if rng.random() < 0.5 and self._table_lamp(body, tint()):
                self.n_lamps += 1
            elif self._floor_lamp(body, tint()):
                self.n_lamps += 1
        if made_panels + self.n_lamps == 0 and not sunny:  # nothing fitted: a small panel
            xs = [p[0] for p in room.polygon]
            zs = [p[1] for p in room.polygon]
            x, z = (min(xs) + max(xs)) / 4, (min(zs) + max(zs)) / 4
            room.prims.append(PrimSpec(G.QUAD, (x, room.height - 0.005, z), ((1, 0, 0), (0, 0, 1), 0.2, 0.2),
                                       body, emit=tuple(20 * tint()), one_sided=True))
        room.sky = Sky.random(rng, sun=sunny)
        # own stream (a jumped copy): the room's later draws stay those of the unbalanced version
        balance_sources(room, np.random.Generator(rng.bit_generator.jumped()))

    def _floor_lamp(self, body, tint) -> bool:
        rng, pal = self.rng, self.pal
        metal = pal.metal()
        h = float(rng.uniform(1.3, 1.7))
        parts = [("cyl", (0, 0.015, 0), (0.14, 0.015), metal),
                 ("cyl", (0, h / 2, 0), (0.015, h / 2 - 0.01), metal)]
        if rng.random() < 0.5:
            r = float(rng.uniform(0.1, 0.16))
            parts.append(("sph", (0, h + r * 0.9, 0), (r,), body, tuple(float(rng.uniform(15, 60)) * tint)))
            top, hw = h + 1.9 * r, r
        else:
            r, hh = float(rng.uniform(0.14, 0.22)), float(rng.uniform(0.1, 0.15))
            le = tuple(float(rng.uniform(10, 35)) * tint)
            parts.append(("cyl", (0, h + hh * 0.6, 0), (r, hh), body, le))
            top, hw = h + 1.6 * hh, r
        hw = max(hw, 0.14)
        return self._place("floor lamp", (hw, top / 2, hw), parts, wall=rng.random() < 0.5) is not None

    def _table_lamp(self, body, tint) -> bool:
        rng, pal = self.rng, self.pal
        base = pal.ceramic() if rng.random() < 0.5 else pal.metal()
        r = float(rng.uniform(0.07, 0.11))
        h = float(rng.uniform(0.2, 0.35))
        parts = [("cyl", (0, 0.02, 0), (0.07, 0.02), base),
                 ("cyl", (0, h / 2, 0), (0.012, h / 2 - 0.01), base),
                 ("sph", (0, h + r * 0.9, 0), (r,), body, tuple(float(rng.uniform(20, 80)) * tint))]
        half = (max(r, 0.07), (h + 1.9 * r) / 2, max(r, 0.07))
        return self._place_on("table lamp", half, parts) is not None

    # -- camera -------------------------------------------------------------------------------
    def place_camera(self) -> bool:
        rng, room = self.rng, self.room
        xs = [p[0] for p in room.polygon]
        zs = [p[1] for p in room.polygon]
        for _ in range(200):
            x, z = float(rng.uniform(min(xs), max(xs))), float(rng.uniform(min(zs), max(zs)))
            y = float(rng.uniform(*CAMERA_HEIGHT))
            if not room.contains(x, z, CAMERA_CLEARANCE + 0.15):
                continue
            if any(point_in_obb((x, y, z), it, CAMERA_CLEARANCE) or
                   point_in_obb((x, it.centre[1], z), it, CAMERA_CLEARANCE)
                   for it in room.items
                   if it.centre[1] + it.half[1] > 0.05 and it.centre[1] - it.half[1] < 1.9):
                continue
            room.camera = (x, y, z)
            room.yaw = float(rng.uniform(-math.pi, math.pi))
            return True
        return False


# Dynamic range: the brightest panel/lamp is drawn SOURCE_RATIO (log-uniform, decades) times the
# radiance of the walls it and the other sources light, estimated in closed form (wall_radiance)
SOURCE_RATIO = (2.6, 3.5)
WALL_GAIN = 0.8  # calibration of wall_radiance against rendered medians (docs/synthetic-data.md)


def _flux(p: PrimSpec) -> float:
    """Radiant flux (channel mean) of an area light or a window (sky and sun)."""
    if p.kind == G.QUAD:
        area = 4 * p.size[2] * p.size[3]
    elif p.kind == G.SPH:
        area = 4 * math.pi * p.size[0] ** 2
    else:
        r, hh = p.size
        area = 2 * math.pi * r * 2 * hh + 2 * math.pi * r * r
    return math.pi * float(np.mean(p.emit)) * area


def _window_flux(room: Room, p: PrimSpec) -> float:
    sky = room.sky
    area = 4 * p.size[2] * p.size[3]
    sky_mean = float(np.mean(sky.zenith + 2 * sky.horizon + sky.ground)) / 4
    out = math.pi * sky_mean * area
    if sky.sun_dir is not None:  # the window's normal cross(ex, ey) points into the room
        n = np.cross(np.asarray(p.size[0], float), np.asarray(p.size[1], float))
        e_sun = float(np.mean(sky.sun_radiance)) * 2 * math.pi * (1 - math.cos(SUN_RADIUS))
        out += e_sun * area * max(0.0, -float(np.dot(sky.sun_dir, n)))
    return out


def wall_radiance(room: Room, flux: float) -> float:
    """Radiance of a typical lit surface for ``flux`` entering the room: irradiance
    flux / (shell area x (1 - mean albedo)) with interreflections, times albedo / pi (albedos 0.5)."""
    perimeter = sum(math.dist(room.polygon[i], room.polygon[i - 1]) for i in range(len(room.polygon)))
    shell = 2 * _polygon_area(room.polygon) + perimeter * room.height
    return WALL_GAIN * flux / (math.pi * shell)


def balance_sources(room: Room, rng: np.random.Generator) -> float | None:
    """Scale the panels and lamps so the brightest is a drawn 10^SOURCE_RATIO times the estimated
    wall radiance (the sky and the sun stay as drawn: windows set the rest of the light). Returns the
    ratio aimed at, None for a room without panels or lamps."""
    target = 10 ** float(rng.uniform(*SOURCE_RATIO))
    lamps = [p for p in room.prims if p.emit is not None]
    if not lamps:
        return None
    nat = sum(_window_flux(room, p) for p in room.prims if p.portal)
    key = max(lamps, key=lambda p: float(np.mean(p.emit)))
    l_key = float(np.mean(key.emit))
    f_key = _flux(key)
    f_oth = sum(_flux(p) for p in lamps if p is not key)
    per_flux = wall_radiance(room, 1.0)
    # the key source alone bounds the reachable ratio (its radiance over the walls it lights alone
    # depends only on its area): a panel too large for the lower bound is made smaller
    reach = 0.7 * l_key / (per_flux * f_key)
    if key.kind == G.QUAD and reach < 10 ** SOURCE_RATIO[0]:
        k = max(0.3, math.sqrt(reach / 10 ** SOURCE_RATIO[0]))
        key.size = (*key.size[:2], key.size[2] * k, key.size[3] * k)
        f_key = _flux(key)
    # dim the others so that the panels and lamps together leave room for the windows' light (or,
    # without windows, reach the target); then scale all of them against the windows' light
    target = min(target, 0.7 * l_key / (per_flux * f_key))
    t = 1.0
    if f_oth > 0:
        t = min(1.0, max(0.02, ((0.7 if nat > 0 else 1.0) * l_key / (per_flux * target) - f_key) / f_oth))
    s = 1.0
    if nat > 0:
        s = target * per_flux * nat / max(l_key - target * per_flux * (f_key + t * f_oth), 0.05 * l_key)
    for p in lamps:
        p.emit = tuple(float(v) * s * (1.0 if p is key else t) for v in p.emit)
    return target


def _polygon_area(poly) -> float:
    a = 0.0
    for i in range(len(poly)):
        x1, z1 = poly[i]
        x2, z2 = poly[(i + 1) % len(poly)]
        a += x1 * z2 - x2 * z1
    return abs(a) / 2


def _light_colour(rng) -> np.ndarray:
    """Linear RGB tint of a light from warm (2700 K) to cool (6500 K), unit mean."""
    t = rng.random()
    warm, cool = np.array((1.0, 0.72, 0.45)), np.array((0.92, 0.98, 1.1))
    c = warm + (cool - warm) * t
    return c / c.mean()


# ---------------------------------------------------------------------------------------------
# furniture makers: (name, OBB half sizes, parts, against wall, top height, base y)


def _legs(w, d, h, r, m, inset=0.05, cyl=False):
    out = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            c = (sx * (w / 2 - inset), h / 2, sz * (d / 2 - inset))
            out.append(("cyl", c, (r, h / 2), m) if cyl else ("box", c, (r, h / 2, r), m))
    return out


def _bed(rng, pal):
    w = float(rng.choice([0.95, 1.4, 1.6, 1.8])) + float(rng.uniform(-0.05, 0.05))
    L = float(rng.uniform(1.95, 2.1))
    frame = pal.wood() if rng.random() < 0.6 else pal.fabric()
    sheet, blanket, pillow = pal.fabric(), pal.fabric(), pal.fabric()
    hb = float(rng.uniform(0.8, 1.1))
    parts = [("box", (0, 0.15, 0), (w / 2, 0.15, L / 2), frame),
             ("box", (0, 0.4, 0.02), (w / 2 - 0.03, 0.1, L / 2 - 0.06), sheet),
             ("box", (0, 0.44, -L * 0.15), (w / 2 - 0.01, 0.075, L * 0.33), blanket),
             ("box", (0, hb / 2, L / 2 - 0.03), (w / 2, hb / 2, 0.03), frame)]
    n_p = 1 if w < 1.2 else 2
    for k in range(n_p):
        x = 0 if n_p == 1 else (k - 0.5) * w / 2
        pw = min(0.3, w / 4 - 0.02) if n_p == 2 else 0.3
        parts.append(("box", (x, 0.55, L / 2 - 0.3), (pw, 0.06, 0.18), pillow))
    return "bed", (w / 2, hb / 2, L / 2), parts, True, None, 0.0


def _table(rng, pal):
    w, d = float(rng.uniform(0.8, 1.8)), float(rng.uniform(0.6, 0.95))
    h = float(rng.uniform(0.7, 0.77))
    top = pal.wood(glossy=rng.random() < 0.5) if rng.random() < 0.6 else pal.plastic()
    legm = pal.metal() if rng.random() < 0.4 else top
    parts = [("box", (0, h - 0.02, 0), (w / 2, 0.02, d / 2), top)]
    parts += _legs(w, d, h - 0.04, 0.025, legm, cyl=rng.random() < 0.5)
    return "table", (w / 2, h / 2, d / 2), parts, rng.random() < 0.4, h, 0.0


def _shelf(rng, pal):
    w, d, h = float(rng.uniform(0.6, 1.2)), float(rng.uniform(0.28, 0.4)), float(rng.uniform(1.4, 2.1))
    m = pal.wood() if rng.random() < 0.6 else pal.plastic(glossy=False)
    t = 0.02
    parts = [("box", (-w / 2 + t, h / 2, 0), (t, h / 2, d / 2), m),
             ("box", (w / 2 - t, h / 2, 0), (t, h / 2, d / 2), m),
             ("box", (0, h / 2, d / 2 - 0.005), (w / 2 - 2 * t, h / 2, 0.005), m)]
    n = int(rng.integers(3, 6))
    for k in range(n + 1):
        y = t + k * (h - 2 * t) / n
        parts.append(("box", (0, y, 0), (w / 2 - 2 * t, t, d / 2 - 0.01), m))
        if k < n and rng.random() < 0.7:  # a row of books
            x = -w / 2 + 3 * t
            while x < w / 2 - 0.15 and rng.random() < 0.85:
                bw = float(rng.uniform(0.02, 0.05))
                bh = float(rng.uniform(0.15, min(0.3, (h - 2 * t) / n - 0.05)))
                cover = pal.plastic() if rng.random() < 0.5 else pal.fabric()
                parts.append(("box", (x + bw / 2, y + t + bh / 2, -0.01),
                              (bw / 2 - 0.002, bh / 2, d / 2 - 0.05), cover))
                x += bw
    return "shelf", (w / 2, h / 2, d / 2), parts, True, None, 0.0


def _cabinet(rng, pal):
    w, d, h = float(rng.uniform(0.5, 1.6)), float(rng.uniform(0.4, 0.6)), float(rng.uniform(0.6, 1.0))
    body = pal.wood() if rng.random() < 0.5 else pal.plastic()
    topm = pal.plastic(glossy=True) if rng.random() < 0.4 else body
    handle = pal.metal()
    parts = [("box", (0, (h - 0.03) / 2, 0), (w / 2 - 0.01, (h - 0.03) / 2, d / 2 - 0.01), body),
             ("box", (0, h - 0.015, 0), (w / 2, 0.015, d / 2), topm)]
    n = max(1, int(w / 0.45))
    for k in range(n):
        x = -w / 2 + (k + 0.5) * w / n
        parts.append(("box", (x, h * 0.75, -d / 2 + 0.005), (0.06, 0.008, 0.006), handle))
    return "cabinet", (w / 2, h / 2, d / 2), parts, rng.random() < 0.8, h, 0.0


def _sofa(rng, pal):
    w, d = float(rng.uniform(1.5, 2.4)), float(rng.uniform(0.8, 1.0))
    m, cush = pal.fabric(), pal.fabric()
    arm = 0.15
    parts = [("box", (0, 0.2, 0), (w / 2, 0.2, d / 2), m),
             ("box", (0, 0.45, d / 2 - 0.1), (w / 2, 0.45, 0.1), m),
             ("box", (-w / 2 + arm / 2, 0.32, -0.1), (arm / 2, 0.32, d / 2 - 0.1), m),
             ("box", (w / 2 - arm / 2, 0.32, -0.1), (arm / 2, 0.32, d / 2 - 0.1), m)]
    n = int(rng.integers(2, 4))
    cw = (w - 2 * arm) / n
    for k in range(n):
        x = -w / 2 + arm + (k + 0.5) * cw
        parts.append(("box", (x, 0.46, -0.08), (cw / 2 - 0.01, 0.06, d / 2 - 0.14), cush))
    return "sofa", (w / 2, 0.45, d / 2), parts, rng.random() < 0.7, None, 0.0


def _rug(rng, pal):
    w, d = float(rng.uniform(1.0, 2.5)), float(rng.uniform(0.7, 1.8))
    parts = [("box", (0, 0.005, 0), (w / 2, 0.005, d / 2), pal.fabric())]
    return "rug", (w / 2, 0.005, d / 2), parts, False, None, 0.0


def _mirror(rng, pal):
    w, h = float(rng.uniform(0.4, 1.1)), float(rng.uniform(0.6, 1.4))
    y0 = float(rng.uniform(0.9, 1.1))
    frame = pal.wood() if rng.random() < 0.5 else pal.metal(brushed=True)
    parts = [("box", (0, h / 2, 0.01), (w / 2 + 0.03, h / 2 + 0.03, 0.01), frame),
             ("box", (0, h / 2, 0.0), (w / 2, h / 2, 0.015), pal.metal(mirror=True))]
    return "mirror", (w / 2 + 0.03, h / 2 + 0.03, 0.02), parts, True, None, y0 - 0.03


def _art(rng, pal):
    w, h = float(rng.uniform(0.4, 1.2)), float(rng.uniform(0.3, 0.9))
    y0 = float(rng.uniform(1.1, 1.5))
    canvas = pal.fabric() if rng.random() < 0.5 else pal.ceramic()
    frame = pal.wood() if rng.random() < 0.5 else pal.metal()
    parts = [("box", (0, h / 2, 0.01), (w / 2, h / 2, 0.01), frame),
             ("box", (0, h / 2, 0.0), (w / 2 - 0.03, h / 2 - 0.03, 0.0125), canvas)]
    return "art", (w / 2, h / 2, 0.0125), parts, True, None, y0


def _vase(rng, pal):
    r, h = float(rng.uniform(0.05, 0.12)), float(rng.uniform(0.15, 0.45))
    m = pal.ceramic() if rng.random() < 0.6 else pal.metal()
    parts = [("cyl", (0, h / 2, 0), (r, h / 2), m)]
    if rng.random() < 0.5:
        parts.append(("sph", (0, h + r * 0.6, 0), (r * 0.8,), m))
        h = h + r * 1.4
    return "vase", (r, h / 2, r), parts


def _ball(rng, pal):
    r = float(rng.uniform(0.05, 0.14))
    m = pal.metal(mirror=rng.random() < 0.4) if rng.random() < 0.7 else pal.ceramic()
    return "ball", (r, r, r), [("sph", (0, r, 0), (r,), m)]
