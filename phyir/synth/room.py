"""A procedural room as data: its primitives (:class:`PrimSpec`), the room with its footprint,
materials, sky and camera (:class:`Room`), and its tensors for the tracer (:class:`TraceScene`,
:meth:`Room.build`). :mod:`phyir.synth.rooms` generates rooms; :mod:`phyir.synth.sources` balances
their lights.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from phyir.pano import yaw_matrix
from phyir.synth import geometry as G
from phyir.synth.footprints import dist_to_polygon_edges, in_polygon
from phyir.synth.lights import Lights, Sky
from phyir.synth.materials import MaterialTable


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
    hall: bool = False
    style: str = "home"  # the palette's: home, studio (white), dark_ceiling
    reserved: list = field(default_factory=list)  # OBBs (centre, half, yaw) kept free

    # -- geometry helpers ---------------------------------------------------------------------
    def contains(self, x: float, z: float, margin: float = 0.0) -> bool:
        if not in_polygon(self.polygon, x, z):
            return False
        return dist_to_polygon_edges(self.polygon, x, z) >= margin

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
        prims.derive()
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
        return {"kind": self.kind, "hall": self.hall, "style": self.style, "width": max(xs) - min(xs),
                "depth": max(zs) - min(zs), "height": self.height,
                "items": [it.name for it in self.items if not it.fixture]}


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
