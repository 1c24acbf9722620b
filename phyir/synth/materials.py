"""Materials of the synthetic rooms: palettes and procedural textures evaluated at hit points.

A material is one row of a :class:`MaterialTable`: a texture kind, two linear-RGB colours, a metric
scale, a roughness range, a metalness and a seed.  :func:`evaluate` turns (material id, metric
texture coordinates ``uv``) into base colour, roughness and metalness for any number of points at
once, so textures are exact at every ray hit (no texture maps, no resolution limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

# texture kinds
PLAIN, NOISE, WOOD, TILES, STRIPES, BRUSHED = range(6)
KIND_NAMES = ("plain", "noise", "wood", "tiles", "stripes", "brushed")


@dataclass
class Material:
    kind: int
    c1: tuple[float, float, float]
    c2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 0.5  # metres: plank/tile/stripe width or noise feature size
    rough: tuple[float, float] = (0.5, 0.5)  # roughness range (spatially varying within it)
    metal: float = 0.0
    seed: int = 0
    name: str = ""


@dataclass
class MaterialTable:
    kind: Tensor  # [K] long
    c1: Tensor  # [K,3]
    c2: Tensor  # [K,3]
    scale: Tensor  # [K]
    rough: Tensor  # [K,2]
    metal: Tensor  # [K]
    seed: Tensor  # [K] long

    @staticmethod
    def from_list(mats: list[Material], device=None) -> MaterialTable:
        def f(x):
            return torch.tensor(x, dtype=torch.float32, device=device)
        return MaterialTable(
            kind=torch.tensor([m.kind for m in mats], dtype=torch.long, device=device),
            c1=f([m.c1 for m in mats]), c2=f([m.c2 for m in mats]), scale=f([m.scale for m in mats]),
            rough=f([m.rough for m in mats]), metal=f([m.metal for m in mats]),
            seed=torch.tensor([m.seed for m in mats], dtype=torch.long, device=device))


# ---------------------------------------------------------------------------------------------
# noise


def _hash(ix: Tensor, iy: Tensor, seed: Tensor) -> Tensor:
    """Integer lattice hash -> float in [0,1) (32-bit mixing in int64, same on every device)."""
    m = 0xFFFFFFFF
    h = (ix * 374761393 + iy * 668265263 + seed * 1442695041) & m
    h = ((h ^ (h >> 13)) * 1274126177) & m
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).float() / 16777216.0


def value_noise(x: Tensor, y: Tensor, seed: Tensor) -> Tensor:
    """Smooth value noise in [0,1) with unit lattice spacing."""
    fx, fy = torch.floor(x), torch.floor(y)
    ix, iy = fx.long(), fy.long()
    tx, ty = x - fx, y - fy
    tx = tx * tx * (3 - 2 * tx)
    ty = ty * ty * (3 - 2 * ty)
    a = _hash(ix, iy, seed)
    b = _hash(ix + 1, iy, seed)
    c = _hash(ix, iy + 1, seed)
    d = _hash(ix + 1, iy + 1, seed)
    return (a * (1 - tx) + b * tx) * (1 - ty) + (c * (1 - tx) + d * tx) * ty


def fbm(x: Tensor, y: Tensor, seed: Tensor, octaves: int = 4) -> Tensor:
    """Fractal sum of value noise, normalised to [0,1)."""
    total, amp, norm = torch.zeros_like(x), 1.0, 0.0
    for k in range(octaves):
        total = total + amp * value_noise(x * 2**k, y * 2**k, seed + 17 * k)
        norm += amp
        amp *= 0.5
    return total / norm


# ---------------------------------------------------------------------------------------------
# evaluation


def evaluate(table: MaterialTable, mat: Tensor, uv: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Base colour ``[N,3]``, roughness ``[N]``, metalness ``[N]`` of ``mat [N]`` at ``uv [N,2]``."""
    N = len(mat)
    base = torch.zeros(N, 3, device=uv.device)
    rough = torch.zeros(N, device=uv.device)
    kinds = table.kind[mat]
    for k in range(len(KIND_NAMES)):
        m = torch.nonzero(kinds == k).squeeze(1)
        if m.numel() == 0:
            continue
        i = mat[m]
        b, r = _TEXTURES[k](uv[m] / table.scale[i][:, None], table.c1[i], table.c2[i], table.rough[i],
                            table.seed[i])
        base[m], rough[m] = b, r
    return base.clamp(0, 1), rough.clamp(0, 1), table.metal[mat]


def _mix(c1: Tensor, c2: Tensor, w: Tensor) -> Tensor:
    return c1 + (c2 - c1) * w[:, None]


def _rough(r: Tensor, w: Tensor) -> Tensor:
    return r[:, 0] + (r[:, 1] - r[:, 0]) * w


def _plain(uv, c1, c2, r, seed):
    w = fbm(uv[:, 0] * 3, uv[:, 1] * 3, seed, 3)
    return c1, _rough(r, w)


