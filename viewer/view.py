"""The two views as pure math (no GL): screen pixel <-> panorama coordinates.

A line-by-line mirror of ``shaders/view.glsl``; directions and panorama coordinates come from
``phyir.pano`` (the one equirect mapping).  Screen positions are framebuffer pixels measured from
the view rectangle's top-left corner; pixel centres sit at +0.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano

MIN_FOV, MAX_FOV = 10.0, 150.0        # perspective field of view limits, degrees
MIN_ZOOM, MAX_ZOOM = 1 / 64, 256.0    # equirect zoom limits, screen px per panorama px
MAX_PITCH = math.radians(89.0)


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
