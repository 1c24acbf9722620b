"""``phyir export SCENE --gltf OUT.glb``: the room as a glTF mesh with materials, camera and lights,
and the HDR panorama as ``OUT_env.exr`` beside it; ``--blend OUT.blend``: a ready Blender scene built
from them by Blender (docs/export.md)."""

from __future__ import annotations

import argparse
import os

from phyir.commands import options

# phyir.insert.views.MAX_DISTANCE, repeated (as viewer/commands/insert.py does) so that `phyir --help`
# imports no torch; tests/robustness/test_bad_inputs_options.py checks they agree
POSITION = 1000.0
PIXEL = 1e6  # --at: finite; the panorama's size is checked once it is loaded

HELP = ("export a scene as a glTF room (mesh, materials, camera, lights, objects) + its HDR panorama, "
        "or as a ready Blender scene")


class _Placement(argparse.Action):
    """``--at`` and ``--position`` go into one list, in command-line order, paired with ``--object``."""

    def __call__(self, parser, namespace, values, option_string=None):
        places = list(getattr(namespace, self.dest) or [])
        places.append((option_string, values))
        setattr(namespace, self.dest, places)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("scene", metavar="SCENE",
        help="scene file with depth (from phyir predict), or a panorama (the model predicts it first)")
    add("--gltf", default=None, metavar="OUT.glb", help="binary glTF to write; OUT_env.exr goes beside it")
    add("--exr", default=None, metavar="FILE.exr",
        help="the HDR panorama's file of --gltf (default OUT_env.exr)")
    add("--blend", default=None, metavar="OUT.blend",
        help="a ready Blender scene to write (world, room as shadow catcher, camera, lights, objects, "
             "compositing over the photograph), built by Blender from the glTF set")
    add("--blender", default=None, metavar="PATH",
        help="the Blender program for --blend (default: blender on PATH)")
    add("--grid", default=None, metavar="HxW",
        help="mesh resolution: cell rows x columns of the longitude/latitude grid (default 256x512, "
             "or the panorama's size if smaller)")
    add("--lights", type=options.number(0, 64, integer=True), default=16, metavar="N",
        help="at most N lights (0..64, default 16; 0: none)")
    add("--fov", type=options.number(1, 179), default=60.0,
        help="the glTF camera's vertical field of view, degrees (1..179)")
    add("--object", action="append", default=[], metavar="OBJ",
        help="insert sphere, cube, cylinder or a mesh file (repeatable; each with one --at or --position)")
    add("--at", dest="places", action=_Placement, metavar="U,V", type=options.image_point(PIXEL),
        help="stand the object on the surface seen at U,V: " + options.POINT_HELP)
    add("--position", dest="places", action=_Placement, metavar="X,Y,Z",
        type=options.numbers(3, -POSITION, POSITION, "X,Y,Z"),
        help=f"put the object's centre at this world point (m, each within +-{POSITION:g})")
    add("--scale", action="append", type=options.number(1e-3, 100), default=[], metavar="S",
        help="object size (once for all objects, or once per object): primitives' radius / half-extent "
             "in m (default 0.25), a factor for meshes (default 1), as in phyir insert")
    add("--material", action="append", default=[], metavar="M",
        help="diffuse, matte-silver, mirror-silver or B,B,B,R,M (once, or once per object)")
    add("--weights", default=None, metavar="FILE",
        help="model weights for a SCENE without depth (default: the shipped ones)")


def parse_grid(text: str, size: tuple[int, int]) -> tuple[int, int]:
    """``HxW`` vertex rows x columns, at least 2x4 and at most the panorama's size."""
    from phyir.errors import InputError

    try:
        gh, gw = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError("--grid", f"expected ROWSxCOLUMNS, e.g. 256x512, got {text!r}") from None
    H, W = size
    if not (2 <= gh <= H and 4 <= gw <= W):
        raise InputError("--grid", f"expected 2..{H} rows and 4..{W} columns (the panorama is {H}x{W}), "
                                   f"got {text!r}")
    return gh, gw


