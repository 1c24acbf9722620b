"""Gallery of insertions: Table 2's diffuse, matte-silver and mirror-silver spheres and one mesh (a
20k-triangle vase, glossy red) standing on free floor found in each scene
(``phyir.insert.spots.floor_spots``, robust to predicted geometry), plus ``phyir insert`` run twice per
scene (a sphere, equirect; the vase, perspective) into ``--cli-out`` (default: a temporary folder).
Before/after panels: a crop of the panorama (``--view equirect``) or a camera looking at the objects
(``--view perspective``).

    .venv/bin/python -m benchmarks.insert_gallery /tmp/synth/scene_00000*.exr  # docs/img/insert_gallery.png
    .venv/bin/python -m benchmarks.insert_gallery /work/pred/*.exr --view perspective \
        --image docs/img/insert_gallery_real.png --json benchmarks/results/insert_gallery_real.json

Scenes need depth and probes (scene files); plain panoramas go through phyir.predict first, which
needs model weights.
"""

from __future__ import annotations

import argparse
import json
import math
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


def perspective_on(points, size: tuple[int, int], fov: float = 60.0):
    """A camera at the panorama centre looking at the group of world ``points`` (object centres,
    ``size`` = (width, height)), its field of view widened until all of them are well inside."""
    import numpy as np
    import torch

    from phyir import pano
    from phyir.insert.views import PerspectiveView

    pts = np.asarray(points, np.float64)
    lon, lat = pano.dir_to_lonlat(torch.as_tensor(pts.mean(0)))
    # look down at most 45 degrees (a steeper view of objects next to the camera shows their tops)
    view = PerspectiveView(fov=fov, yaw=float(lon), pitch=max(float(lat), -math.pi / 4))
    while view.fov < 110:
        d = pts @ view.rotation()  # camera frame: x right, y up, looking along -z
        x = view.focal(size) * d[:, 0] / -d[:, 2]
        y = view.focal(size) * d[:, 1] / -d[:, 2]
        if (d[:, 2] < 0).all() and (abs(x) < 0.35 * size[0]).all() and (abs(y) < 0.3 * size[1]).all():
            break
        view.fov += 5
    return view, math.degrees(view.yaw), math.degrees(view.pitch)


NAMES = ["diffuse", "matte-silver", "mirror-silver", "vase"]
VASE_MATERIAL = "0.7,0.08,0.06,0.3,0"


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--image", default=str(REPO / "docs" / "img" / "insert_gallery.png"))
    ap.add_argument("--json", default=str(REPO / "benchmarks" / "results" / "insert_gallery.json"))
    ap.add_argument("--view", choices=("equirect", "perspective"), default="equirect",
                    help="gallery panels: a crop of the panorama, or a camera looking at the objects")
    ap.add_argument("--cli-out", default=None,
                    help="keep the `phyir insert` outputs here (default: a temporary folder)")
    return ap.parse_args()


def _objects(scene, mesh, spots):
    """The three spheres and the vase, dropped on ``spots`` (as many as there are spots)."""
    from phyir.insert import placement
    from phyir.insert.objects import PRESETS, SceneObject, parse_material, primitive

    objs = [SceneObject(primitive("sphere"), PRESETS[m], scale=0.15)
            for m in ("diffuse", "matte-silver", "mirror-silver")]
    objs.append(SceneObject(mesh, parse_material(VASE_MATERIAL), scale=1.0))
    for obj, (u, v) in zip(objs, spots):
        pl = placement.drop(scene, u, v, obj.base_offset())
        obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
    return objs[:len(spots)]


def _panel(ins, scene, objs, spots, exposure: float, view_kind: str, entry: dict):
    """The before/after row of one scene (tone-mapped); its render time and view go to ``entry``."""
    import numpy as np

    from phyir.insert.views import EquirectView, tonemap
    from viewer.insertion import FULL

    H, W = scene.size
    t = time.perf_counter()
    if view_kind == "perspective" and objs:
        size = (440, 330)
        view, yaw, pitch = perspective_on([o.bounding_sphere()[0] for o in objs], size)
        out = ins.render_view(objs, view, size, FULL)
        entry["render_s"] = round(time.perf_counter() - t, 3)
        entry["view"] = {"fov": view.fov, "yaw": round(yaw, 1), "pitch": round(pitch, 1),
                         "size": f"{size[0]}x{size[1]}"}
        before = ins.render_view([], view, size, FULL)["composite"]
        after = out["composite"]
        return np.concatenate([tonemap(before, exposure), tonemap(after, exposure)], 1)
    out = ins.render_view(objs, EquirectView(center=(W / 2, H / 2), zoom=1.0), (W, H), FULL)
    entry["render_s"] = round(time.perf_counter() - t, 3)
    us, vs = [s[0] for s in spots] or [W / 2], [s[1] for s in spots] or [H / 2]
    cw, ch = W // 3, H // 3
    x0 = int(min(max(np.mean(us) - cw / 2, 0), W - cw))
    y0 = int(min(max(np.mean(vs) - ch * 0.6, 0), H - ch))
    box = (slice(y0, y0 + ch), slice(x0, x0 + cw))
    before = tonemap(scene.image.permute(1, 2, 0).numpy()[box], exposure)
    return np.concatenate([before, tonemap(out["composite"][box], exposure)], 1)


