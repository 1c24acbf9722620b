"""``phyir insert INPUT --object ... (--at U,V | --position X,Y,Z | --path ...) -o OUT``: virtual object
insertion rendered headlessly (EGL) at the panorama's resolution (docs/insertion.md)."""

from __future__ import annotations

import argparse
import sys
import time

from phyir.commands import options

# checked by phyir.cli before run(): the renderer needs GL
REQUIRES = ("viewer", "phyir insert", ("moderngl", "glfw", "trimesh"))
HELP = "insert a sphere, cube, cylinder or mesh into a panorama and render it (EXR passes + PNG, GIF)"


# bounds of the numeric options, the library's (phyir.insert.views MIN_FOV..MAX_FOV, MIN_SCALE..
# MAX_SCALE, MAX_DISTANCE, MAX_RENDER_SIDE, MAX_RENDER_PIXELS) repeated so that `phyir --help`
# imports no torch; tests/robustness/test_bad_inputs_options.py checks they agree
FOV = (10.0, 150.0)
SCALE = (1e-3, 100.0)
POSITION = 1000.0  # metres from the camera, per coordinate
RENDER_SIDE = 8192
RENDER_PIXELS = 2048 * 2048
PIXEL = 1e6  # --at / --path coordinates: finite; the panorama's size is checked once it is loaded
MAX_FRAMES = 1000


def _path(text: str) -> list[options.ImagePoint]:
    """``U1,V1:U2,V2[:...]``: at least two points, each as ``--at`` takes it (pixels or fractions)."""
    point = options.image_point(PIXEL)
    points = [point(p) for p in text.split(":")]
    if len(points) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two points U1,V1:U2,V2, got {text!r}")
    return points


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("input", metavar="INPUT",
        help="scene file with depth and probes, or a panorama (the model predicts its layers first)")
    add("--object", required=True, metavar="OBJ",
        help="sphere (radius 1), cube ([-1,1]^3), cylinder, or a mesh file (OBJ/PLY/STL/OFF/GLB, metres)")
    where = parser.add_mutually_exclusive_group().add_argument
    where("--at", metavar="U,V", type=options.image_point(PIXEL),
          help="stand the object on the surface seen at U,V: " + options.POINT_HELP + "; on a ceiling "
               "it hangs upside down (warned)")
    where("--position", metavar="X,Y,Z", type=options.numbers(3, -POSITION, POSITION, "X,Y,Z"),
          help=f"put the object's centre at this world point (m, each within +-{POSITION:g})")
    where("--path", metavar="U1,V1:U2,V2", type=_path,
          help="move the object along these points (--frames), each as --at takes it")
    add("--frames", type=options.number(2, MAX_FRAMES, integer=True), default=24,
        help=f"frames along --path (2..{MAX_FRAMES}, default 24)")
    add("--scale", type=options.number(*SCALE), default=None,
        help=f"size factor ({SCALE[0]:g}..{SCALE[1]:g}): primitives are unit-size, so the scale is their "
             "radius / half-extent in metres (default 0.25: 25 cm); meshes keep their own units (metres; "
             "default 1)")
    add("--material", default="diffuse",
        help="diffuse, matte-silver, mirror-silver (supplement Table 2) or B,B,B,R,M")
    add("--fusion", default="three-image", choices=("three-image", "differential"),
        help="supplement D.2: object lit by the environment (three-image, default) or seeing the "
             "virtual plane (differential)")
    add("--view", default="equirect", choices=("equirect", "perspective"))
    add("--size", type=options.size(8, RENDER_SIDE), default=None, metavar="WxH",
        help=f"output size (equirect default: the panorama's; perspective: 960x720; at most {RENDER_SIDE} "
             f"per side and {RENDER_PIXELS:,} pixels, or the panorama's when it has more)")
    add("--fov", type=options.number(*FOV), default=60.0,
        help=f"perspective vertical field of view (degrees, {FOV[0]:g}..{FOV[1]:g})")
    add("--yaw", type=options.number(-3600, 3600), default=None,
        help="perspective yaw, degrees (default: toward the object)")
    add("--pitch", type=options.number(-90, 90), default=None,
        help="perspective pitch, degrees (default: toward the object)")
    add("--quality", default="full", choices=("full", "draft"))
    add("--exposure", type=options.number(-64, 64), default=None, metavar="EV",
        help="PNG/GIF exposure (-64..64; default: median luminance -> 0.18)")
    add("--weights", default=None, metavar="FILE",
        help="model weights for panoramas without depth/probes (default: the shipped ones)")
    add("-o", "--out", required=True, metavar="OUT", type=options.path,
        help="OUT.exr (passes + OUT.png) or OUT.png")


def _warn(problem: str | None, what: str = "") -> None:
    if problem:
        print(f"phyir insert: warning: {what}{problem}", file=sys.stderr)


