"""Gallery of insertions: Table 2's diffuse, matte-silver and mirror-silver spheres and one mesh (a
20k-triangle vase, glossy red) standing on the floor of each scene, plus ``phyir insert`` run once
per scene.  Writes docs/img/insert_gallery.png and benchmarks/results/insert_gallery.json.

    .venv/bin/python benchmarks/insert_gallery.py SCENE.exr [SCENE.exr ...]

Scenes need depth and probes (scene files); plain panoramas go through phyir.predict first, which
needs model weights.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def vase(path: str) -> None:
    """A lathe-turned vase, 20k triangles, 0.5 m tall, base at y = 0."""
    import numpy as np
    import trimesh

    t = np.linspace(0, 1, 40)
    r = 0.09 + 0.07 * np.sin(np.pi * t * 1.3) ** 2 - 0.035 * t
    profile = np.stack([np.r_[0.0, r, 0.0], np.r_[0.0, 0.5 * t, 0.5]], 1)
    mesh = trimesh.creation.revolve(profile, sections=256)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    mesh.export(path)


def floor_spots(scene, n: int, distance=(1.2, 2.4), spacing: float = 0.6):
    """``n`` free floor pixels (u, v) about ``spacing`` metres apart, in front of the camera."""
    import torch

    from phyir import pano

    H, W = scene.size
    p = scene.depth * pano.directions(H, W)
    floor_y = float(p[1][scene.normal[1] > 0.99].median())
    is_floor = (scene.normal[1] > 0.99) & ((p[1] - floor_y).abs() < 0.02)
    horiz = torch.sqrt(p[0] ** 2 + p[2] ** 2)
    cand = torch.nonzero(is_floor & (horiz > distance[0]) & (horiz < distance[1])).tolist()
    cand.sort(key=lambda ij: abs(ij[1] + 0.5 - W / 2))
    spots, pts = [], []
    for i, j in cand:
        c = p[:, i, j]
        near = torch.linalg.vector_norm(p - c[:, None, None], dim=0) < 0.35
        if bool((near & ~is_floor & (p[1] > floor_y - 0.5)).any()):
            continue
        if all(float(torch.linalg.vector_norm(c - q)) > spacing for q in pts):
            spots.append((j + 0.5, i + 0.5))
            pts.append(c)
        if len(spots) == n:
            break
    return spots


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--image", default=str(REPO / "docs" / "img" / "insert_gallery.png"))
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    args = ap.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import moderngl
    import numpy as np
    from PIL import Image

    from phyir import placement
    from phyir.cli import main as cli
    from viewer.export import load_input, tonemap
    from viewer.insertion import FULL, InsertionRenderer
    from viewer.objects import PRESETS, SceneObject, load_mesh, parse_material, primitive
    from viewer.view import EquirectView

    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    ins = InsertionRenderer(ctx)
    rows, results = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        vase_path = os.path.join(tmp, "vase.obj")
        vase(vase_path)
        mesh = load_mesh(vase_path)
        for path in args.scenes:
            name = Path(path).stem
            scene = load_input(path)
            H, W = scene.size
            ins.set_scene(scene)
            spots = floor_spots(scene, 4)
            objs = [SceneObject(primitive("sphere"), PRESETS[m], scale=0.15)
                    for m in ("diffuse", "matte-silver", "mirror-silver")]
            objs.append(SceneObject(mesh, parse_material("0.7,0.08,0.06,0.3,0"), scale=1.0))
            for obj, (u, v) in zip(objs, spots):
                pl = placement.drop(scene, u, v, obj.base_offset())
                obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
            objs = objs[:len(spots)]
            t = time.perf_counter()
            out = ins.render_view(objs, EquirectView(center=(W / 2, H / 2), zoom=1.0), (W, H), FULL)
            dt = time.perf_counter() - t
            lum = scene.image.permute(1, 2, 0).numpy() @ np.array([0.2126, 0.7152, 0.0722], np.float32)
            exposure = float(np.log2(0.18 / max(float(np.median(lum[lum > 0])), 1e-12)))
            us = [s[0] for s in spots]
            vs = [s[1] for s in spots]
            cw, ch = W // 3, H // 3
            x0 = int(min(max(np.mean(us) - cw / 2, 0), W - cw))
            y0 = int(min(max(np.mean(vs) - ch * 0.6, 0), H - ch))
            box = (slice(y0, y0 + ch), slice(x0, x0 + cw))
            before = tonemap(scene.image.permute(1, 2, 0).numpy()[box], exposure)
            after = tonemap(out["composite"][box], exposure)
            rows.append(np.concatenate([before, after], 1))
            results[name] = {"size": f"{W}x{H}", "objects": len(objs), "render_s": round(dt, 3),
                             "spots": [[round(a, 1), round(b, 1)] for a, b in spots]}
    ins.release()
    ctx.release()
    # the command line, once per scene (a matte-silver sphere; it makes its own GL context)
    os.makedirs(args.out, exist_ok=True)
    for path in args.scenes:
        name = Path(path).stem
        u, v = results[name]["spots"][0]
        t = time.perf_counter()
        rc = cli(["insert", path, "--object", "sphere", "--scale", "0.2", "--material", "matte-silver",
                  "--at", f"{u - 0.5:.0f},{v - 0.5:.0f}", "-o", os.path.join(args.out, f"insert_{name}.exr")])
        results[name].update(cli_rc=rc, cli_s=round(time.perf_counter() - t, 2))
        print(name, results[name], flush=True)
    width = max(r.shape[1] for r in rows)
    grid = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], 0)
    os.makedirs(os.path.dirname(args.image), exist_ok=True)
    scale = max(1, 1200 // grid.shape[1])
    big = Image.fromarray(grid).resize((grid.shape[1] * scale, grid.shape[0] * scale), Image.LANCZOS)
    big.save(args.image)
    with open(os.path.join(args.out, "insert_gallery.json"), "w") as f:
        json.dump(results, f, indent=2)
    print("wrote", args.image)
    return 0


if __name__ == "__main__":
    sys.exit(main())