def _gallery_scene(ins, path: str, mesh, view_kind: str):
    """One scene's entry (sizes, timings, spots) and its gallery row."""
    import numpy as np

    from phyir.insert.spots import floor_spots
    from phyir.insert.views import load_insert_scene

    t = time.perf_counter()
    scene = load_insert_scene(path)
    load_s = time.perf_counter() - t
    H, W = scene.size
    ins.set_scene(scene)
    t, c = time.perf_counter(), time.process_time()
    spots = floor_spots(scene, 4)
    spots_s, spots_cpu = time.perf_counter() - t, time.process_time() - c
    objs = _objects(scene, mesh, spots)
    lum = scene.image.permute(1, 2, 0).numpy() @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    exposure = float(np.log2(0.18 / max(float(np.median(lum[lum > 0])), 1e-12)))
    entry = {"size": f"{W}x{H}", "objects": NAMES[:len(objs)], "load_s": round(load_s, 2),
             "spots_s": round(spots_s, 2), "spots_cpu_s": round(spots_cpu, 2),
             "spots": [[round(a, 1), round(b, 1)] for a, b in spots]}
    return entry, _panel(ins, scene, objs, spots, exposure, view_kind, entry)


def _cli_runs(path: str, spots, vase_path: str, cli_out: str) -> list[dict]:
    """``phyir insert`` on one scene (it makes its own GL context): a matte-silver sphere on the first
    spot (full-resolution equirect), the vase on its spot (perspective crop)."""
    from phyir.cli import main as cli

    name = Path(path).stem
    runs = []
    vase_args = ["--material", VASE_MATERIAL, "--view", "perspective"]
    for obj, k, extra in (("sphere", 0, ["--scale", "0.15", "--material", "matte-silver"]),
                          (vase_path, 3, vase_args)):
        if k >= len(spots):
            continue
        u, v = spots[k]
        out_path = os.path.join(cli_out, f"insert_{name}_{'sphere' if k == 0 else 'vase'}.exr")
        t, c = time.perf_counter(), time.process_time()
        rc = cli(["insert", path, "--object", obj, *extra, "--at", f"{u - 0.5:.0f},{v - 0.5:.0f}",
                  "-o", out_path])
        stem = os.path.splitext(out_path)[0]
        files = {os.path.basename(f): os.path.getsize(f) for f in (out_path, stem + ".png")
                 if os.path.exists(f)}
        runs.append({"rc": rc, "wall_s": round(time.perf_counter() - t, 2),
                     "cpu_s": round(time.process_time() - c, 2), "files": files})
    return runs


def _save(rows: list, results: dict, image: str, json_path: str) -> None:
    """The gallery (rows stacked, padded to the widest, upscaled to ~1200 px wide) and the JSON."""
    import numpy as np
    from PIL import Image

    width = max(r.shape[1] for r in rows)
    grid = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], 0)
    os.makedirs(os.path.dirname(image), exist_ok=True)
    scale = max(1, 1200 // grid.shape[1])
    big = Image.fromarray(grid).resize((grid.shape[1] * scale, grid.shape[0] * scale), Image.LANCZOS)
    big.save(image, optimize=True)
    os.makedirs(os.path.dirname(json_path), exist_ok=True)
    with open(json_path, "w") as f:
        json.dump(results, f, indent=2)
    print("wrote", image, json_path)


def main() -> int:
    args = _args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import moderngl

    from phyir.insert.objects import load_mesh
    from viewer.insertion import InsertionRenderer

    rows, results = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        cli_out = args.cli_out or tmp
        os.makedirs(cli_out, exist_ok=True)
        vase_path = os.path.join(tmp, "vase.obj")
        vase(vase_path)
        mesh = load_mesh(vase_path)
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
        ins = InsertionRenderer(ctx)
        for path in args.scenes:
            name = Path(path).stem
            results[name], row = _gallery_scene(ins, path, mesh, args.view)
            rows.append(row)
            print(name, results[name], flush=True)
        ins.release()
        ctx.release()
        for path in args.scenes:
            name = Path(path).stem
            results[name]["cli"] = runs = _cli_runs(path, results[name]["spots"], vase_path, cli_out)
            print(name, runs, flush=True)
    _save(rows, results, args.image, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
