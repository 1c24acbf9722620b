"""The view and the mouse (:class:`Camera`): equirect or perspective, fit and 1:1, and screen <->
panorama positions (framebuffer pixels relative to the view's top-left)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from phyir.errors import PhyIRError
from phyir.insert.views import EquirectView, PerspectiveView
from viewer.app.images import ImageList
from viewer.app.pins import Pins
from viewer.probes import Pin


class Camera:
    """Owns both views (``views``; ``view_kind`` says which one is shown), shared by all images;
    ``view_size()`` is the view's (w, h) in framebuffer pixels.  A click pins a probe (``pins``)."""

    def __init__(self, images: ImageList, pins: Pins, view_size: Callable[[], tuple[int, int]]):
        self.images = images
        self.pins = pins
        self.view_size = view_size
        self.views = {"equirect": EquirectView(), "perspective": PerspectiveView()}
        self.view_kind = "equirect"

    @property
    def view(self) -> EquirectView | PerspectiveView:
        return self.views[self.view_kind]

    @property
    def hover(self) -> tuple[float, float] | None:
        """The panorama (u, v) under the mouse, None when it is elsewhere."""
        return self.images.doc.hover

    def set_view(self, kind: str | None = None, **params) -> None:
        """Switch view ("equirect"/"perspective") and/or set its parameters (equirect: center, zoom;
        perspective: fov [deg], yaw, pitch [rad])."""
        if kind is not None:
            if kind not in self.views:
                raise PhyIRError(f"unknown view {kind!r} (choose from equirect, perspective)")
            self.view_kind = kind
        for k, val in params.items():
            if not hasattr(self.view, k):
                raise PhyIRError(f"view {self.view_kind} has no parameter {k!r}")
            setattr(self.view, k, val)

    def fit(self) -> None:
        size = self.images.doc.size
        if size is not None:
            self.views["equirect"].fit(self.view_size(), size)

    def one_to_one(self) -> None:
        self.views["equirect"].zoom_about(1.0 / self.views["equirect"].zoom, self.view_size())

    # -- mouse (positions in framebuffer pixels relative to the view's top-left) ---------------
    def screen_to_uv(self, x: float, y: float) -> tuple[float, float] | None:
        """Panorama coordinates under a view position, None outside the panorama."""
        size = self.images.doc.size
        if size is None:
            return None
        H, W = size
        u, v = self.view.screen_to_uv(np.float64(x), np.float64(y), self.view_size(), size)
        u, v = float(u), float(v)
        if not (0 <= v < H) or (self.view_kind == "equirect" and not 0 <= u < W):
            return None
        return u % W, v

    def drag(self, dx: float, dy: float) -> None:
        if self.view_kind == "equirect":
            self.view.drag(dx, dy)
        else:
            self.view.drag(dx, dy, self.view_size())

    def scroll(self, steps: float, x: float, y: float) -> None:
        if self.view_kind == "equirect":
            self.view.zoom_about(2 ** (steps / 4), self.view_size(), (x, y))
        else:
            self.view.zoom_fov(2 ** (-steps / 8))

    def click(self, x: float, y: float) -> Pin | None:
        uv = self.screen_to_uv(x, y)
        return None if uv is None else self.pins.pin_probe(*uv)

    def hover_at(self, x: float | None, y: float | None) -> None:
        self.images.doc.hover = None if x is None else self.screen_to_uv(x, y)
