"""Placing inserted objects on the surfaces of a panorama (pure torch/numpy; the viewer's clicks and
``phyir insert --at/--position`` use the same functions).

* :func:`surface_at` — the 3D point and normal of the surface seen at panorama coordinates (u, v):
  the pixel ray meets the plane of the nearest pixel's point and normal, so points on a planar
  floor are exactly on it (the bilinear radial depth of a plane is not planar), and depth edges
  pick one side instead of floating between foreground and background.
* :func:`drop` — stand an object on that surface: its local +y along the surface normal (normals
  within ``snap_deg`` of vertical snap to exactly vertical, so predicted normals don't tilt objects
  on floors and tables), the lowest point of its mesh on the surface.
* :class:`Drag` — moving an object with the mouse: the cursor keeps its offset (in panorama pixels)
  from the object's contact point when the drag starts, and each move drops the object at the
  surface under the offset cursor, so it slides over the floor and climbs onto a table top.
* :func:`place_at_position` — an object centred at a world point, resting on nothing; the surface
  straight below it (``support``) is found by marching the depth panorama.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano
from phyir.errors import PhyIRError
from phyir.scene import PanoScene

SNAP_DEG = 10.0
GRAZING_COS = 0.05  # pixel rays more grazing than this to the plane use the pixel's point itself


@dataclass
class Surface:
    point: np.ndarray  # [3] world, metres
    normal: np.ndarray  # [3] unit, facing the camera


@dataclass
class Placement:
    """Where an object goes: ``position`` of its local origin, ``rotation`` (3x3) and the surface
    it rests on (``contact`` under its lowest point, ``normal``)."""

    position: np.ndarray
    rotation: np.ndarray
    contact: np.ndarray
    normal: np.ndarray


def rotation_to(up: np.ndarray) -> np.ndarray:
    """The shortest rotation taking +y to the unit vector ``up``."""
    y = np.array([0.0, 1.0, 0.0])
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    c = float(y @ u)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    k = np.cross(y, u)
    s = float(np.linalg.norm(k))
    k = k / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def scene_normals(scene: PanoScene) -> torch.Tensor:
    """The normal layer, or normals from the depth when the scene has none (compute once, reuse)."""
    if scene.normal is not None:
        return scene.normal.float()
    return pano.normals_from_depth(scene.depth.float())


def _require_depth(scene: PanoScene) -> None:
    if scene.depth is None:
        raise PhyIRError("placement needs the scene's depth layer")


def surface_at(scene: PanoScene, u: float, v: float, normal: torch.Tensor | None = None) -> Surface:
    """The surface seen at continuous panorama coordinates (u, v) (see the module doc)."""
    _require_depth(scene)
    H, W = scene.size
    i = min(max(int(math.floor(v)), 0), H - 1)
    j = int(math.floor(u)) % W
    n_all = scene_normals(scene) if normal is None else normal
    depth = float(scene.depth[0, i, j])
    if not math.isfinite(depth) or depth <= 0:
        raise PhyIRError(f"no surface at pixel ({u:.1f}, {v:.1f}): the depth there is {depth:g}")
    f64 = torch.float64
    d0 = pano.uv_to_dir(torch.tensor(j + 0.5, dtype=f64), torch.tensor(i + 0.5, dtype=f64), H, W).numpy()
    p0 = depth * d0
    n0 = n_all[:, i, j].double().numpy()
    n0 = n0 / max(np.linalg.norm(n0), 1e-12)
    d = pano.uv_to_dir(torch.tensor(float(u), dtype=torch.float64),
                       torch.tensor(float(min(max(v, 0.0), H)), dtype=torch.float64), H, W).numpy()
    cos = float(d @ n0)
    point = p0
    if abs(cos) > GRAZING_COS:
        t = float(p0 @ n0) / cos
        if t > 0:
            point = t * d
    return Surface(point, n0)


def snap_normal(n: np.ndarray, snap_deg: float = SNAP_DEG) -> np.ndarray:
    """``n`` or exactly +-y when it is within ``snap_deg`` of vertical."""
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    if abs(n[1]) >= math.cos(math.radians(snap_deg)):
        return np.array([0.0, math.copysign(1.0, n[1]), 0.0])
    return n


def yaw_of(rotation: np.ndarray) -> float:
    """The turn about the object's own up axis kept when it moves to another surface."""
    x = rotation @ np.array([1.0, 0.0, 0.0])
    up = rotation @ np.array([0.0, 1.0, 0.0])
    base = rotation_to(up) @ np.array([1.0, 0.0, 0.0])
    return math.atan2(float(np.cross(base, x) @ up), float(base @ x))


