"""Live-dragging frame time of an inserted 20k-triangle mesh in a 1024x512 equirect view, against
the bare panorama frame measured in the same run (software GL on this machine: Mesa llvmpipe).

    .venv/bin/python -m benchmarks.insert_drag [--scene FILE] [--frames 20] [--out benchmarks/results]

Each dragging frame moves the object along the floor (phyir.insert.placement.Drag, as a mouse drag does),
recomputes its lighting (probe interpolation, lights, irradiance) and redraws impostor, shadow maps
and composite at the DRAGGING quality; the still frame redraws at FULL quality with cached lighting.
Times are medians of ``--frames`` frames, each ended by ``ctx.finish()``; bare and dragging frames
alternate so that both see the same load when other processes share the CPU.  Besides wall time each
frame's process CPU time is reported (llvmpipe's rendering threads are this process's threads, so
CPU-time ratios hold on a loaded machine, where wall times are inflated by waiting for a core).
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


SIZE = (1024, 512)  # the equirect view (width, height)


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=None, help="scene file (default: the analytic box room, 512x1024)")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--subdivisions", type=int, default=5, help="icosphere subdivisions (5: 20480 faces)")
    ap.add_argument("--relight-tolerance", type=float, default=None,
                    help="override DRAGGING.relight_tolerance (0: relight every frame, as before it existed)")
    ap.add_argument("--old-dragging", action="store_true",
                    help="the earlier dragging quality: full mesh in impostor and shadow maps, a "
                         "look-up per proxy sphere, PCSS blocker search, lights marched on every relight, "
                         "the object's own contact shadow from its proxies")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results"))
    return ap.parse_args()


def _scene(args: argparse.Namespace):
    """The panorama (``--scene`` or the box room) and the dragging quality (``--relight-tolerance``,
    ``--old-dragging``), which also becomes ``viewer.insertion.DRAGGING``."""
    import dataclasses

    import viewer.insertion
    from phyir.io import load_scene

    if args.scene:
        scene = load_scene(args.scene)
    else:
        from tests.support.scenes import box_room

        scene = box_room(512, 1024, grid=(32, 64), probe_size=(16, 32))
    if args.relight_tolerance is not None:
        viewer.insertion.DRAGGING = dataclasses.replace(viewer.insertion.DRAGGING,
                                                        relight_tolerance=args.relight_tolerance)
    if args.old_dragging:
        viewer.insertion.DRAGGING = dataclasses.replace(
            viewer.insertion.DRAGGING, impostor_faces=0, shadow_faces=0, proxy_lookups=True,
            blocker_search=True, reuse_lights=False, own_shadow_bounds=False)
    return scene, viewer.insertion.DRAGGING


def _frame(ctx, scene):
    """The viewer's renderer, a :data:`SIZE` render target and the panorama's frame in it."""
    from phyir.insert.views import EquirectView
    from viewer.renderer import Display, Frame, Renderer

    H, W = scene.size
    renderer = Renderer(ctx)
    target = ctx.framebuffer([ctx.renderbuffer(SIZE, 4)])
    layer = renderer.texture(scene.image.permute(1, 2, 0).numpy())
    view = EquirectView()
    view.fit(SIZE, (H, W))
    return renderer, target, Frame(texture=layer, pano_size=(H, W), view=view, display=Display())


def _timed(ctx, fn, cpu_times: list | None = None) -> float:
    """Wall seconds of ``fn`` with the GL finished before and after (its CPU seconds to ``cpu_times``)."""
    ctx.finish()
    t, c = time.perf_counter(), time.process_time()
    fn()
    ctx.finish()
    if cpu_times is not None:
        cpu_times.append(time.process_time() - c)
    return time.perf_counter() - t


def _ball(subdivisions: int):
    """The icosphere mesh and its matte-silver object (0.25 m)."""
    import trimesh

    from phyir.insert.objects import PRESETS, SceneObject, load_mesh

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "ball.ply")
        trimesh.creation.icosphere(subdivisions=subdivisions).export(path)
        mesh = load_mesh(path)
    return mesh, SceneObject(mesh, PRESETS["matte-silver"], scale=0.25)


def _insert(ctx, scene, obj):
    """The insertion renderer and pass of ``obj`` dropped on the floor 2 m in front of the camera, a
    sideways drag along the floor from there, and the drop's pixel (u, v)."""
    import numpy as np
    import torch

    from phyir import pano
    from phyir.insert import placement
    from viewer.insertion import InsertionRenderer
    from viewer.insertion_pass import InsertionPass

    H, W = scene.size
    ins = InsertionRenderer(ctx)
    ins.set_scene(scene)
    hook = InsertionPass(ins, [obj])
    start = np.array([-0.6, -1.5, -1.4])
    su, sv, _ = pano.points_to_uv(torch.as_tensor(start), H, W)
    pl = placement.drop(scene, float(su), float(sv), obj.base_offset())
    obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
    drag = placement.Drag(scene, pl.contact, (float(su), float(sv) - 8), obj.base_offset())
    return ins, hook, drag, (float(su), float(sv))


