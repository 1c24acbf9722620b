"""``phyir-view``'s scripted insertion: ``--object SPEC [--at U,V | --position X,Y,Z] [--scale S]
[--material M]``, repeatable; each ``--at``/``--position``/``--scale``/``--material`` belongs to the
``--object`` before it, with the meaning they have in ``phyir insert``."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, replace

from phyir.commands import options
from phyir.errors import PhyIRError


@dataclass(frozen=True)
class ObjectSpec:
    """One ``--object`` and its options, as given."""

    spec: str
    at: tuple[float, float] | None = None  # pixels, or an options.ImagePoint of fractions
    position: tuple[float, float, float] | None = None
    scale: float | None = None  # None: the panel's default (25 cm primitives, meshes in their units)
    material: str = "diffuse"


def _numbers(text: str, n: int, option: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(t) for t in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n or not all(math.isfinite(x) for x in vals):
        raise ValueError(f"{option}: expected {n} finite comma-separated numbers, got {text!r}")
    return vals


class _ObjectAction(argparse.Action):
    """``--object`` starts a new object; its options set fields of the last one."""

    def __call__(self, parser, namespace, value, option_string=None):
        objects = list(getattr(namespace, self.dest) or [])
        if option_string == "--object":
            objects.append(ObjectSpec(value))
        elif not objects:
            parser.error(f"{option_string} needs an --object before it")
        else:
            last = objects[-1]
            if option_string in ("--at", "--position") and (last.at or last.position):
                parser.error(f"--object {last.spec}: give one of --at or --position")
            try:
                field, parsed = _parse(option_string, value)
            except ValueError as e:
                parser.error(str(e))
            objects[-1] = replace(last, **{field: parsed})
        setattr(namespace, self.dest, objects)


def _parse(option: str, value: str):
    if option == "--at":
        try:
            return "at", options.image_point(1e6)(value)
        except argparse.ArgumentTypeError as e:
            raise ValueError(f"--at: {e}") from None
    if option == "--position":
        return "position", _numbers(value, 3, option)
    if option == "--scale":
        (s,) = _numbers(value, 1, option)
        if not 1e-3 <= s <= 100:
            raise ValueError(f"--scale: expected a size in [0.001, 100] m, got {value!r}")
        return "scale", s
    return "material", value


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("inserted objects (repeatable; each option belongs to the --object before it)")
    kw = dict(action=_ObjectAction, dest="objects", default=[])
    g.add_argument("--object", metavar="OBJ", **kw,
                   help="sphere, cube, cylinder or a mesh file (OBJ/PLY/STL/OFF/GLB, metres)")
    g.add_argument("--at", metavar="U,V", **kw,
                   help="stand it on the surface seen at U,V (default: in front of the camera, below the "
                        "horizon): " + options.POINT_HELP)
    g.add_argument("--position", metavar="X,Y,Z", **kw, help="its centre at this world point (m)")
    g.add_argument("--scale", metavar="S", **kw,
                   help="size: primitives' radius / half-extent in m (default 0.25); meshes: a factor (1)")
    g.add_argument("--material", metavar="M", **kw,
                   help="diffuse (default), matte-silver, mirror-silver or B,B,B,R,M")


def add_objects(objects, specs: list[ObjectSpec]) -> None:
    """Insert ``specs`` into the scene of ``objects`` (a :class:`viewer.app.objects.InsertedObjects`;
    the scene has depth and probes); one-line errors naming the option."""
    from phyir.insert import views
    from phyir.insert.objects import parse_material
    from phyir.insert.placement import camera_inside, ceiling_warning, on_ceiling

    if specs and not objects.sync():
        raise PhyIRError(f"{objects.scene_name}: --object needs the scene's depth and probes "
                         "(the model did not run: drop --no-model, or open a predicted scene)")
    for s in specs:
        material = parse_material(s.material)
        obj = objects.add(s.spec, material=material, scale=s.scale)
        if s.at is not None or s.position is not None:
            H, W = objects.scene().size
            at = options.to_pixels(s.at, W, H) if s.at is not None else None
            views.place_object(obj, objects.scene(), at=at, position=s.position,
                               log=lambda text: objects.note("warning", text))
            if at is not None and on_ceiling(obj.support):
                objects.note("warning", ceiling_warning(f"--object {s.spec} --at {s.at[0]:g},{s.at[1]:g}", H))
        problem = camera_inside([obj])
        if problem:
            raise PhyIRError(f"--object {s.spec}: {problem}")
