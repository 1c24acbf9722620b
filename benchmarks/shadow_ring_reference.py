"""How dark *should* the floor ring around an inserted sphere be?  An independent reference for
``benchmarks.insert_shadow_ring``: per ring pixel, the floor point's irradiance with and without the
sphere, integrated by brute force over the light arriving at that point (``phyir.lighting.light_at``:
the panorama projected from the point through its depth, lamps where they are), the sphere's texels
replaced by what a diffuse sphere sends back there (its albedo / pi x the irradiance of the light at
its centre around the hit point's normal; ``phyir.insert.reference``).  The same light the renderer
is given, so the comparison tests the shadow and occlusion model (``composite.frag``), not the
lighting.

    .venv/bin/python -m benchmarks.shadow_ring_reference ../shared/panos/*.hdr [--json out.json]

Per spot: the renderer's darkening (as ``insert_shadow_ring``) and the reference's over the same
pixels, and their ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from benchmarks.insert_shadow_ring import ring_band, spot_renders
from phyir import pano
from phyir.insert.reference import irradiance_towards, sphere_occlusion

LUMA = torch.tensor([0.2126, 0.7152, 0.0722], dtype=torch.float64)


def ring_reference(scene, obj, ring_px: torch.Tensor, size: tuple[int, int], max_points: int,
                   gen: torch.Generator, light: str = "at-point") -> tuple[torch.Tensor, torch.Tensor]:
    """(pixel indices into the ring, reference ratio after / before [n,3]) for up to ``max_points``
    ring pixels.  ``light``: "at-point" (light_at at each point) or "panorama" (the panorama itself
    as distant light everywhere: no parallax, but every lamp exactly as sharp as the input shows it)."""
    from phyir.lighting.at_point import LightAtPoint

    H, W = scene.size
    idx = torch.nonzero(ring_px)
    if idx.shape[0] > max_points:
        idx = idx[torch.randperm(idx.shape[0], generator=gen)[:max_points]]
    d = pano.directions(H, W, dtype=torch.float64)[:, idx[:, 0], idx[:, 1]].T  # [n,3]
    depth = scene.depth[0].double()[idx[:, 0], idx[:, 1]]
    n = torch.nn.functional.normalize(scene.normal.double()[:, idx[:, 0], idx[:, 1]].T, dim=-1)
    x = d * depth[:, None] + 0.02 * n  # off the surface: the rays leave from just above it
    centre, r = obj.bounding_sphere()
    centre = torch.as_tensor(centre, dtype=torch.float64)
    h, w = size
    if light == "panorama":
        Lc = pano.resize_area(scene.image.double(), h, w)
        L = Lc[None].expand(x.shape[0], -1, -1, -1)
    else:
        field = LightAtPoint(scene, size)
        L = field.probes_at(x.float()).double()  # [n,3,h,w]
        Lc = field.probes_at(centre.float()[None]).double()[0]
    dirs = pano.directions(h, w, dtype=torch.float64)
    om = pano.solid_angles(h, w, dtype=torch.float64)
    cover, m = sphere_occlusion(x, dirs, centre, r)
    albedo = torch.tensor(obj.material.base_color, dtype=torch.float64)
    L_sphere = albedo[None, :, None, None] / np.pi * irradiance_towards(Lc, m)
    cos = (n[:, :, None, None] * dirs[None]).sum(1).clamp_min(0) * om  # [n,h,w]
    e0 = (L * cos[:, None]).sum((-1, -2))
    e1 = ((L * (1 - cover[:, None]) + L_sphere * cover[:, None]) * cos[:, None]).sum((-1, -2))
    return idx, e1 / e0.clamp_min(1e-12)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+")
    ap.add_argument("--radius", type=float, default=0.15)
    ap.add_argument("--spots", type=int, default=6)
    ap.add_argument("--distance", type=float, default=1.2)
    ap.add_argument("--ring", type=float, default=0.5)
    ap.add_argument("--points", type=int, default=96, help="ring pixels per spot for the reference")
    ap.add_argument("--probe-size", default="64x128")
    ap.add_argument("--light", choices=("at-point", "panorama"), default="at-point")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    size = tuple(int(s) for s in args.probe_size.split("x"))

    from phyir.insert import views
    from viewer.gl.window import gl_context
    from viewer.insertion import InsertionRenderer

    ctx = gl_context()
    renderer = InsertionRenderer(ctx)
    results = {}
    gen = torch.Generator().manual_seed(0)
    try:
        for path in args.inputs:
            scene = views.load_insert_scene(path, log=lambda *a: None)
            renderer.set_scene(scene)
            before = scene.image.permute(1, 2, 0).double()
            rows = []
            for u, v, obj, out in spot_renders(renderer, scene, args):
                band, _radius = ring_band(out["alpha"], args.ring)
                idx, ratio = ring_reference(scene, obj, band, size, args.points, gen, args.light)
                b = before[idx[:, 0], idx[:, 1]]
                a = torch.from_numpy(out["composite"]).double()[idx[:, 0], idx[:, 1]]
                lb = b @ LUMA
                ours = float(1 - (a @ LUMA).sum() / lb.sum())
                ref = float(1 - ((b * ratio) @ LUMA).sum() / lb.sum())
                rows.append({"u": u, "v": v, "ours": ours, "reference": ref})
            name = Path(path).stem
            results[name] = rows
            o = np.array([r["ours"] for r in rows])
            f = np.array([r["reference"] for r in rows])
            print(f"{name}: ring darkening ours median {np.median(o):.3f}, reference {np.median(f):.3f} "
                  f"(ours / reference {np.median(o / np.maximum(f, 1e-6)):.2f}; reference >= 0.15 at "
                  f"{int((f >= 0.15).sum())}/{len(f)} spots)", flush=True)
    finally:
        renderer.release()
        ctx.release()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
