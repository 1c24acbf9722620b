"""GPU insertion against the path tracer: a sphere added to a synthetic room (phyir.insert.reference).

    .venv/bin/python -m benchmarks.insert_vs_pathtrace [--seed 2022 --index 0] [--size 128x256]
        [--spp 64 --ref-spp 256] [--out benchmarks/results] [--image docs/img/insert_vs_pathtrace.png]

The insertion gets the room's ground-truth layers and probes (traced without the sphere) and renders
the sphere at FULL quality with both fusion methods; the reference traces the room with the sphere.
The tracer shades one ray through each pixel centre, so mirror reflections are point-sampled there:
the insertion's reflections are point-sampled too for this comparison (``footprint_scale = 0``).
Errors (relative L1):
* object: the composite against the reference on the pixels where the sphere is visible
  (``object_interior``: without the silhouette's pixels, which mix sphere and background);
* shadow: the change the sphere makes to the rest of the picture, composite - background against
  the reference's (with - without sphere, same sampler seed), over the scene points within four
  sphere radii of the sphere; ``shadow_bias`` is sum(ours) / sum(reference) of that change (1 = the
  right total darkening);
* ``noise_floor``: the same shadow measure for no change at all (two renders of the empty room at
  different sample counts): the part of the shadow error that is the reference's Monte Carlo noise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MATERIALS = ("diffuse", "matte-silver", "mirror-silver")


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=2022)
    ap.add_argument("--index", type=int, default=0)
    ap.add_argument("--size", default="128x256")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--ref-spp", type=int, default=128)
    ap.add_argument("--radius", type=float, default=0.25)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    ap.add_argument("--image", default=str(REPO / "docs" / "img" / "insert_vs_pathtrace.png"))
    ap.add_argument("--cache", default=None, help="reuse (or write) the traced reference here (torch.save)")
    return ap.parse_args()


def _reference(args: argparse.Namespace, H: int, W: int):
    """The traced room with and without the sphere (from ``--cache`` when it exists)."""
    import torch

    from phyir.evaluation.metrics import RELIGHT_MATERIALS
    from phyir.insert.reference import trace_reference

    mats = {m: RELIGHT_MATERIALS[m.replace("-", "_")] for m in MATERIALS}
    if args.cache and os.path.exists(args.cache):
        return torch.load(args.cache, weights_only=False)
    ref = trace_reference(args.seed, args.index, args.radius, mats, size=(H, W), spp=args.spp,
                          ref_spp=args.ref_spp, probe_grid=(H // 8, W // 8))
    if args.cache:
        torch.save(ref, args.cache)
    return ref


def _regions(ref):
    """Pixels of the sphere, of its interior (no silhouette pixels) and of the scene points within
    four sphere radii of it (the shadow region), each ``[H, W]`` bool."""
    import torch

    from phyir import pano
    from phyir.insert.reference import sphere_mask

    scene = ref.scene
    H, W = scene.size
    mask = sphere_mask(ref.centre, ref.radius, scene.depth)
    p = scene.depth * pano.directions(H, W)
    c = torch.as_tensor(ref.centre, dtype=torch.float32)[:, None, None]
    near = (torch.linalg.vector_norm(p - c, dim=0) < 4 * ref.radius) & ~mask
    interior = mask & mask.roll(1, 0) & mask.roll(-1, 0) & mask.roll(1, 1) & mask.roll(-1, 1)
    return mask, interior, near


def _compare(ins, ref, mask, interior, near) -> tuple[dict, list]:
    """Errors of both fusion methods per material (module doc), and the images of each material's row
    (path traced, three-image, differential)."""
    import numpy as np
    import torch

    from phyir.color import luminance
    from phyir.insert.objects import PRESETS, SceneObject, primitive
    from phyir.insert.views import EquirectView
    from viewer.insertion import FULL

    H, W = ref.scene.size
    bg = ref.scene.image
    view = EquirectView(center=(W / 2, H / 2), zoom=1.0)
    results, crops = {}, []
    for name in MATERIALS:
        obj = SceneObject(primitive("sphere"), PRESETS[name], position=ref.centre, scale=ref.radius)
        obj.support = (ref.centre - np.array([0, ref.radius, 0]), np.array([0.0, 1.0, 0.0]))
        d_ref = luminance(ref.with_sphere[name] - ref.without)
        row = [ref.with_sphere[name]]
        for fusion in ("three-image", "differential"):
            t = time.perf_counter()
            out = ins.render_view([obj], view, (W, H), FULL, fusion)
            dt = time.perf_counter() - t
            comp = torch.from_numpy(out["composite"]).permute(2, 0, 1)
            row.append(comp)
            truth = ref.with_sphere[name]
            m3, i3 = mask.expand(3, H, W), interior.expand(3, H, W)
            obj_err = float((comp - truth).abs()[m3].sum() / truth.abs()[m3].sum())
            obj_int = float((comp - truth).abs()[i3].sum() / truth.abs()[i3].sum())
            d_ours = luminance(comp - bg)
            sh_err = float((d_ours - d_ref).abs()[near].sum() / d_ref.abs()[near].sum())
            bias = float(d_ours[near].sum() / d_ref[near].sum())
            results[f"{name}/{fusion}"] = {"object_rel_l1": round(obj_err, 4),
                                           "object_interior_rel_l1": round(obj_int, 4),
                                           "shadow_rel_l1": round(sh_err, 4),
                                           "shadow_bias": round(bias, 3), "render_s": round(dt, 3)}
            print(f"{name:14s} {fusion:12s} object {obj_err:.3f} (interior {obj_int:.3f})  "
                  f"shadow {sh_err:.3f}  bias {bias:.2f}  ({dt:.2f} s)", flush=True)
        crops.append(row)
    return results, crops


def _save_image(ref, crops: list, path: str) -> None:
    """Side by side: rows = materials; columns = path traced, three-image, differential (crops)."""
    import numpy as np
    import torch
    from PIL import Image

    from phyir import pano
    from phyir.color import luminance
    from phyir.insert.views import tonemap

    H, W = ref.scene.size
    u, v, _ = pano.points_to_uv(torch.as_tensor(ref.centre), H, W)
    cw, ch = W // 4, H // 3
    x0 = int(min(max(float(u) - cw / 2, 0), W - cw))
    y0 = int(min(max(float(v) - ch / 2, 0), H - ch))
    lum = luminance(ref.scene.image).flatten()
    exposure = float(np.log2(0.18 / max(float(lum[lum > 0].median()), 1e-12)))
    tiles = [[tonemap(img[:, y0:y0 + ch, x0:x0 + cw].permute(1, 2, 0).numpy(), exposure) for img in row]
             for row in crops]
    grid = np.concatenate([np.concatenate(r, 1) for r in tiles], 0)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    Image.fromarray(grid).resize((grid.shape[1] * 3, grid.shape[0] * 3), Image.NEAREST).save(path)
    print(f"wrote {path}", flush=True)


def main() -> int:
    args = _args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import moderngl
    import numpy as np

    from phyir.color import luminance
    from viewer.insertion import InsertionRenderer

    H, W = (int(x) for x in args.size.split("x"))
    t0 = time.perf_counter()
    ref = _reference(args, H, W)
    print(f"traced in {ref.seconds:.0f} s; sphere centre {np.round(ref.centre, 3)}", flush=True)
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    ins = InsertionRenderer(ctx)
    ins.set_scene(ref.scene)
    ins.footprint_scale = 0.0  # point-sampled reflections, as the tracer's pixel-centre rays
    mask, interior, near = _regions(ref)
    results, crops = _compare(ins, ref, mask, interior, near)
    # noise floor of the shadow measure: the two empty-room renders differ only by noise/settings
    d_noise = luminance(ref.without - ref.scene.image)
    d_diffuse = luminance(ref.with_sphere["diffuse"] - ref.without)
    results["noise_floor"] = round(float(d_noise[near].abs().sum() / d_diffuse.abs()[near].sum()), 4)
    results.update(size=f"{W}x{H}", spp=args.spp, ref_spp=args.ref_spp, radius=args.radius,
                   seed=args.seed, index=args.index, centre=[round(float(c), 3) for c in ref.centre],
                   trace_s=round(ref.seconds, 1), total_s=round(time.perf_counter() - t0, 1))
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "insert_vs_pathtrace.json"), "w") as f:
        json.dump(results, f, indent=2)
    _save_image(ref, crops, args.image)
    return 0


if __name__ == "__main__":
    sys.exit(main())