def _drag_frames(ctx, renderer, draw, ins, hook, obj, drag, uv, frames: int, dragging_quality) -> dict:
    """Bare and dragging frames in turns (so both see the same load on a shared machine): their wall
    and CPU seconds, the lighting's share, and how many frames recomputed the lighting."""
    t = {"bare": [], "dragging": [], "lighting": [], "bare_cpu": [], "dragging_cpu": []}
    relit, last = [0], [None]  # frames whose lighting was recomputed
    su, sv = uv
    for k in range(frames):
        renderer.overlay_passes.remove(hook)
        t["bare"].append(_timed(ctx, draw, t["bare_cpu"]))
        renderer.overlay_passes.insert(0, hook)

        def step(k=k):
            p = drag.move((su + 1.5 * k, sv - 8))
            obj.position, obj.rotation, obj.support = p.position, p.rotation, (p.contact, p.normal)
            t0 = time.perf_counter()
            lighting = ins.object_state(obj, dragging_quality).lighting
            t["lighting"].append(time.perf_counter() - t0)
            relit[0] += lighting is not last[0]
            last[0] = lighting
            draw()
        t["dragging"].append(_timed(ctx, step, t["dragging_cpu"]))
    t["relit"] = relit[0]
    return t


def _ms(xs: list[float]) -> float:
    """Median in milliseconds."""
    import numpy as np

    return float(np.median(xs)) * 1000


def _save(res: dict, out: str) -> None:
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "insert_drag.json"), "w") as f:
        json.dump(res, f, indent=2)
    for k, v in res.items():
        print(f"{k:28s} {v:.3g}" if isinstance(v, float) else f"{k:28s} {v}")


def main() -> int:
    args = _args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as phyir.cli: idle torch threads must not spin
    import moderngl
    import torch

    scene, DRAGGING = _scene(args)
    H, W = scene.size
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    renderer, target, frame = _frame(ctx, scene)

    def draw():
        renderer.render(target, (0, 0, *SIZE), frame)

    for _ in range(3):
        draw()
    mesh, obj = _ball(args.subdivisions)
    ins, hook, drag, uv = _insert(ctx, scene, obj)
    hook.dragging = True
    renderer.overlay_passes.insert(0, hook)
    draw()
    load_before = os.getloadavg()[0]
    t = _drag_frames(ctx, renderer, draw, ins, hook, obj, drag, uv, args.frames, DRAGGING)
    drag_rect, drag_faces = hook.last_rect, dict(ins.drawn_faces)
    hook.dragging = False
    draw()
    still = [_timed(ctx, draw) for _ in range(max(3, args.frames // 4))]
    bare, dragging = _ms(t["bare"]), _ms(t["dragging"])
    _save({
        "view": f"{SIZE[0]}x{SIZE[1]} equirect", "panorama": f"{W}x{H}", "faces": int(len(mesh.faces)),
        "renderer": ctx.info["GL_RENDERER"], "bare_ms": bare, "dragging_ms": dragging,
        "dragging_lighting_cpu_ms": _ms(t["lighting"]), "still_full_quality_ms": _ms(still),
        "dragging_ratio": dragging / bare, "still_ratio": _ms(still) / bare,
        "bare_cpu_ms": _ms(t["bare_cpu"]), "dragging_cpu_ms": _ms(t["dragging_cpu"]),
        "dragging_cpu_ratio": _ms(t["dragging_cpu"]) / _ms(t["bare_cpu"]), "dragging_faces_drawn": drag_faces,
        "region": hook.last_rect, "dragging_region": drag_rect, "threads": torch.get_num_threads(),
        "relight_tolerance": DRAGGING.relight_tolerance, "relit_frames": t["relit"],
        "old_dragging": args.old_dragging,
        "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],  # 1-minute, before and after
    }, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