def _noise(uv, c1, c2, r, seed):
    w = fbm(uv[:, 0], uv[:, 1], seed)
    return _mix(c1, c2, (w - 0.2).clamp(0, 1) / 0.6), _rough(r, fbm(uv[:, 0] * 2, uv[:, 1] * 2, seed + 5, 3))


def _wood(uv, c1, c2, r, seed):
    # planks of unit width along v; grain rings stretched along u; per-plank tint and offset
    plank = torch.floor(uv[:, 1])
    pid = plank.long()
    off = _hash(pid, pid * 0 + 7, seed)
    warp = fbm(uv[:, 0] * 0.6 + off * 50, uv[:, 1] * 3, seed + 1, 3)
    rings = torch.frac((uv[:, 1] - plank) * 4 + warp * 3 + off * 10)
    grain = torch.sin(rings * 2 * np.pi) * 0.5 + 0.5
    tint = 0.85 + 0.3 * _hash(pid, pid * 0 + 3, seed)
    col = _mix(c1, c2, grain * 0.8) * tint[:, None]
    seam = torch.minimum(uv[:, 1] - plank, plank + 1 - uv[:, 1]) < 0.015
    col = torch.where(seam[:, None], col * 0.5, col)
    return col, _rough(r, torch.where(seam, 1.0, grain * 0.6))


def _tiles(uv, c1, c2, r, seed):
    cell = torch.floor(uv)
    f = uv - cell
    grout = (torch.minimum(f, 1 - f) < 0.03).any(1)
    ci = cell.long()
    var = 0.9 + 0.2 * _hash(ci[:, 0], ci[:, 1], seed)
    col = torch.where(grout[:, None], c2, c1 * var[:, None])
    rr = torch.where(grout, r[:, 1], r[:, 0] + 0.05 * value_noise(uv[:, 0] * 8, uv[:, 1] * 8, seed))
    return col, rr


def _stripes(uv, c1, c2, r, seed):
    s = torch.frac(uv[:, 0]) < 0.5
    n = 0.92 + 0.08 * fbm(uv[:, 0] * 8, uv[:, 1] * 8, seed, 3)
    return torch.where(s[:, None], c1, c2) * n[:, None], _rough(r, s.float())


def _brushed(uv, c1, c2, r, seed):
    # streaks: noise stretched 40x along u
    w = fbm(uv[:, 0] * 0.5, uv[:, 1] * 40, seed, 3)
    return _mix(c1, c2, w * 0.3), _rough(r, w)


_TEXTURES = {PLAIN: _plain, NOISE: _noise, WOOD: _wood, TILES: _tiles, STRIPES: _stripes,
             BRUSHED: _brushed}


# ---------------------------------------------------------------------------------------------
# palettes (linear RGB)

WALL_PAINTS = [(0.80, 0.78, 0.74), (0.72, 0.70, 0.65), (0.62, 0.60, 0.55), (0.70, 0.62, 0.50),
               (0.50, 0.58, 0.62), (0.55, 0.62, 0.50), (0.75, 0.55, 0.50), (0.40, 0.42, 0.45),
               (0.82, 0.80, 0.80), (0.60, 0.66, 0.72)]
WOODS = [((0.35, 0.20, 0.10), (0.20, 0.10, 0.05)), ((0.55, 0.38, 0.22), (0.40, 0.25, 0.12)),
         ((0.70, 0.55, 0.38), (0.55, 0.40, 0.25)), ((0.25, 0.15, 0.09), (0.12, 0.07, 0.04)),
         ((0.60, 0.50, 0.40), (0.45, 0.35, 0.25))]
TILE_COLOURS = [(0.75, 0.75, 0.73), (0.55, 0.55, 0.55), (0.55, 0.30, 0.18), (0.20, 0.22, 0.25),
                (0.65, 0.60, 0.50), (0.30, 0.40, 0.45)]
FABRICS = [(0.30, 0.32, 0.38), (0.50, 0.15, 0.12), (0.15, 0.25, 0.40), (0.55, 0.50, 0.42),
           (0.20, 0.35, 0.22), (0.65, 0.55, 0.30), (0.35, 0.35, 0.35), (0.60, 0.35, 0.40)]
PLASTICS = [(0.85, 0.85, 0.85), (0.05, 0.05, 0.05), (0.70, 0.10, 0.08), (0.08, 0.30, 0.60),
            (0.85, 0.65, 0.10), (0.10, 0.45, 0.25)]
METALS = {"silver": (0.97, 0.96, 0.91), "aluminium": (0.91, 0.92, 0.92), "gold": (1.0, 0.78, 0.34),
          "copper": (0.96, 0.64, 0.54), "iron": (0.56, 0.57, 0.58), "chrome": (0.55, 0.56, 0.55)}


STUDIO_SHARE = 0.08
DARK_CEILING_SHARE = 0.15


