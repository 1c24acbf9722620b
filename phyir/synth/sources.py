"""Light levels of the synthetic rooms: the panels and lamps scaled against the walls they light
(a drawn dynamic range, docs/synthetic-data.md), light colours from warm to cool."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from phyir.synth import geometry as G
from phyir.synth.lights import SUN_RADIUS

if TYPE_CHECKING:
    from phyir.synth.room import PrimSpec, Room

# Dynamic range: the brightest panel/lamp is drawn SOURCE_RATIO (log-uniform, decades) times the
# radiance of the walls it and the other sources light, estimated in closed form (wall_radiance)
SOURCE_RATIO = (2.6, 3.5)


WALL_GAIN = 0.8  # calibration of wall_radiance against rendered medians (docs/synthetic-data.md)
TYPICAL_RHO = 0.6  # the shell albedo WALL_GAIN was calibrated at (the median of the home palette)


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
    flux / (shell area x (1 - mean albedo)) with interreflections, times albedo / pi: the shell's
    area-weighted albedo where its materials are known (a white studio's walls are ~3x brighter
    for the same flux than a room's of albedo 0.5), else 0.5."""
    perimeter = sum(math.dist(room.polygon[i], room.polygon[i - 1]) for i in range(len(room.polygon)))
    floor, walls = polygon_area(room.polygon), perimeter * room.height
    shell = 2 * floor + walls
    rho = 0.5
    if len(room.materials) >= 3:  # the shell's: floor, ceiling, walls (rooms.shell draws them first)
        a = [float(np.mean(m.c1) + np.mean(m.c2 if any(m.c2) else m.c1)) / 2 for m in room.materials[:3]]
        rho = min((floor * (a[0] + a[1]) + walls * a[2]) / shell, 0.9)
    return WALL_GAIN * (rho / (1 - rho)) / (TYPICAL_RHO / (1 - TYPICAL_RHO)) * flux / (math.pi * shell)


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
        k = max(0.15, math.sqrt(reach / 10 ** SOURCE_RATIO[0]))
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


def polygon_area(poly) -> float:
    a = 0.0
    for i in range(len(poly)):
        x1, z1 = poly[i]
        x2, z2 = poly[(i + 1) % len(poly)]
        a += x1 * z2 - x2 * z1
    return abs(a) / 2


def light_colour(rng) -> np.ndarray:
    """Linear RGB tint of a light from warm (2700 K) to cool (6500 K), unit mean."""
    t = rng.random()
    warm, cool = np.array((1.0, 0.72, 0.45)), np.array((0.92, 0.98, 1.1))
    c = warm + (cool - warm) * t
    return c / c.mean()
