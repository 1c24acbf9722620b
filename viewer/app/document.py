"""One open image's state (:class:`Document`): where it came from, its scene and layers (predicted
and true), its pinned probes, timings and the layers' textures, uploaded a few per frame."""

from __future__ import annotations

import os
import time

import moderngl
import numpy as np

from phyir.scene import PanoScene
from viewer.app.common import UPLOAD_BUDGET_S
from viewer.layers import LAYERS
from viewer.probes import Pin, pixel_values


def release_pin(pin: Pin) -> None:
    """Free the GL resources of a pin's probe images (GL current)."""
    for obj in pin.textures.values():
        if isinstance(obj, (moderngl.Texture, moderngl.Framebuffer)):
            obj.release()
    pin.textures.clear()


class Document:
    """An image's scene, layers, pins and textures.  ``arrays`` are the prediction's (or the file's)
    layers, ``gt_arrays`` the ground truth's; textures are keyed by ``(source, layer)`` with source
    "pred" or "gt", and ``texture_versions`` counts each one's uploads (the view's cache key)."""

    def __init__(self) -> None:
        self.path: str | None = None
        self.name = ""
        self.scene: PanoScene | None = None
        self.confidence: float | None = None  # geometry confidence of the scene (status bar)
        self.arrays: dict[str, np.ndarray] = {}
        self.gt: PanoScene | None = None
        self.gt_arrays: dict[str, np.ndarray] = {}
        self.show_gt = False
        self.pins: list[Pin] = []
        self.hover: tuple[float, float] | None = None  # panorama (u, v) under the mouse
        self.timings: dict[str, float] = {}
        self.layer_textures: dict[tuple[str, str], moderngl.Texture] = {}
        self.texture_versions: dict[tuple[str, str], int] = {}
        self.pending_uploads: list[tuple[str, str]] = []
        self.fit_pending = True  # the equirect view fits it once it has a size
        self.watch_stamp: tuple | None = None  # (mtime, size) of the file as loaded

    # -- what it shows --------------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int] | None:
        """(H, W) of the panorama."""
        return None if self.scene is None else self.scene.size

    @property
    def shown_source(self) -> str:
        """"gt" while the ground truth is shown, else "pred"."""
        return "gt" if self.show_gt and self.gt is not None else "pred"

    def arrays_of(self, source: str) -> dict[str, np.ndarray]:
        return self.gt_arrays if source == "gt" else self.arrays

    @property
    def shown_arrays(self) -> dict[str, np.ndarray]:
        return self.arrays_of(self.shown_source)

    def available(self, source: str | None = None) -> list[str]:
        """Layers present for ``source`` ("pred"/"gt"; default: the one shown), in display order."""
        arrays = self.arrays_of(source or self.shown_source)
        return [n for n in LAYERS if n in arrays]

    def values_at(self, u: float, v: float, source: str = "pred") -> dict[str, np.ndarray]:
        """Every layer's value at (u, v) (what the read-out shows)."""
        return pixel_values(self.arrays_of(source), u, v, self.size) if self.size else {}

    def file_stamp(self) -> tuple | None:
        """(mtime, size) of its file now; None without a file."""
        try:
            st = os.stat(self.path) if self.path else None
        except OSError:
            return None
        return None if st is None else (st.st_mtime_ns, st.st_size)

    # -- textures -------------------------------------------------------------------------------
    def queue_upload(self, source: str, arrays: dict[str, np.ndarray]) -> None:
        for name in arrays:
            key = (source, name)
            if key not in self.pending_uploads:
                self.pending_uploads.append(key)

    def upload_some(self, renderer, layer: str) -> bool:
        """Upload queued layers, the shown ``layer`` first, within a time budget per frame; True if
        any was uploaded."""
        if not self.pending_uploads:
            return False
        shown = ("gt" if self.show_gt else "pred", layer)
        self.pending_uploads.sort(key=lambda k: k != shown)
        t0 = time.perf_counter()
        pending = self.pending_uploads
        while pending and (time.perf_counter() - t0 < UPLOAD_BUDGET_S or pending[0] == shown):
            source, name = pending.pop(0)
            arrays = self.arrays_of(source)
            if name in arrays:
                self._upload(renderer, (source, name), arrays[name])
        return True

    def texture(self, renderer, layer: str):
        """The shown source's texture of ``layer`` and its upload count, uploaded here if it is new
        (a reference image is not the one shown, whose uploads ``upload_some`` spreads over frames)."""
        key = (self.shown_source, layer)
        if key not in self.layer_textures or key in self.pending_uploads:
            self._upload(renderer, key, self.shown_arrays[layer])
            if key in self.pending_uploads:
                self.pending_uploads.remove(key)
        return self.layer_textures[key], self.texture_versions[key]

    def _upload(self, renderer, key: tuple[str, str], array: np.ndarray) -> None:
        self.layer_textures[key] = renderer.texture(array, self.layer_textures.get(key))
        self.texture_versions[key] = self.texture_versions.get(key, 0) + 1

    def drop_texture(self, key: tuple[str, str]) -> None:
        tex = self.layer_textures.pop(key, None)
        if tex is not None:
            tex.release()

    # -- clearing (GL current) ------------------------------------------------------------------
    def clear(self) -> None:
        """Forget the scene, its layers and pins, freeing their GL resources (the file's name and
        path stay: a file being opened shows them)."""
        for tex in self.layer_textures.values():
            tex.release()
        self.layer_textures.clear()
        self.pending_uploads.clear()
        for pin in self.pins:
            release_pin(pin)
        self.pins.clear()
        self.scene, self.arrays, self.gt, self.gt_arrays = None, {}, None, {}
        self.show_gt = False
        self.hover = None
        self.timings = {}
        self.fit_pending = True