def check_output(path: str, flag: str, ext: str) -> None:
    from phyir.errors import InputError

    if os.path.splitext(path)[1].lower() != ext:
        raise InputError(flag, f"{path}: expected a {ext} file name")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        problem = "is not a folder" if os.path.exists(folder) else "does not exist"
        raise InputError(flag, f"{path}: the folder {folder} {problem}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(flag, f"{path}: the folder {folder} is not writable")


def _per_object(values: list, n: int, flag: str, default):
    from phyir.errors import InputError

    if len(values) not in (0, 1, n):
        raise InputError(flag, f"give it once for all objects or once per --object ({n}), got {len(values)}")
    return [values[0] if len(values) == 1 else (values[k] if values else default) for k in range(n)]


def _warn_mixed_scale(specs: list[str], scales: list[float]) -> None:
    """One --scale for primitives and meshes alike is a radius in metres for the ones and a factor for
    the others: almost never what was meant, so say so (it stays valid, as documented)."""
    import warnings

    from phyir.insert.objects import PRIMITIVES

    kinds = {spec in PRIMITIVES for spec in specs}
    if len(scales) == 1 and len(kinds) == 2:
        warnings.warn(f"--scale {scales[0]:g} is given once, so every object has it: the primitives' radius "
                      f"in metres and the meshes' size factor; give one --scale per --object to size them "
                      f"apart", stacklevel=2)


def make_objects(args: argparse.Namespace, scene) -> list:
    """The inserted objects, placed as ``phyir insert`` places them."""
    import warnings

    from phyir.errors import InputError
    from phyir.insert import placement, views

    places = args.places or []
    n = len(args.object)
    if len(places) != n:
        raise InputError("--object", f"each --object needs one --at or --position: {n} objects, "
                                     f"{len(places)} placements")
    objects = []
    _warn_mixed_scale(args.object, args.scale)
    scales = _per_object(args.scale, n, "--scale", None)
    materials = _per_object(args.material, n, "--material", "diffuse")
    H, W = scene.size
    for spec, (flag, values), scale, material in zip(args.object, places, scales, materials):
        obj = views.make_object(spec, scale, material)
        if flag == "--at":
            views.place_object(obj, scene, at=options.to_pixels(values, W, H))
            if placement.on_ceiling(obj.support):  # hangs from it: warned, not refused (placement.py)
                warnings.warn(placement.ceiling_warning(f"--at {values[0]:g},{values[1]:g}", H), stacklevel=2)
        else:
            views.place_object(obj, scene, position=values)
        inside = placement.camera_inside([obj])  # [issue 22] as phyir insert: nothing could be seen
        if inside:
            raise InputError(flag, f"{inside} (--scale)")
        objects.append(obj)
    return objects


def run(args: argparse.Namespace) -> int:
    from phyir.errors import InputError
    from phyir.export.bundle import environment_path, export_gltf
    from phyir.export.room_mesh import DEFAULT_GRID
    from phyir.io import load_scene

    if args.gltf is None and args.blend is None:
        raise InputError(None, "nothing to write: give --gltf OUT.glb, --blend OUT.blend or both")
    if args.gltf is None and args.exr is not None:
        raise InputError("--exr", "names the panorama of --gltf: give --gltf too")
    if args.blend is None and args.blender is not None:
        raise InputError("--blender", "runs Blender for --blend: give --blend too")
    exr = None
    if args.gltf is not None:
        exr = args.exr or environment_path(args.gltf)
        check_output(args.gltf, "--gltf", ".glb")
        check_output(exr, "--exr", ".exr")
        if os.path.exists(args.scene) and os.path.exists(exr) and os.path.samefile(args.scene, exr):
            raise InputError("--exr", f"{exr} is the input scene; choose another file name")
    if args.blend is not None:
        from phyir.export.blend import find_blender

        check_output(args.blend, "--blend", ".blend")
        find_blender(args.blender)  # before the scene is read: a missing Blender is a quick error
    if not (0 <= args.lights <= 256):
        raise InputError("--lights", f"expected 0..256, got {args.lights}")
    if not (1.0 <= args.fov <= 170.0):
        raise InputError("--fov", f"expected 1..170 degrees, got {args.fov:g}")
    scene = load_scene(args.scene)
    if scene.depth is not None:
        from phyir.insert.views import require_depth

        require_depth(scene, args.scene)
    if scene.depth is None:
        from phyir import predict

        print(f"{args.scene}: no depth: predicting the layers with the model (phyir.predict)")
        scene = predict(scene, weights=args.weights)
    grid = (parse_grid(args.grid, scene.size) if args.grid is not None
            else tuple(min(g, n) for g, n in zip(DEFAULT_GRID, scene.size)))
    objects = make_objects(args, scene)
    if args.blend is not None:
        from phyir.export.blend import write_blend

        b = write_blend(scene, args.blend, blender=args.blender, gltf=args.gltf, exr=exr, grid=grid,
                        objects=objects, max_lights=args.lights, fov_deg=args.fov)
        lights = "on" if b.lights_render else "off in renders: the room's EXR emission carries their light"
        print(f"wrote {b.blend} ({b.blend_bytes / 1e6:.1f} MB, Blender {b.blender}: room as shadow catcher, "
              f"camera, {b.lights} lights ({lights}), {b.objects} object{'' if b.objects == 1 else 's'}, "
              f"compositing over the photograph) in {b.seconds:.1f} s")
        if args.gltf is None:
            return 0
        r = b.gltf
    else:
        r = export_gltf(scene, args.gltf, exr_path=exr, grid=grid, objects=objects, max_lights=args.lights,
                        fov_deg=args.fov)
    print(f"wrote {r.glb} ({r.glb_bytes / 1e6:.1f} MB: {r.vertices} vertices, {r.faces} triangles, "
          f"{r.dropped} dropped at depth edges, {r.lights} lights, {r.objects} objects) and {r.exr} "
          f"({r.exr_bytes / 1e6:.1f} MB) in {r.seconds:.2f} s")
    return 0
