"""The light arriving at any 3D point of the room, from the light the panorama saw.

The panorama *is* the incident light at the camera, in HDR where the input is; an object elsewhere
sees the same surfaces from another place. :class:`LightAtPoint` traces each probe texel's rays from
the point through the scene's depth surface (:meth:`phyir.lighting.projection.DepthSurface.trace`)
and reads the panorama's radiance where they meet a surface the camera saw — footprint-filtered,
parallax-correct, lamps and windows splatted with their full energy from where they are
(:func:`phyir.lighting.projection.bright_sources`). Only the share the camera did not see (behind
furniture, rays through depth discontinuities) comes from the learned probes (LNet's grid,
interpolated by :class:`phyir.lighting.object_lighting.ProbeField`), blended by the texel's visible
share so there are no seams. At the camera itself the result is the panorama.

One instance per scene; probes are cached by position (millimetres), so an object dragged back and
forth, or several objects at one place, cost one projection.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import Tensor

from phyir import pano
from phyir.lighting.object_lighting import ProbeField
from phyir.lighting.projection import DepthSurface, project_probes
from phyir.scene import PanoScene, SceneError

CACHE_SIZE = 256
DRAFT_STEP = 0.05  # metres: the grid a dragged object's light is read on (the viewer's drag quality)


class LightAtPoint:
    """Probes ``[3,h,w]`` at any point: projection of the panorama, learned probes where unseen."""

    interpolates = False  # the probe is computed at the point: no distance correction of blended probes

    def __init__(self, scene: PanoScene, probe_size: tuple[int, int] | None = None,
                 surface: DepthSurface | None = None, supersample: int = 2, steps: int = 32):
        if scene.batched:
            raise SceneError("LightAtPoint: expected an unbatched scene")
        if scene.depth is None:
            raise SceneError("LightAtPoint: the scene needs depth")
        self.field = ProbeField(scene) if scene.probes is not None else None
        self.probe_size = probe_size or (tuple(scene.probe_size) if scene.probes is not None else (16, 32))
        self.surface = surface if surface is not None else DepthSurface.from_scene(scene)
        self.supersample, self.steps = supersample, steps
        self._cache: OrderedDict[tuple, Tensor] = OrderedDict()

    def fallback(self, points: Tensor) -> Tensor:
        """``[N,3,h,w]`` learned probes at ``points [N,3]`` (zeros without probes)."""
        h, w = self.probe_size
        if self.field is None:
            return torch.zeros(points.shape[0], 3, h, w)
        out = []
        for p in points:
            fb = self.field.probe_at(p)
            out.append(fb if tuple(fb.shape[-2:]) == (h, w) else pano.resize_area(fb, h, w))
        return torch.stack(out)

    def probes_at(self, points: Tensor, draft: bool = False, grid: float = 0.0) -> Tensor:
        """``[N,3,h,w]`` probes at ``points [N,3]`` (float32, CPU).  ``draft``: one ray per texel;
        ``grid`` > 0: at the nearest node of a grid of that step in metres (an object being dragged:
        most frames find their probe cached, e.g. :data:`DRAFT_STEP`)."""
        pts = torch.as_tensor(points, dtype=torch.float32).reshape(-1, 3)
        if grid > 0:
            pts = torch.round(pts / grid) * grid
        keys = [(draft, *(int(round(float(c) * 1000)) for c in p)) for p in pts]
        todo = [i for i, k in enumerate(keys) if k not in self._cache]
        if todo:
            sel = pts[todo]
            probes, _ = project_probes(self.surface, sel, self.probe_size, self.fallback(sel),
                                       supersample=1 if draft else self.supersample, steps=self.steps)
            for i, p in zip(todo, probes.clamp_min(0).cpu()):
                self._cache[keys[i]] = p
                while len(self._cache) > CACHE_SIZE:
                    self._cache.popitem(last=False)
        for k in keys:
            self._cache.move_to_end(k)
        return torch.stack([self._cache[k] for k in keys])

    def probe_at(self, point: Tensor, draft: bool = False, grid: float = 0.0) -> Tensor:
        """The probe ``[3,h,w]`` at one point ``[3]`` (the :class:`ProbeField` interface)."""
        return self.probes_at(torch.as_tensor(point).reshape(1, 3), draft, grid)[0]


def light_at(scene: PanoScene, points: Tensor, size: tuple[int, int] | None = None) -> Tensor:
    """Probes ``[N,3,h,w]`` at 3D ``points [N,3]`` of ``scene`` (see :class:`LightAtPoint`)."""
    return LightAtPoint(scene, size).probes_at(points)