class Palette:
    """Draws materials from the palettes with a numpy Generator (deterministic per scene)."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.materials: list[Material] = []
        # rooms users shoot beyond homes: white photo studios (white walls, floor and ceiling, a
        # cyclorama's worth of bounce) and dark ceilings (bars, theatres, lofts) under bright fixtures
        u = float(rng.random())
        self.style = "studio" if u < STUDIO_SHARE else \
            "dark_ceiling" if u < STUDIO_SHARE + DARK_CEILING_SHARE else "home"

    def _white(self, r: tuple[float, float]) -> int:
        c = self._jitter((0.86, 0.86, 0.85), 0.04)
        return self.add(Material(PLAIN, c, c, 1.0, r))

    def add(self, m: Material) -> int:
        m.seed = int(self.rng.integers(0, 2**20))
        self.materials.append(m)
        return len(self.materials) - 1

    def _pick(self, seq):
        return seq[int(self.rng.integers(len(seq)))]

    def _jitter(self, c, amount: float = 0.08):
        c = np.asarray(c) * (1 + amount * self.rng.uniform(-1, 1, 3))
        return tuple(float(x) for x in np.clip(c, 0.01, 0.95))

    def wall(self) -> int:
        if self.style == "studio":
            return self._white((0.9, 0.85))
        c = self._jitter(self._pick(WALL_PAINTS))
        r = float(self.rng.uniform(0.6, 0.95))
        if self.rng.random() < 0.25:
            c2 = self._jitter(self._pick(WALL_PAINTS))
            return self.add(Material(STRIPES, c, c2, float(self.rng.uniform(0.1, 0.4)), (r, r - 0.1)))
        if self.rng.random() < 0.3:
            c2 = tuple(x * 0.85 for x in c)
            return self.add(Material(NOISE, c, c2, float(self.rng.uniform(0.2, 1.0)), (r, r - 0.15)))
        return self.add(Material(PLAIN, c, c, 1.0, (r, r - 0.05)))

    def ceiling(self) -> int:
        if self.style == "dark_ceiling":
            c = self._jitter((0.1, 0.1, 0.1), 0.6)
            return self.add(Material(PLAIN, c, c, 1.0, (0.8, 0.7)))
        c = self._jitter((0.82, 0.81, 0.79), 0.04)
        return self.add(Material(PLAIN, c, c, 1.0, (0.9, 0.85)))

    def floor(self) -> int:
        if self.style == "studio" and self.rng.random() < 0.7:
            return self._white((0.5, 0.4))
        u = self.rng.random()
        if u < 0.55:
            return self.wood(glossy=self.rng.random() < 0.6, plank=float(self.rng.uniform(0.12, 0.25)))
        if u < 0.85:
            c = self._jitter(self._pick(TILE_COLOURS))
            g = self._jitter((0.5, 0.5, 0.48), 0.1)
            r = float(self.rng.uniform(0.05, 0.45))
            return self.add(Material(TILES, c, g, float(self.rng.uniform(0.3, 0.8)), (r, 0.9)))
        c = self._jitter(self._pick(FABRICS))
        return self.add(Material(NOISE, c, tuple(x * 0.7 for x in c), 0.05, (0.95, 0.8)))  # carpet

    def wood(self, glossy: bool = False, plank: float = 0.15) -> int:
        c1, c2 = self._pick(WOODS)
        r = (0.2, 0.4) if glossy else (0.55, 0.8)
        return self.add(Material(WOOD, self._jitter(c1), self._jitter(c2), plank, r))

    def fabric(self) -> int:
        c = self._jitter(self._pick(FABRICS))
        if self.rng.random() < 0.3:
            c2 = self._jitter(self._pick(FABRICS))
            return self.add(Material(STRIPES, c, c2, float(self.rng.uniform(0.05, 0.2)), (0.9, 0.8)))
        return self.add(Material(NOISE, c, tuple(x * 0.75 for x in c), 0.08, (0.95, 0.75)))

    def plastic(self, glossy: bool | None = None) -> int:
        c = self._jitter(self._pick(PLASTICS))
        glossy = self.rng.random() < 0.5 if glossy is None else glossy
        r = (0.08, 0.25) if glossy else (0.5, 0.7)
        return self.add(Material(PLAIN, c, c, 0.3, r))

    def metal(self, mirror: bool = False, brushed: bool | None = None) -> int:
        name = "silver" if mirror else self._pick(list(METALS))
        c = METALS[name]
        if mirror:
            return self.add(Material(PLAIN, c, c, 1.0, (0.0, 0.02), metal=1.0, name="mirror"))
        brushed = self.rng.random() < 0.5 if brushed is None else brushed
        if brushed:
            return self.add(Material(BRUSHED, c, tuple(x * 0.8 for x in c), 0.3,
                                     (0.2, 0.45), metal=1.0, name=name))
        r = float(self.rng.uniform(0.03, 0.2))
        return self.add(Material(PLAIN, c, c, 0.5, (r, r + 0.05), metal=1.0, name=name))

    def ceramic(self) -> int:
        c = self._jitter(self._pick(PLASTICS + TILE_COLOURS))
        return self.add(Material(NOISE, c, tuple(x * 0.8 for x in c), 0.1, (0.05, 0.15)))

    def emitter_body(self) -> int:
        """Material of emissive surfaces: black (they only emit), never shaded."""
        return self.add(Material(PLAIN, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1.0, (1.0, 1.0)))
