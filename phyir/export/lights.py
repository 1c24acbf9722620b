"""The room's dominant light sources as glTF punctual lights (KHR_lights_punctual), and the emissive
texture that goes with them.

The split is :func:`phyir.lighting.projection.bright_sources`' — the same one the projection lighting
of ``phyir insert`` splats: a pixel brighter than ``factor`` x the panorama's mean (channel mean, over
solid angle) keeps that level (colour preserved) in the *base* image; the excess, times the surface
area the pixel covers, is gathered into sources at their power-weighted 3D centroid (the depth places
them) with their mean surface normal.  So ``base + lights`` holds the panorama's energy once:

* the glTF's emissive texture is the base image (8-bit, scaled by KHR_materials_emissive_strength),
  to be used **with** the lights;
* the equirect EXR beside the file is the whole panorama, to be used **without** them.

Units.  The panorama's linear values are taken as radiance in W sr^-1 m^-2 per channel (the scale
Blender's emission strength 1 and the world's strength 1 use); a source's ``power`` is its
radiant intensity toward its normal, I = sum of radiance x area, in W/sr.  glTF wants candela
(lm/sr) for point and spot lights: intensity = 683 lm/W x max(I_rgb), colour = I_rgb / max(I_rgb)
(so colour x intensity / 683 = I_rgb exactly; Blender's importer turns candela back into its watts
with the same 683 lm/W, W = 4π cd / 683 for point and spot lights).

A source is a Lambertian patch: it emits I cos(α) into the half-space its surface faces.  It is
exported as a spot light aimed along its normal with the widest cone glTF allows (outer cone 90°,
inner 0°), so it lights that half-space only; renderers' spot falloffs approximate cos(α).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano
from phyir.lighting.projection import bright_sources
from phyir.scene import PanoScene

LUMENS_PER_WATT = 683.0
BRIGHT_FACTOR = 8.0  # DepthSurface.from_scene's default: phyir insert splats the same sources
MAX_LIGHTS = 16
MERGE_RADIUS = 0.5  # metres: bright cells closer than this (facing alike) are one lamp
SOURCE_CELLS = 64  # bright_sources gathers into at most this many cells before merging
SPOT_OUTER = math.pi / 2  # glTF's largest outer cone angle: the whole half-space


@dataclass
class PunctualLight:
    """One light, world frame: ``direction`` is where a spot points (its node's -z)."""

    position: np.ndarray  # [3] metres
    direction: np.ndarray  # [3] unit
    color: tuple[float, float, float]  # linear RGB, max channel 1
    intensity: float  # candela (lm/sr) toward ``direction``

    @property
    def radiant_intensity(self) -> np.ndarray:
        """W/sr per channel toward ``direction`` (scene radiance units x m²)."""
        return np.asarray(self.color) * self.intensity / LUMENS_PER_WATT


def scene_lights(scene: PanoScene, max_lights: int = MAX_LIGHTS, factor: float = BRIGHT_FACTOR,
                 merge_radius: float = MERGE_RADIUS) -> tuple[list[PunctualLight], torch.Tensor]:
    """``(lights, base)``: the scene's bright sources (strongest first) and the image ``[3,H,W]``
    without them (see the module doc).  No lights (and the image itself) when nothing is that bright
    or ``max_lights`` is 0.  bright_sources' cells of one lamp are merged (:func:`merge_sources`)."""
    image = torch.nan_to_num(scene.image.float(), nan=0.0, posinf=0.0).clamp_min(0)
    if max_lights <= 0:
        return [], image
    depth = scene.depth.float()
    normal = pano.normals_from_depth(depth) if scene.normal is None else scene.normal.float()
    base, src = bright_sources(image, depth, normal, factor, SOURCE_CELLS)
    if src is None:
        return [], image
    pos, nrm, power = merge_sources(src.pos.double().numpy().T, src.normal.double().numpy().T,
                                    src.power.double().numpy().T, merge_radius, max_lights)
    lights = []
    for p, n, rgb in zip(pos, nrm, power):
        peak = float(rgb.max())
        if peak > 0:
            lights.append(PunctualLight(position=p, direction=n, color=tuple(float(x) for x in rgb / peak),
                                        intensity=peak * LUMENS_PER_WATT))
    return lights, base


def merge_sources(pos: np.ndarray, normal: np.ndarray, power: np.ndarray, radius: float, max_count: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sources ``[S,3]`` (positions, unit normals, W/sr per channel) merged, strongest first: a source
    within ``radius`` of a stronger one facing the same way (normals within ~25°) joins it, and
    beyond ``max_count`` every source joins the nearest kept one; merged positions and normals are
    power-weighted, powers add (the energy is kept)."""
    order = np.argsort(-power.sum(1))
    groups: list[list[int]] = []
    for k in order:
        for g in groups:
            if np.linalg.norm(pos[k] - pos[g[0]]) < radius and normal[k] @ normal[g[0]] > 0.9:
                g.append(k)
                break
        else:
            groups.append([k])
    for g in groups[max_count:]:
        near = min(range(max_count), key=lambda i: np.linalg.norm(pos[g[0]] - pos[groups[i][0]]))
        groups[near] += g
    groups = groups[:max_count]
    w = [power[g].sum(1) for g in groups]
    out_pos = np.array([(wi[:, None] * pos[g]).sum(0) / wi.sum() for g, wi in zip(groups, w)])
    out_n = np.array([(wi[:, None] * normal[g]).sum(0) for g, wi in zip(groups, w)])
    out_n /= np.linalg.norm(out_n, axis=1, keepdims=True).clip(1e-12)
    out_p = np.array([power[g].sum(0) for g in groups])
    keep = np.argsort(-out_p.sum(1))
    return out_pos[keep], out_n[keep], out_p[keep]


def spot_rotation(direction: np.ndarray) -> tuple[float, float, float, float]:
    """glTF node rotation (x, y, z, w) turning the node's -z onto unit ``direction``."""
    a = np.array([0.0, 0.0, -1.0])
    b = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    axis = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-9:  # opposite: half a turn about y
        return (0.0, 1.0, 0.0, 0.0)
    q = np.array([*axis, 1.0 + c])
    q /= np.linalg.norm(q)
    return tuple(float(x) for x in q)  # type: ignore[return-value]
