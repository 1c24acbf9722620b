"""``phyir insert INPUT --object ... (--at U,V | --position X,Y,Z | --path ...) -o OUT``: virtual object
insertion rendered headlessly (EGL) at the panorama's resolution (docs/insertion.md)."""

from __future__ import annotations

import argparse
import time

# checked by phyir.cli before run(): the renderer needs GL
REQUIRES = ("viewer", "phyir insert", ("moderngl", "glfw", "trimesh"))
HELP = "insert a sphere, cube, cylinder or mesh into a panorama and render it (EXR passes + PNG, GIF)"


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    from phyir.errors import InputError

    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n:
        raise InputError(what, f"expected {n} comma-separated numbers, got {text!r}")
    return vals


def _size(text: str) -> tuple[int, int]:
    from phyir.errors import InputError

    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError("--size", f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (8 <= w <= 16384 and 8 <= h <= 16384):
        raise InputError("--size", f"expected 8..16384 pixels per side, got {text!r}")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("input", metavar="INPUT",
        help="scene file with depth and probes, or a panorama (the model predicts its layers first)")
    add("--object", required=True, metavar="OBJ",
        help="sphere (radius 1), cube ([-1,1]^3), cylinder, or a mesh file (OBJ/PLY/STL/OFF/GLB, metres)")
    where = parser.add_mutually_exclusive_group().add_argument
    where("--at", metavar="U,V", help="stand the object on the surface seen at pixel column U, row V")
    where("--position", metavar="X,Y,Z", help="put the object's centre at this world point (m)")
    where("--path", metavar="U1,V1:U2,V2", help="move the object along these pixels (--frames)")
    add("--frames", type=int, default=24, help="frames along --path (default 24)")
    add("--scale", type=float, default=1.0,
        help="size factor: primitives are unit-size (sphere radius 1 m), meshes keep their units")
    add("--material", default="diffuse",
        help="diffuse, matte-silver, mirror-silver (supplement Table 2) or B,B,B,R,M")
    add("--fusion", default="three-image", choices=("three-image", "differential"),
        help="supplement D.2: object lit by the environment (three-image, default) or seeing the "
             "virtual plane (differential)")
    add("--view", default="equirect", choices=("equirect", "perspective"))
    add("--size", type=_size, default=None, metavar="WxH",
        help="output size (equirect default: the panorama's; perspective: 960x720)")
    add("--fov", type=float, default=60.0, help="perspective vertical field of view (degrees)")
    add("--yaw", type=float, default=None, help="perspective yaw, degrees (default: toward the object)")
    add("--pitch", type=float, default=None, help="perspective pitch, degrees (default: toward the object)")
    add("--quality", default="full", choices=("full", "draft"))
    add("--exposure", type=float, default=None, metavar="EV",
        help="PNG/GIF exposure (default: median luminance -> 0.18)")
    add("--weights", default=None, metavar="FILE",
        help="model weights for panoramas without depth/probes (default: the shipped ones)")
    add("-o", "--out", required=True, metavar="OUT", help="OUT.exr (passes + OUT.png) or OUT.png")


def run(args: argparse.Namespace) -> int:
    from phyir.errors import InputError
    from phyir.insert import views  # GL and trimesh are imported only here
    from viewer.gl.quality import DRAFT_EXPORT
    from viewer.gl.window import gl_context
    from viewer.insertion import FULL, InsertionRenderer

    t0 = time.perf_counter()
    scene = views.load_insert_scene(args.input, weights=args.weights)
    H, W = scene.size
    obj = views.make_object(args.object, args.scale, args.material)
    waypoints = None
    if args.path:
        waypoints = [_floats(p, 2, "--path") for p in args.path.split(":")]
        points = views.path_points(waypoints, args.frames, W)
    elif args.at:
        views.place_object(obj, scene, at=_floats(args.at, 2, "--at"))
    elif args.position:
        views.place_object(obj, scene, position=_floats(args.position, 3, "--position"))
    else:
        raise InputError("--at", "give --at U,V, --position X,Y,Z or --path U1,V1:U2,V2")
    ctx = gl_context()
    renderer = InsertionRenderer(ctx)
    try:
        renderer.set_scene(scene)
        quality = FULL if args.quality == "full" else DRAFT_EXPORT
        spec = views.ViewSpec(args.view, args.size, args.fov, args.yaw, args.pitch)
        meta = {"input": args.input, "object": args.object, "material": obj.material.as_text(),
                "scale": f"{obj.scale:g}", "fusion": args.fusion}
        if waypoints is None:
            view, size = spec.build(scene, obj.bounding_sphere()[0])
            out = renderer.render_view([obj], view, size, quality, args.fusion)
            files = views.write_passes(out, args.out, args.exposure, meta)
            print(f"wrote {', '.join(files)} ({size[0]}x{size[1]}, {time.perf_counter() - t0:.1f} s)")
            return 0
        from phyir.insert import placement

        normal = placement.scene_normals(scene)
        frames = []
        view = size = None
        for u, v in points:
            views.place_object(obj, scene, at=(u - 0.5, v - 0.5), normal=normal)
            if view is None or spec.kind == "equirect":
                view, size = spec.build(scene, obj.bounding_sphere()[0])
            frames.append(renderer.render_view([obj], view, size, quality, args.fusion))
        stats = views.write_animation(frames, args.out, args.exposure)
        print(f"wrote {len(frames)} frames, {args.out.rsplit('.', 1)[0]}.gif; static background change "
              f"{stats['static_background_change']:.2e}, object step {stats['object_step']:.3f} "
              f"({time.perf_counter() - t0:.1f} s)")
        return 0
    finally:
        renderer.release()
        ctx.release()
