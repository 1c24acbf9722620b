"""Views of a panorama and the files of an insertion render, without GL (``phyir insert`` and the
viewer's export button; the GL side is ``viewer/insertion.py``).

* :class:`EquirectView` / :class:`PerspectiveView` — the two views as pure maths: screen pixel <->
  panorama coordinates, a line-by-line mirror of ``shaders/view.glsl``; directions and panorama
  coordinates come from ``phyir.pano`` (the one equirect mapping).  Screen positions are
  framebuffer pixels measured from the view rectangle's top-left corner; pixel centres sit at +0.5.
  :func:`look_at` / :func:`perspective` / :func:`pixel_angle` — camera matrices and pixel footprint.
* :func:`load_insert_scene` — a scene file with probes is used as it is; anything else goes through
  the model (:func:`phyir.predict`) first.
* :func:`make_object` / :func:`place_object` / :func:`path_points` — the object and where it goes
  (``--at``/``--position``/``--path``); :class:`ViewSpec` — the view to render (``--view`` ...).
* :func:`write_passes` — linear EXR passes (``R,G,B`` composite, ``object.A`` alpha, ``shadow.Y``
  matte, ``object.R,G,B`` object-only) and a tonemapped PNG (:func:`tonemap`);
  :func:`write_animation` — numbered frames, an animated GIF preview and the frame-to-frame flicker
  on static background pixels (:func:`flicker`).

Nothing here imports GL, the viewer or its UI libraries.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from dataclasses import dataclass

import numpy as np
import torch

from phyir import color, pano
from phyir.errors import InputError, PhyIRError, shown
from phyir.insert import placement
from phyir.insert.objects import PRIMITIVES, SceneObject, object_mesh, parse_material
from phyir.scene import PanoScene

MIN_FOV, MAX_FOV = 10.0, 150.0        # perspective field of view limits, degrees
MIN_ZOOM, MAX_ZOOM = 1 / 64, 256.0    # equirect zoom limits, screen px per panorama px
MAX_PITCH = math.radians(89.0)
GIF_WIDTH = 512
PRIMITIVE_SCALE = 0.25                # default primitive size: radius / half-extent 25 cm
MIN_SCALE, MAX_SCALE = 1e-3, 100.0    # --scale: a 1 mm .. 100 m radius primitive
MAX_DISTANCE = 1000.0                 # m: an object placed farther is not in an indoor scene
# a render takes ~150 bytes per output pixel (three RGBA float32 targets, their read-back, the
# passes) over ~400 MB: peak 706 MB at 2048x1024, 1.0 GB at 2048x2048, 1.6 GB at 4096x2048
# (`phyir insert --view perspective --size ...`, llvmpipe).  Renders are refused beyond this many
# pixels, or the panorama's own when it has more (its equirect view at full resolution)
MAX_RENDER_PIXELS = 2048 * 2048
MAX_RENDER_SIDE = 8192                # and never more per side than GL's renderbuffer limit
LUMA = np.array(color.LUMA, np.float32)  # phyir.color.LUMA, for numpy images [..., 3]


# ---------------------------------------------------------------------------------------------
# views and cameras


@dataclass
class EquirectView:
    """The panorama as a flat image: ``center`` (u, v) shown at the view centre, ``zoom`` screen
    pixels per panorama pixel."""

    center: tuple[float, float] = (0.0, 0.0)
    zoom: float = 1.0
    kind: str = "equirect"

    def fit(self, view: tuple[float, float], size: tuple[int, int]) -> None:
        """Show the whole H x W panorama (``size``) in a view of ``view`` = (width, height) px."""
        H, W = size
        self.zoom = min(view[0] / W, view[1] / H)
        self.center = (W / 2, H / 2)

    def one_to_one(self, view: tuple[float, float], size: tuple[int, int],
                   at: tuple[float, float] | None = None) -> None:
        """One panorama pixel per screen pixel, keeping the point under screen position ``at``."""
        self.zoom_about(1.0 / self.zoom, view, at)

    def zoom_about(self, factor: float, view: tuple[float, float],
                   at: tuple[float, float] | None = None) -> None:
        """Multiply the zoom, keeping the panorama point under screen position ``at`` fixed."""
        at = (view[0] / 2, view[1] / 2) if at is None else at
        u, v = self.screen_to_uv(np.array(at[0]), np.array(at[1]), view)
        self.zoom = float(np.clip(self.zoom * factor, MIN_ZOOM, MAX_ZOOM))
        self.center = (float(u) - (at[0] - view[0] / 2) / self.zoom,
                       float(v) - (at[1] - view[1] / 2) / self.zoom)

    def drag(self, dx: float, dy: float) -> None:
        """Pan by a mouse movement of (dx, dy) screen pixels."""
        self.center = (self.center[0] - dx / self.zoom, self.center[1] - dy / self.zoom)

    def screen_to_uv(self, x: np.ndarray, y: np.ndarray, view: tuple[float, float],
                     size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Panorama coordinates under screen positions (x, y); may fall outside the panorama."""
        return (self.center[0] + (x - view[0] / 2) / self.zoom,
                self.center[1] + (y - view[1] / 2) / self.zoom)

    def uv_to_screen(self, u: np.ndarray, v: np.ndarray, view: tuple[float, float],
                     size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Screen positions of panorama coordinates, and whether each is in front (always)."""
        x = (u - self.center[0]) * self.zoom + view[0] / 2
        y = (v - self.center[1]) * self.zoom + view[1] / 2
        return x, y, np.ones(np.shape(x), bool)


@dataclass
class PerspectiveView:
    """A pinhole camera at the panorama centre: ``fov`` (vertical, degrees), ``yaw`` (toward +x) and
    ``pitch`` (up), radians; the same camera as ``phyir.pano.perspective_dirs``."""

    fov: float = 75.0
    yaw: float = 0.0
    pitch: float = 0.0
    kind: str = "perspective"

    def update(self, fov: float | None = None, yaw: float | None = None, pitch: float | None = None) -> None:
        """Set the given parameters (``fov`` in degrees, ``yaw`` and ``pitch`` in radians), keep the rest."""
        for name, value in (("fov", fov), ("yaw", yaw), ("pitch", pitch)):
            if value is not None:
                setattr(self, name, value)

    def rotation(self) -> np.ndarray:
        """Camera-to-world rotation (pano.perspective_dirs: yaw_matrix(-yaw) @ pitch matrix)."""
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        pitch_m = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
        return pano.yaw_matrix(-self.yaw, dtype=torch.float64).numpy() @ pitch_m

    def focal(self, view: tuple[float, float]) -> float:
        return 0.5 * view[1] / math.tan(math.radians(self.fov) / 2)

    def view_matrix(self) -> np.ndarray:
        """4x4 world-to-camera matrix (camera at the origin; OpenGL camera looks along -z)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation().T
        return m

    def projection_matrix(self, view: tuple[float, float], near: float = 0.05,
                          far: float = 100.0) -> np.ndarray:
        """4x4 OpenGL projection of this camera for a view of (width, height) pixels, so meshes
        rasterised with ``projection @ view_matrix`` line up with the panorama drawn by the shaders."""
        f = 2 * self.focal(view)
        w, h = view
        return np.array([[f / w, 0, 0, 0], [0, f / h, 0, 0],
                         [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                         [0, 0, -1, 0]])

    def drag(self, dx: float, dy: float, view: tuple[float, float]) -> None:
        """Turn so that the scene follows the mouse: (dx, dy) screen pixels."""
        f = self.focal(view)
        self.yaw -= math.atan2(dx, f)
        self.pitch = float(np.clip(self.pitch + math.atan2(dy, f), -MAX_PITCH, MAX_PITCH))

    def zoom_fov(self, factor: float) -> None:
        self.fov = float(np.clip(self.fov * factor, MIN_FOV, MAX_FOV))

    def screen_to_dir(self, x: np.ndarray, y: np.ndarray, view: tuple[float, float]) -> np.ndarray:
        f = self.focal(view)
        d = np.stack(np.broadcast_arrays((x - view[0] / 2) / f, (view[1] / 2 - y) / f, -1.0), -1)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return d @ self.rotation().T

    def screen_to_uv(self, x: np.ndarray, y: np.ndarray, view: tuple[float, float],
                     size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        d = torch.from_numpy(np.asarray(self.screen_to_dir(x, y, view), np.float64))
        u, v = pano.dir_to_uv(d, *size, dim=-1)
        return u.numpy(), v.numpy()

    def uv_to_screen(self, u: np.ndarray, v: np.ndarray, view: tuple[float, float],
                     size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Screen positions of panorama coordinates and whether each lies in front of the camera."""
        d = pano.uv_to_dir(torch.as_tensor(u, dtype=torch.float64),
                           torch.as_tensor(v, dtype=torch.float64), *size, dim=-1).numpy()
        c = d @ self.rotation()  # world -> camera (rotation is orthonormal)
        front = c[..., 2] < -1e-6
        z = np.where(front, -c[..., 2], 1.0)
        f = self.focal(view)
        return view[0] / 2 + f * c[..., 0] / z, view[1] / 2 - f * c[..., 1] / z, front


View = EquirectView | PerspectiveView


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 world-to-camera matrix of a camera at ``eye`` looking at ``target`` (OpenGL: along -z;
    numpy row-major, transposed when written to GLSL's column-major uniforms)."""
    f = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    f /= np.linalg.norm(f)
    up = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, np.float64)
    return m


def perspective(tan_half: float, near: float, far: float) -> np.ndarray:
    """4x4 OpenGL projection of a square frustum with ``tan_half`` the tangent of its half angle."""
    return np.array([[1 / tan_half, 0, 0, 0], [0, 1 / tan_half, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])


def pixel_angle(view: EquirectView | PerspectiveView, view_size: tuple[int, int],
                pano_size: tuple[int, int]) -> float:
    """Radians per screen pixel at the view's centre."""
    if isinstance(view, PerspectiveView):
        return 2 * math.tan(math.radians(view.fov) / 2) / view_size[1]
    return (2 * math.pi / pano_size[1]) / view.zoom


# ---------------------------------------------------------------------------------------------
# the scene, the object and the view of a render


def require_depth(scene: PanoScene, path: str | os.PathLike) -> None:
    """[issue 22, class 5] A depth layer that is 0 everywhere (as stored, or after the loader
    repaired negative / NaN values) holds no room: nothing can be placed in it or exported."""
    if scene.depth is not None and not bool((scene.depth > 0).any()):
        raise InputError(path, "the depth layer is 0 everywhere (or was negative / NaN): the scene holds "
                               "no room geometry")


def load_insert_scene(path: str, *, weights: str | None = None, log=print) -> PanoScene:
    """The scene to insert into: its own layers if it has depth and probes, else the model's
    (``weights``: a weights file for :func:`phyir.predict`, default the shipped ones)."""
    from phyir.io import load_scene

    scene = load_scene(path)
    require_depth(scene, path)
    if scene.depth is not None and scene.probes is not None:
        return scene
    missing = [n for n in ("depth", "probes") if getattr(scene, n) is None]
    log(f"{shown(path)}: no {' or '.join(missing)}: predicting the layers with the model (phyir.predict)")
    from phyir import predict

    try:
        return predict(scene, weights=weights)
    except InputError as e:  # [issue 22, class 9] the scene's own problem (e.g. too small): name its file
        if e.path is not None:
            raise
        raise InputError(path, e.problem) from None


def make_object(spec: str, scale: float | None, material: str) -> SceneObject:
    """The object ``--object``/``--scale``/``--material`` describe; ``scale`` None: primitives get
    :data:`PRIMITIVE_SCALE` (a 25 cm radius / half-extent), meshes keep their own units (1)."""
    mesh = object_mesh(spec)
    if scale is None:
        scale = PRIMITIVE_SCALE if spec in PRIMITIVES else 1.0
    if not (math.isfinite(scale) and MIN_SCALE <= scale <= MAX_SCALE):
        raise InputError("--scale", f"expected a number in {MIN_SCALE:g}..{MAX_SCALE:g}, got {scale!r}")
    return SceneObject(mesh, parse_material(material), scale=scale)


def place_object(obj: SceneObject, scene: PanoScene, *, at: tuple[float, float] | None = None,
                 position: tuple[float, float, float] | None = None, normal: torch.Tensor | None = None,
                 log=print) -> None:
    """``at``: pixel (column, row) whose surface the object stands on; ``position``: world centre."""
    H, W = scene.size
    if at is not None:
        u, v = at
        if not (0 <= u < W and 0 <= v < H):
            raise InputError("--at", f"pixel ({u:g}, {v:g}) is outside the {W}x{H} panorama")
        pl = placement.drop(scene, u + 0.5, v + 0.5, obj.base_offset(), normal=normal)
        # the footprint's centre (not the local origin, which a mesh may have far from its
        # geometry) stands on the point: shift by the bounding centre's local x, z
        c = obj.mesh.bounding_sphere()[0] * obj.scale
        pl.position = pl.position - pl.rotation @ np.array([c[0], 0.0, c[2]])
        far = float(np.linalg.norm(pl.contact))
        if not far <= MAX_DISTANCE:  # e.g. a depth layer that is not in metres (1e30 everywhere)
            raise InputError("--at", f"the surface at pixel ({u:g}, {v:g}) is {far:.3g} m from the camera "
                                     f"(more than {MAX_DISTANCE:g} m): the scene's depth is not an "
                                     "indoor room in metres")
    elif position is not None:
        centre_local = obj.rotation @ (obj.mesh.bounding_sphere()[0] * obj.scale)
        pl, free = placement.place_at_position(scene, np.asarray(position, np.float64), centre_local,
                                               obj.rotation)
        if not free:
            log(f"warning: the object's centre {tuple(position)} is behind the scene surface: "
                "it will be hidden")
    else:
        raise PhyIRError("give --at U,V, --position X,Y,Z or --path")
    obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)


def path_points(waypoints: list[tuple[float, float]], frames: int, W: int,
                H: int | None = None) -> list[tuple[float, float]]:
    """``frames`` pixel positions (as ``--at`` takes them: column in [0, W), row in [0, H)) evenly
    spaced along a polyline, the shortest way round the seam; waypoints outside the panorama
    (``H`` given) are refused as ``--path``."""
    if len(waypoints) < 2 or frames < 2:
        raise InputError("--path", "expected at least two points U1,V1:U2,V2 and --frames >= 2")
    for u, v in waypoints:
        if not (0 <= u < W and (H is None or 0 <= v < H)):
            raise InputError("--path", f"point ({u:g}, {v:g}) is outside the {W}x{H or '?'} panorama")
    segs = []
    for (u0, v0), (u1, v1) in zip(waypoints, waypoints[1:]):
        du = (u1 - u0 + W / 2) % W - W / 2
        segs.append((u0, v0, du, v1 - v0, math.hypot(du, v1 - v0)))
    total = sum(s[4] for s in segs) or 1.0
    out = []
    for i in range(frames):
        s = total * i / (frames - 1)
        for u0, v0, du, dv, length in segs:
            if s <= length or (u0, v0, du, dv, length) == segs[-1]:
                t = min(s / length, 1.0) if length > 0 else 0.0
                u = (u0 + t * du) % W
                out.append((u if u < W else 0.0, v0 + t * dv))  # (-1e-20 % W is W)
                break
            s -= length
    return out


@dataclass
class ViewSpec:
    kind: str = "equirect"  # or "perspective"
    size: tuple[int, int] | None = None  # (width, height); equirect default: the panorama's
    fov: float = 60.0
    yaw: float | None = None  # degrees; default: toward the first object
    pitch: float | None = None

    def build(self, scene: PanoScene, target: np.ndarray | None) -> tuple[EquirectView | PerspectiveView,
                                                                           tuple[int, int]]:
        H, W = scene.size
        if self.kind == "equirect":
            size = self.size or (W, H)
            return EquirectView(center=(W / 2, H / 2), zoom=size[0] / W), size
        if self.kind != "perspective":
            raise InputError("--view", f"expected equirect or perspective, got {self.kind!r}")
        if not MIN_FOV <= self.fov <= MAX_FOV:  # (also False for NaN)
            raise InputError("--fov", f"expected {MIN_FOV:g}..{MAX_FOV:g} degrees, got {self.fov!r}")
        for name in ("yaw", "pitch"):
            if getattr(self, name) is not None and not math.isfinite(getattr(self, name)):
                raise InputError(f"--{name}", f"expected a finite angle, got {getattr(self, name)!r}")
        yaw, pitch = self.yaw, self.pitch
        if target is not None:
            lon, lat = pano.dir_to_lonlat(torch.as_tensor(target, dtype=torch.float64))
            yaw = math.degrees(float(lon)) if yaw is None else yaw
            pitch = math.degrees(float(lat)) if pitch is None else pitch
        return (PerspectiveView(fov=self.fov, yaw=math.radians(yaw or 0.0), pitch=math.radians(pitch or 0.0)),
                self.size or (960, 720))


def check_render_size(size: tuple[int, int], max_side: int = MAX_RENDER_SIDE,
                      pano_size: tuple[int, int] | None = None) -> None:
    """Refuse a render of ``size`` = (width, height) beyond ``max_side`` (GL's maximum renderbuffer
    size where known, at most :data:`MAX_RENDER_SIDE`) or :data:`MAX_RENDER_PIXELS` (or the pixels
    of the panorama, ``pano_size`` = (H, W), when it has more) before any GL object is made."""
    w, h = size
    side = min(max_side, MAX_RENDER_SIDE)
    pixels = max(MAX_RENDER_PIXELS, pano_size[0] * pano_size[1] if pano_size else 0)
    if max(w, h) > side or w * h > pixels:
        raise InputError("--size", f"a {w}x{h} render is too large (at most {side} pixels per side and "
                                   f"{pixels:,} pixels, e.g. 2048x2048 or 2896x1448); pass a smaller --size")


# ---------------------------------------------------------------------------------------------
# output files


def tonemap(rgb: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """uint8 sRGB of linear ``rgb [h,w,3]``: ``2^exposure`` x ACES (Narkowicz fit, as the viewer's
    colour.glsl); ``exposure`` None: the median luminance maps to 0.18."""
    if exposure is not None and not math.isfinite(exposure):  # 2^nan: a black (or white) image
        raise InputError("--exposure", f"expected a finite EV, got {exposure!r}")
    x = np.maximum(rgb, 0)
    if exposure is None:
        lum = x @ LUMA
        med = float(np.median(lum[lum > 0])) if (lum > 0).any() else 1.0
        k = 0.18 / max(med, 1e-12)
    else:
        k = 2.0 ** exposure
    return np.round(color.linear_to_srgb(color.aces(x * k)) * 255).astype(np.uint8)


def write_passes(out: dict[str, np.ndarray], path: str, exposure: float | None,
                 meta: dict | None = None, files=None) -> list[str]:
    """``.exr``: the passes (and a PNG next to it); ``.png``: the tonemapped composite.  Written as one
    atomic set (:class:`phyir.io.AtomicSet`; ``files``: a caller's set to add them to instead)."""
    from PIL import Image

    from phyir.io import AtomicSet, exr

    stem, ext = os.path.splitext(path)
    ext = ext.lower()
    if ext not in (".exr", ".png"):
        raise InputError(path, "the output must be .exr (passes + PNG) or .png")
    png = stem + ".png"
    with contextlib.nullcontext(files) if files is not None else AtomicSet() as out_files:
        if ext == ".exr":
            c, o = out["composite"], out["object"]
            chans = {"R": c[..., 0], "G": c[..., 1], "B": c[..., 2], "object.A": out["alpha"],
                     "shadow.Y": out["shadow"], **{f"object.{k}": o[..., i] for i, k in enumerate("RGB")}}
            attrs = {f"phyir.{k}": str(v) for k, v in (meta or {}).items()}
            exr_tmp, png_tmp = out_files.add(path), out_files.add(png)
            exr.write_parts(exr_tmp, [("insert", attrs, {k: np.ascontiguousarray(v, np.float32)
                                                         for k, v in chans.items()})])
        else:
            png_tmp = out_files.add(png)
        Image.fromarray(tonemap(out["composite"], exposure), "RGB").save(png_tmp, format="PNG")
    return [path, png] if ext == ".exr" else [png]


class Flicker:
    """:func:`flicker` one frame at a time (:meth:`add`), holding only the previous frame, so an
    animation of any length is measured while its frames are written."""

    def __init__(self):
        self.prev: dict[str, np.ndarray] | None = None
        self.diffs: list[float] = []
        self.means: list[float] = []

    def add(self, b: dict[str, np.ndarray]) -> None:
        a = self.prev
        if a is not None:
            static = ((a["alpha"] == 0) & (b["alpha"] == 0) & (a["shadow_delta"] == 0)
                      & (b["shadow_delta"] == 0))
            if static.any():
                la, lb = a["composite"][static] @ LUMA, b["composite"][static] @ LUMA
                self.diffs.append(float(np.abs(la - lb).mean() / max(float(la.mean()), 1e-12)))
        self.means.append(float((b["object"] @ LUMA).sum() / max(float(b["alpha"].sum()), 1e-12)))
        self.prev = b

    def result(self) -> dict[str, float]:
        return _flicker_stats(self.diffs, self.means)


def flicker(frames) -> dict[str, float]:
    """Frame-to-frame change on static background pixels (neither object nor shadow in either
    frame), relative to their mean luminance, and the relative jitter of the object's mean radiance
    (its second difference along the path: a smooth change of lighting scores ~0)."""
    acc = Flicker()
    for f in frames:
        acc.add(f)
    return acc.result()


def _flicker_stats(diffs: list[float], means: list[float]) -> dict[str, float]:
    m = np.asarray(means)
    scale = max(float(m.mean()), 1e-12)
    jitter = float(np.abs(m[2:] - 2 * m[1:-1] + m[:-2]).max()) / scale if len(m) > 2 else 0.0
    step = float(np.abs(np.diff(m)).max()) / scale if len(m) > 1 else 0.0
    return {"static_background_change": max(diffs) if diffs else 0.0, "object_step": step,
            "object_jitter": jitter}


def write_animation(frames, path: str, exposure: float | None) -> dict:
    """Numbered frames ``<stem>_0000<ext>`` (passes as :func:`write_passes`), ``<stem>.gif`` and
    ``<stem>_flicker.json``; one exposure for all frames (the first frame's when automatic).
    ``frames``: any iterable (e.g. a generator rendering them): each frame is written and measured
    as it comes, only the GIF's thumbnails and the previous frame stay in memory."""
    from PIL import Image

    from phyir.io import AtomicSet

    stem, ext = os.path.splitext(path)
    images = []
    stats_acc = Flicker()
    # [issue 22, class 4] every frame, the GIF and the stats are one atomic set: an interrupted run
    # leaves the previous animation whole (the frames wait as hidden temporaries until the end)
    with AtomicSet() as out_files:
        for i, f in enumerate(frames):
            if exposure is None:  # the first frame's
                lum = f["composite"] @ LUMA
                med = float(np.median(lum[lum > 0])) if (lum > 0).any() else 1.0
                exposure = math.log2(0.18 / max(med, 1e-12))
            stats_acc.add(f)
            write_passes(f, f"{stem}_{i:04d}{ext}", exposure, files=out_files)
            im = Image.fromarray(tonemap(f["composite"], exposure), "RGB")
            if im.width > GIF_WIDTH:
                im = im.resize((GIF_WIDTH, round(im.height * GIF_WIDTH / im.width)), Image.BILINEAR)
            images.append(im.convert("P", palette=Image.Palette.ADAPTIVE))  # what GIF stores; 1/3 the memory
        images[0].save(out_files.add(stem + ".gif"), format="GIF", save_all=True, append_images=images[1:],
                       duration=80, loop=0)
        stats = stats_acc.result()
        with open(out_files.add(stem + "_flicker.json"), "w") as fh:
            json.dump({"frames": len(images), **stats}, fh, indent=2)
    return stats