def _yaw_about_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rest_on(surface: Surface, base_offset: float, yaw: float = 0.0, snap_deg: float = SNAP_DEG) -> Placement:
    """Stand an object whose lowest point is ``base_offset`` below its origin (along its +y) on a surface."""
    n = snap_normal(surface.normal, snap_deg)
    rot = rotation_to(n) @ _yaw_about_y(yaw)
    return Placement(surface.point + base_offset * n, rot, surface.point.copy(), n)


def drop(scene: PanoScene, u: float, v: float, base_offset: float, yaw: float = 0.0,
         snap_deg: float = SNAP_DEG, normal: torch.Tensor | None = None) -> Placement:
    """Drop an object onto the surface seen at (u, v) (continuous panorama coordinates);
    ``normal``: :func:`scene_normals` computed once by callers that drop repeatedly."""
    return rest_on(surface_at(scene, u, v, normal), base_offset, yaw, snap_deg)


def contact_uv(scene: PanoScene, point: np.ndarray) -> tuple[float, float]:
    H, W = scene.size
    u, v, _ = pano.points_to_uv(torch.as_tensor(point, dtype=torch.float64), H, W)
    return float(u), float(v)


class Drag:
    """Dragging an object resting at ``contact`` from the cursor position ``start_uv``."""

    def __init__(self, scene: PanoScene, contact: np.ndarray, start_uv: tuple[float, float],
                 base_offset: float, yaw: float = 0.0, snap_deg: float = SNAP_DEG):
        self.scene, self.base_offset, self.yaw, self.snap_deg = scene, base_offset, yaw, snap_deg
        self.normal = scene_normals(scene)
        cu, cv = contact_uv(scene, contact)
        W = scene.size[1]
        du = (cu - start_uv[0] + W / 2) % W - W / 2  # shortest way round the seam
        self.offset = (du, cv - start_uv[1])

    def move(self, cursor_uv: tuple[float, float]) -> Placement:
        H, W = self.scene.size
        u = (cursor_uv[0] + self.offset[0]) % W
        v = min(max(cursor_uv[1] + self.offset[1], 0.0), H - 1e-6)
        return drop(self.scene, u, v, self.base_offset, self.yaw, self.snap_deg, self.normal)


def support_below(scene: PanoScene, point: np.ndarray, surface=None) -> Surface | None:
    """The surface straight below ``point`` (marching the depth panorama along -y), or None."""
    from phyir.lighting.projection import DepthSurface

    _require_depth(scene)
    surf = surface if surface is not None else DepthSurface.from_scene(scene)
    o = torch.as_tensor(np.asarray(point, dtype=np.float32)).reshape(3, 1)
    t, _ = surf.trace(o, torch.tensor([[0.0], [-1.0], [0.0]]))
    if not math.isfinite(float(t[0])):
        return None
    hit = np.asarray(point, dtype=np.float64) + float(t[0]) * np.array([0.0, -1.0, 0.0])
    u, v = contact_uv(scene, hit)
    s = surface_at(scene, u, v)
    return Surface(hit, s.normal)