def _placements(obj, scene, args) -> tuple[str, list[tuple]]:
    """The placing option and the object's placement (position, rotation, support) of every frame,
    all computed (and checked: inside the panorama, not around the camera) before any rendering."""
    from phyir.errors import InputError
    from phyir.insert import placement, views

    H, W = scene.size
    if args.path:
        waypoints = [options.to_pixels(p, W, H) for p in args.path]
        option, points = "--path", views.path_points(waypoints, args.frames, W, H)
    elif args.at:
        option, points = "--at", [options.to_pixels(args.at, W, H)]
    elif args.position:
        option, points = "--position", None
    else:
        raise InputError("--at", "give --at U,V, --position X,Y,Z or --path U1,V1:U2,V2")
    normal = placement.scene_normals(scene) if points else None
    out = []
    for at in points or [None]:
        views.place_object(obj, scene, at=at, position=None if at else args.position, normal=normal)
        inside = placement.camera_inside([obj])
        if inside:
            raise InputError(option, f"{inside} (--scale)")
        out.append((obj.position.copy(), obj.rotation.copy(), obj.support))
    return option, out


def _ceiling_warning(option: str, poses: list[tuple], height: int, args: argparse.Namespace) -> str | None:
    """Placements on the ceiling hang the object there: warned about once the render is written, not
    refused (the comment at phyir.insert.placement.CEILING_COS says why)."""
    from phyir.insert import placement

    hanging = sum(placement.on_ceiling(support) for _, _, support in poses)
    if not hanging or option == "--position":  # (a --position rests on nothing: it is where it was put)
        return None
    given = f"--at {args.at[0]:g},{args.at[1]:g}" if option == "--at" else option
    return placement.ceiling_warning(given, height, hanging, len(poses))


def _check_outputs_spare_the_input(args: argparse.Namespace) -> None:
    """[issue 22] ``-o`` (or the PNG beside an OUT.exr) must not be the input: the passes would
    replace the scene or panorama they were rendered from."""
    import os

    from phyir.errors import InputError

    stem, ext = os.path.splitext(args.out)
    outs = {args.out, stem + ".png"} if ext.lower() == ".exr" else {args.out}
    for out in outs:
        if os.path.exists(out) and os.path.exists(args.input) and os.path.samefile(out, args.input):
            raise InputError("-o", f"{out} is the input {args.input}: choose another output name")


def run(args: argparse.Namespace) -> int:
    from phyir.insert import placement, views  # GL and trimesh are imported only here
    from viewer.gl.quality import DRAFT_EXPORT
    from viewer.gl.window import gl_context
    from viewer.insertion import FULL, InsertionRenderer

    t0 = time.perf_counter()
    _check_outputs_spare_the_input(args)
    scene = views.load_insert_scene(args.input, weights=args.weights)
    obj = views.make_object(args.object, args.scale, args.material)
    option, poses = _placements(obj, scene, args)
    ceiling = _ceiling_warning(option, poses, scene.size[0], args)
    spec = views.ViewSpec(args.view, args.size, args.fov, args.yaw, args.pitch)
    views.check_render_size(spec.build(scene, obj.bounding_sphere()[0])[1], pano_size=scene.size)
    ctx = gl_context()
    renderer = InsertionRenderer(ctx)
    try:
        gl_max = min(int(ctx.info.get(k, views.MAX_RENDER_SIDE))
                     for k in ("GL_MAX_RENDERBUFFER_SIZE", "GL_MAX_TEXTURE_SIZE"))
        renderer.set_scene(scene)
        quality = FULL if args.quality == "full" else DRAFT_EXPORT
        meta = {"input": args.input, "object": args.object, "material": obj.material.as_text(),
                "scale": f"{obj.scale:g}", "fusion": args.fusion}
        problems: list[str] = []

        def render(pose, view=None):
            obj.position, obj.rotation, obj.support = pose
            if view is None or spec.kind == "equirect":
                view, size = spec.build(scene, obj.bounding_sphere()[0])
            else:
                size = spec.size or (960, 720)
            views.check_render_size(size, gl_max, scene.size)
            out = renderer.render_view([obj], view, size, quality, args.fusion)
            problem = placement.coverage_problem(out["alpha"])
            if problem:
                problems.append(problem)
            return out, view, size

        if args.path is None:
            out, _, size = render(poses[0])
            files = views.write_passes(out, args.out, args.exposure, meta)
            _warn(ceiling)
            _warn(problems[0] if problems else None, f"{option}: ")
            print(f"wrote {', '.join(files)} ({size[0]}x{size[1]}, {time.perf_counter() - t0:.1f} s)")
            return 0

        def frames():  # rendered one at a time while write_animation writes and measures them
            view = None
            for pose in poses:
                out, view, _ = render(pose, view)
                yield out

        stats = views.write_animation(frames(), args.out, args.exposure)
        _warn(ceiling)
        if problems:
            _warn(f"{len(problems)} of {len(poses)} frames: {problems[0]}", "--path: ")
        print(f"wrote {len(poses)} frames, {args.out.rsplit('.', 1)[0]}.gif; static background change "
              f"{stats['static_background_change']:.2e}, object step {stats['object_step']:.3f} "
              f"({time.perf_counter() - t0:.1f} s)")
        return 0
    finally:
        renderer.release()
        ctx.release()
