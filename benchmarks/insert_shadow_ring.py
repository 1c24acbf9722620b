"""Do inserted objects' shadows read?  A diffuse sphere stood on the floor at several spots of each
room (``--spots`` azimuths, ``--distance`` m from the camera horizontally), rendered like ``phyir
insert`` (equirect, the panorama's size, three-image fusion, full quality); per spot, the floor ring
around the silhouette (floor pixels the object does not cover, within ``--ring`` x the silhouette's
radius of its edge):

* ``darkening`` = 1 - (ring luminance after) / (before): the issue's bar is >= 0.15;
* ``ring_min`` = the 2nd percentile of the per-pixel ratio after / before (a black halo is < 0.25).

    .venv/bin/python -m benchmarks.insert_shadow_ring ../shared/panos/*.hdr [--json out.json]

Panoramas go through ``phyir.predict`` (the shipped weights); scene files are used as they are.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch


def floor_spots(scene, count: int, distance: float, max_tilt_deg: float = 25.0) -> list[tuple[float, float]]:
    """Pixels (u, v) at ``count`` azimuths whose point is a floor point (normal within
    ``max_tilt_deg`` of up) nearest ``distance`` m from the camera horizontally (None where none)."""
    from phyir import pano

    H, W = scene.size
    p = pano.depth_to_points(scene.depth.float())
    n = pano.normals_from_depth(scene.depth.float())
    up = n[1] > math.cos(math.radians(max_tilt_deg))
    horiz = torch.sqrt(p[0] ** 2 + p[2] ** 2)
    spots = []
    for k in range(count):
        j = int((k + 0.5) * W / count)
        rows = torch.nonzero(up[H // 2 :, j]).squeeze(1) + H // 2
        if rows.numel() == 0:
            continue
        i = int(rows[(horiz[rows, j] - distance).abs().argmin()])
        spots.append((j + 0.5, i + 0.5))
    return spots


def dilate(mask: torch.Tensor, steps: int) -> torch.Tensor:
    """``mask [h,w]`` grown by ``steps`` pixels (3x3 steps; columns wrap round the seam)."""
    m = mask[None, None].float()
    for _ in range(steps):
        m = torch.nn.functional.max_pool2d(torch.cat([m[..., -1:], m, m[..., :1]], -1), 3, 1, (1, 0))
    return m[0, 0] > 0


def ring_band(alpha: np.ndarray, ring: float) -> tuple[torch.Tensor, float]:
    """The floor ring ``[h,w]`` (bool) around the silhouette ``alpha > 0.02``, ``ring`` x its radius
    wide, and that radius in pixels."""
    covered = torch.from_numpy(alpha > 0.02)
    radius = math.sqrt(float(covered.sum()) / math.pi)
    return dilate(covered, max(3, round(ring * radius))) & ~dilate(covered, 1), radius


def spot_renders(renderer, scene, args):
    """Per floor spot of ``scene``: (u, v, the sphere, its ``render_view`` output), rendered like
    ``phyir insert`` (equirect, the panorama's size, three-image fusion, full quality)."""
    from phyir.insert import views
    from viewer.insertion import FULL

    for u, v in floor_spots(scene, args.spots, args.distance):
        obj = views.make_object("sphere", args.radius, "diffuse")
        views.place_object(obj, scene, at=(u - 0.5, v - 0.5), log=lambda *a: None)
        view, size = views.ViewSpec().build(scene, None)
        yield u, v, obj, renderer.render_view([obj], view, size, FULL, "three-image")


def ring_stats(before: np.ndarray, after: np.ndarray, alpha: np.ndarray, ring: float) -> dict[str, float]:
    """Darkening and darkest pixels of the ring around the object's silhouette (equirect arrays)."""
    luma = np.array([0.2126, 0.7152, 0.0722], np.float32)
    band, radius = ring_band(alpha, ring)
    band = band.numpy()
    lb, la = before[band] @ luma, after[band] @ luma
    ok = lb > 1e-8
    return {"darkening": float(1 - la.sum() / lb.sum()), "ring_min": float(np.percentile(la[ok] / lb[ok], 2)),
            "radius_px": radius, "ring_px": int(band.sum())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+")
    ap.add_argument("--radius", type=float, default=0.15, help="sphere radius (m)")
    ap.add_argument("--spots", type=int, default=6)
    ap.add_argument("--distance", type=float, default=1.2)
    ap.add_argument("--ring", type=float, default=0.5)
    ap.add_argument("--json")
    args = ap.parse_args(argv)

    from phyir.insert import views
    from viewer.gl.window import gl_context
    from viewer.insertion import InsertionRenderer

    ctx = gl_context()
    renderer = InsertionRenderer(ctx)
    results = {}
    try:
        for path in args.inputs:
            scene = views.load_insert_scene(path, log=lambda *a: None)
            renderer.set_scene(scene)
            before = scene.image.permute(1, 2, 0).numpy()
            rows = []
            for u, v, _obj, out in spot_renders(renderer, scene, args):
                rows.append({"u": u, "v": v, **ring_stats(before, out["composite"], out["alpha"], args.ring)})
            name = Path(path).stem
            results[name] = rows
            d = [r["darkening"] for r in rows]
            m = [r["ring_min"] for r in rows]
            print(f"{name}: darkening median {np.median(d):.3f} (min {min(d):.3f}, "
                  f"{sum(x >= 0.15 for x in d)}/{len(d)} >= 0.15), ring 2nd percentile min {min(m):.3f}")
    finally:
        renderer.release()
        ctx.release()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