def place_at_position(scene: PanoScene, centre: np.ndarray, centre_offset: np.ndarray,
                      rotation: np.ndarray | None = None, surface=None) -> tuple[Placement, bool]:
    """An object whose bounding centre is at ``centre`` (world); ``centre_offset`` is that centre in
    the object's scaled, rotated local frame.  Returns the placement (contact and normal: the surface
    below, if any) and whether the centre lies in the camera's free space (else it is hidden)."""
    rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    below = support_below(scene, c, surface) if scene.depth is not None else None
    if below is None:
        contact, normal = c.copy(), np.array([0.0, 1.0, 0.0])
    else:
        contact, normal = below.point, snap_normal(below.normal)
    H, W = scene.size
    u, v = contact_uv(scene, c)
    i, j = min(int(v), H - 1), int(u) % W
    free = float(np.linalg.norm(c)) < float(scene.depth[0, i, j]) if scene.depth is not None else True
    return Placement(c - rot @ np.asarray(centre_offset, dtype=np.float64), rot, contact, normal), free


# ---------------------------------------------------------------------------------------------
# sanity of a render: what the camera sees of the objects (issue 22, class 5)

COVERED_ALPHA = 0.5  # coverage above which a pixel counts as the object's
# objects are drawn as impostors seen from outside their bounding sphere: within CAMERA_CLEARANCE x
# its radius the renderer (viewer/gl/impostors.py) cannot draw them at all
CAMERA_CLEARANCE = 1.02


def camera_inside(objects, camera=(0.0, 0.0, 0.0)) -> str | None:
    """A one-line problem when the ``camera`` point (world, metres; the panorama's centre by default,
    the perspective view's too) lies within :data:`CAMERA_CLEARANCE` x the bounding sphere of a
    visible object (the render would show nothing of it), else None.  ``objects``:
    :class:`phyir.insert.objects.SceneObject` values (anything with ``bounding_sphere()``,
    ``visible`` and ``name``)."""
    cam = np.asarray(camera, dtype=np.float64)
    for obj in objects:
        if not getattr(obj, "visible", True):
            continue
        centre, radius = obj.bounding_sphere()
        dist = float(np.linalg.norm(cam - centre))
        if dist <= radius * CAMERA_CLEARANCE:
            return (f"the camera is inside the object {obj.name!r} (within its bounding sphere: centre "
                    f"{dist:.3g} m away, radius {radius:.3g} m), which can't be drawn: move it away or "
                    "make it smaller")
    return None


def coverage_problem(alpha: np.ndarray) -> str | None:
    """A one-line warning when a rendered view's object coverage ``alpha [h, w]`` is empty (the
    objects are hidden behind the scene, outside the view, beyond the far plane or smaller than a
    pixel) or fills every pixel (the view shows nothing but the object), else None."""
    a = np.asarray(alpha)
    covered = a > COVERED_ALPHA
    if not np.isfinite(a).all():
        return "the object coverage of the render is not finite (NaN): the placement is broken"
    if not (a > 0).any():
        return ("no object is visible in the render (hidden behind the scene's surfaces, outside the "
                "view, too far or smaller than a pixel)")
    if covered.all():
        return ("an object covers the whole view (is the camera inside it, or is it far too large — "
                "a mesh modelled in centimetres?)")
    return None


# Standing an object on a surface that faces down (a ceiling) hangs it there upside down.  That is
# warned about, not refused: a pendant lamp or a hanging plant is what it is for, and it is the only
# way to attach an object to the ceiling (``--position`` leaves it floating, resting on what is below
# it).  The warning is for the usual mistake: a row counted in another image size (``--at 512,20``
# meant for a taller image lands near the zenith, where the equirect view stretches the object).
CEILING_COS = 0.5  # a support whose normal points down by more than this (within 60° of straight down)


def on_ceiling(support: tuple[np.ndarray, np.ndarray] | None) -> bool:
    """Whether an object's ``support`` (contact point, normal) faces down: a ceiling."""
    return support is not None and float(np.asarray(support[1])[1]) < -CEILING_COS


def ceiling_warning(option: str, height: int, frames: int = 1, of: int = 1) -> str:
    """A one-line warning that ``option`` put an object (``frames`` of ``of``) on the ceiling of a
    panorama ``height`` pixels high."""
    where = f"{frames} of {of} points are" if of > 1 else "the point is"
    return (f"{option}: {where} on the ceiling (a surface facing down): the object hangs from it upside "
            f"down, as a lamp would; to stand it on the floor give a point below the horizon (a row "
            f"over {height // 2} of {height}, or over 0.5 as a fraction)")
