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

import numpy as np
import torch

from phyir.pano import yaw_matrix
from phyir.synth import geometry as G
from phyir.synth.footprints import (
    Item,
    in_polygon,
    obb_corners,
    obb_overlap,
    point_in_obb,
)
from phyir.synth.furniture import art, ball, bed, cabinet, mirror, rug, shelf, sofa, table, vase
from phyir.synth.lights import Sky
from phyir.synth.materials import Palette
from phyir.synth.room import PrimSpec, Room
from phyir.synth.sources import balance_sources, light_colour, polygon_area

ROOM_WIDTH = (2.5, 9.0)
ROOM_HEIGHT = (2.4, 3.5)
# halls (lobbies, studios, warehouses, churches): users' large rooms, where a model trained on
# bedrooms alone bends the far walls into a bowl
HALL_SHARE = 0.15
HALL_WIDTH = (9.0, 30.0)
HALL_HEIGHT = (3.5, 8.0)
CAMERA_HEIGHT = (1.0, 2.0)  # tripods and hand-held: seated to over-the-head
CAMERA_CLEARANCE = 0.35  # metres from walls and furniture
SOURCES = (1, 6)
HALL_SOURCES = (3, 9)


# ---------------------------------------------------------------------------------------------
# 2D helpers


# ---------------------------------------------------------------------------------------------
# generation


def generate_room(rng: np.random.Generator) -> Room:
    """Draw one furnished, lit room with a camera."""
    for _ in range(20):
        room = _try_room(rng)
        if room is not None:
            return room
    raise RuntimeError("generate_room: could not place a camera in 20 attempts")


def room_extent(rng: np.random.Generator) -> tuple[float, float, float, bool]:
    """Width, depth, height of the footprint's bounding box, and whether the room is a hall."""
    hall = rng.random() < HALL_SHARE
    sides, heights = (HALL_WIDTH, HALL_HEIGHT) if hall else (ROOM_WIDTH, ROOM_HEIGHT)
    W = float(rng.uniform(*sides))
    D = float(rng.uniform(max(sides[0], 0.5 * W), min(sides[1], 1.6 * W)))
    return W, D, float(rng.uniform(*heights)), hall


def _try_room(rng: np.random.Generator) -> Room | None:
    W, D, H, hall = room_extent(rng)
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
    room = Room(polygon=[(float(x), float(z)) for x, z in poly], height=H, kind=kind, hall=hall)
    pal = Palette(rng)
    room.materials = pal.materials  # filled as the room is built (balance_sources reads the shell's)
    b = _Builder(room, pal, rng, HALL_SOURCES if hall else SOURCES)
    b.shell(rects, reentrant)
    b.furnish()
    b.lights()
    if not b.place_camera():
        return None
    room.materials = pal.materials
    room.style = pal.style
    return room


class _Builder:
    def __init__(self, room: Room, pal: Palette, rng: np.random.Generator, sources: tuple[int, int]):
        self.room, self.pal, self.rng, self.sources = room, pal, rng, sources
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
            if not in_polygon(poly, *mid):
                n_in = -n_in
            self.walls.append((a, e, n_in, L, u))
            u += L
        # lighting plan: windows, panels, lamps
        n_src = int(rng.integers(self.sources[0], self.sources[1] + 1))
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
        area = polygon_area(self.room.polygon)
        n_items = int(np.clip(rng.poisson(2 + area / 6), 2, 12))
        makers = [bed, table, shelf, cabinet, sofa, rug, cabinet, table, mirror, art]
        weights = np.array([0.8, 1.2, 1.0, 1.2, 1.0, 0.6, 0.6, 0.4, 0.5, 0.6])
        for _ in range(n_items):
            mk = makers[int(rng.choice(len(makers), p=weights / weights.sum()))]
            name, half, parts, wall, top, y0 = mk(rng, pal)
            self._place(name, half, parts, wall, top, y0)
        for _ in range(int(rng.integers(1, 5))):
            mk = [vase, ball, vase][int(rng.integers(3))]
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
            return light_colour(rng)
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


# ---------------------------------------------------------------------------------------------
# furniture makers: (name, OBB half sizes, parts, against wall, top height, base y)
