"""``phyir-view``: the interactive panorama inspector.

:class:`App` holds the viewer's state and is what the UI, the command line and the tests drive: the
imgui panels (``viewer/gui.py``) call the same methods a script does (``open``, ``set_layer``,
``pin_probe``, ``set_view``, ...), then ``frame()`` draws and ``screenshot()`` reads the result.
All GL work happens on the thread that created the App; loading, inference and re-rendering run in
``viewer.worker``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import gc
import math
import os

# Idle OpenMP threads sleep instead of spinning (set before torch loads, as phyir.cli does): a
# spinning inference thread would take the UI thread's core on a small CPU.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import numpy as np

from phyir.errors import PhyIRError
from phyir.scene import PanoScene
from viewer import window as surfaces
from viewer.layers import LAYERS, SPECS, auto_range
from viewer.probes import Pin, make_pin, pixel_values, update_pin
from viewer.recent import RecentFiles
from viewer.renderer import COLORMAPS, TONEMAPS, Display, Frame, Marker, Renderer
from viewer.view import EquirectView, PerspectiveView
from viewer.worker import Loaded, Worker, preload

UPLOAD_BUDGET_S = 0.004  # texture uploads per frame (seconds; at least one) so arriving layers don't stall
NEAREST_ZOOM = 1.0       # equirect zoom above which pixels are drawn as squares (nearest)
# GIL switch interval while an App lives (see App.__init__): 0.5 ms left frames of 135-192 ms while
# loading (imgui's draw waits once per GL call), 0.1 ms 34-65 ms (headless, quiet machine)
SWITCH_INTERVAL_S = 0.0001
BACKGROUND = (0.11, 0.11, 0.12)


def _gl(method):
    """Run an App method with the App's GL and imgui contexts current (several Apps may coexist)."""
    @functools.wraps(method)
    def wrapper(self, *args, **kw):
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
            return method(self, *args, **kw)
    return wrapper


@dataclass
class Message:
    level: str  # info | warning | error
    text: str
    time: float = field(default_factory=time.monotonic)


@dataclass
class ScalarDisplay:
    colormap: str
    range: tuple[float, float]
    auto: bool = True  # range follows the data when new layers arrive


class App:
    """The viewer.  ``headless=True`` renders through a standalone EGL context (no window/input);
    ``ui=False`` draws only the view (no imgui).  ``predict``/``render`` replace ``phyir.predict``
    and ``phyir.shading.render.render_scene`` (tests); ``recent=False`` disables the recent-files list."""

    def __init__(self, size: tuple[int, int] = (1400, 820), *, headless: bool = False, ui: bool = True,
                 scale: float = 1.0, title: str = "phyir-view", visible: bool = True, predict=None,
                 render=None, threads: int | None = None, recent: RecentFiles | bool | None = None,
                 run_model: bool = True, weights: str | os.PathLike | None = None,
                 device: str | None = None):
        if headless:
            surfaces.prefer_egl()
            self.surface: surfaces.Headless | surfaces.Window = surfaces.Headless(size, scale)
        else:
            self.surface = surfaces.Window(size, title, visible)
        self.ctx: moderngl.Context = self.surface.ctx
        # The UI thread drops the GIL in every GLFW/PyOpenGL call; while the worker runs Python,
        # retaking it waits up to the switch interval (5 ms by default), dozens of times a frame.
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self.renderer = Renderer(self.ctx)
        with self.surface.current():
            self.renderer.warm_up(self.surface.target())
        self.title = title
        self.last_capture: np.ndarray | None = None
        model_kw = {k: v for k, v in (("weights", weights), ("device", device)) if v is not None}
        preload()  # what jobs would import in the worker, holding the GIL the UI needs
        self.worker = Worker(wake=getattr(self.surface, "wake", None), predict=predict, render=render,
                             threads=threads, predict_kwargs=model_kw)
        self.run_model = run_model
        self.recent = (RecentFiles() if recent is None or recent is True else recent) or None
        # what is shown
        self.path: str | None = None
        self.name = ""
        self.scene: PanoScene | None = None
        self.arrays: dict[str, np.ndarray] = {}
        self.gt: PanoScene | None = None
        self.gt_arrays: dict[str, np.ndarray] = {}
        self.show_gt = False
        self.layer = "image"
        self.hdr = Display()
        self.scalar = {n: ScalarDisplay(s.colormap, s.range or (0.0, 1.0), s.range is None)
                       for n, s in SPECS.items() if s.kind == "scalar"}
        self.views = {"equirect": EquirectView(), "perspective": PerspectiveView()}
        self.view_kind = "equirect"
        self.pins: list[Pin] = []
        self.hover: tuple[float, float] | None = None  # panorama (u, v) under the mouse
        # status
        self.messages: deque[Message] = deque(maxlen=50)
        self.error: str | None = None  # shown in a banner until dismissed or the next file opens
        self.progress: tuple[float | None, str] | None = None
        self.busy = False
        self.timings: dict[str, float] = {}
        self.frame_times: deque[float] = deque(maxlen=240)
        self.job_max_frame = 0.0  # longest frame while the current job ran (s)
        self.job_max_parts: dict[str, tuple[float, float]] = {}  # that frame's parts: (wall, CPU) s
        self.job_frames = 0
        self.frame_parts: dict[str, tuple[float, float]] = {}  # the last frame's parts
        self.sync_parts = False  # wait for the GL after each part, so GL time lands in its part
        # GL resources
        self._textures: dict[tuple[str, str], moderngl.Texture] = {}
        self._tex_version: dict[tuple[str, str], int] = {}  # uploads per texture: in the view's cache key
        self._pending: list[tuple[str, str]] = []
        self._fit_pending = True
        self._redraw = 2
        self._last_uploaded = False
        from viewer.objects_panel import ObjectsPanel  # inserted objects (issue 8): an overlay pass

        with self.surface.current():
            self.objects = ObjectsPanel(self)
        self.gui = None
        if ui:
            from viewer.gui import Gui

            with self.surface.current():
                self.gui = Gui(self)
        if self.window is not None:
            self.surface.on_drop(self.on_drop)
        self.frame()  # the first frame compiles imgui's shaders: before any file is opened
        # Move everything allocated so far (torch, the model's modules, imgui: ~240k objects) out of
        # the cyclic collector's reach: a full collection holds the GIL while it scans them, and one
        # triggered by the worker's allocations stopped the UI for 360 ms at load 10.
        gc.collect()
        gc.freeze()

    def on_drop(self, paths: list[str]) -> None:
        """Files dropped on the window: open the first."""
        if paths:
            self.open(paths[0])
            self.request_redraw()

    # -- properties ---------------------------------------------------------------------------
    @property
    def window(self):
        return self.surface.window

    @property
    def view(self) -> EquirectView | PerspectiveView:
        return self.views[self.view_kind]

    @property
    def size(self) -> tuple[int, int] | None:
        """(H, W) of the open panorama."""
        return None if self.scene is None else self.scene.size

    @property
    def shown_arrays(self) -> dict[str, np.ndarray]:
        return self.gt_arrays if self.show_gt and self.gt is not None else self.arrays

    def available(self, source: str | None = None) -> list[str]:
        """Layers present for ``source`` ("pred"/"gt"; default: the one shown), in display order."""
        src = source or ("gt" if self.show_gt and self.gt is not None else "pred")
        arrays = self.gt_arrays if src == "gt" else self.arrays
        return [n for n in LAYERS if n in arrays]

    def view_rect(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the view in framebuffer pixels (y from the top)."""
        fw, fh = self.surface.framebuffer_size
        if self.gui is None:
            return 0, 0, fw, fh
        return self.gui.view_rect(fw, fh)

    def view_size(self) -> tuple[int, int]:
        return self.view_rect()[2:]

    # -- opening ------------------------------------------------------------------------------
    @_gl
    def open(self, source: str | os.PathLike | PanoScene, *, gt: PanoScene | None = None,
             name: str | None = None, compare: bool | None = None) -> None:
        """Open a panorama/scene file or a PanoScene; cancels a running job.  The file is read in the
        worker; its layers appear when read, the model's when computed.  ``gt``: a ground-truth
        scene to compare with; ``compare``: treat the file's own layers as ground truth and predict
        all layers (default: only for complete synthetic scenes)."""
        self.worker.cancel()
        self._clear()
        self.error = None
        if isinstance(source, PanoScene):
            self.name = name or source.meta.get("name", "scene")
            self.path = None
        else:
            self.path = os.fspath(source)
            self.name = name or Path(self.path).name
        if gt is not None:
            self._set_gt(gt.detach().cpu().float() if not gt.batched else gt[0])
        self.progress = (None, f"opening {self.name}")
        self.busy = True
        self.job_max_frame, self.job_frames, self.job_max_parts = 0.0, 0, {}
        self._job_start = time.perf_counter()
        self.worker.start(source, name=name, compare=compare, run_model=self.run_model)
        self._title()

    def _clear(self) -> None:
        for tex in self._textures.values():
            tex.release()
        self._textures.clear()
        self._pending.clear()
        for pin in self.pins:
            self._release_pin(pin)
        self.pins.clear()
        self.scene, self.arrays, self.gt, self.gt_arrays = None, {}, None, {}
        self.show_gt = False
        self.hover = None
        self.timings = {}
        self._fit_pending = True

    def _set_gt(self, gt: PanoScene, arrays: dict[str, np.ndarray] | None = None) -> None:
        """Ground truth: a scene given to ``open`` (arrays made here) or the file's layers in compare
        mode (arrays made, and their ranges applied, when the file loaded)."""
        from viewer.layers import auto_ranges, scene_arrays

        if arrays is None:
            arrays = scene_arrays(gt)
            self.gt = None  # so that its ranges apply
            self._auto_ranges(auto_ranges(arrays))
        self.gt, self.gt_arrays = gt, dict(arrays)
        self._queue_upload("gt", self.gt_arrays)

    def cancel(self) -> None:
        """Stop the running job (keeps the layers that arrived)."""
        if self.busy:
            self.worker.cancel()
            self.busy = False
            self.progress = None
            self.note("info", "cancelled")

    def note(self, level: str, text: str) -> None:
        self.messages.append(Message(level, text))
        if level == "error":
            self.error = text
        self._redraw = max(self._redraw, 2)

    # -- worker results -----------------------------------------------------------------------
    def poll(self) -> bool:
        """Apply the worker's updates; True if anything changed."""
        ups = self.worker.poll()
        for u in ups:
            getattr(self, "_on_" + u.kind.replace("-", "_"))(u.payload)
        return bool(ups)

    def _on_loaded(self, loaded: Loaded) -> None:
        self.scene = loaded.scene
        self.path, self.name = loaded.path, loaded.name
        self.arrays = dict(loaded.arrays)
        self._queue_upload("pred", loaded.arrays)
        self._auto_ranges(loaded.ranges)
        for text in loaded.notes:
            self.note("warning", text)
        H, W = self.scene.size
        self.note("info", f"opened {loaded.name} ({W}x{H}; layers: {', '.join(loaded.arrays)})")
        self.timings["load"] = time.perf_counter() - self._job_start
        if self.recent is not None and loaded.path is not None:
            self.recent.add(loaded.path)
        self._refresh_pins()
        self._title()

    def _on_progress(self, payload) -> None:
        frac, text = payload
        old = self.progress or (None, "")
        self.progress = (frac if frac is not None else old[0], text or old[1])

    def _on_layers(self, payload) -> None:
        scene, arrays, ranges, seconds = payload
        self.scene = scene
        self.arrays.update(arrays)
        self._queue_upload("pred", arrays)
        self._auto_ranges(ranges)
        self.timings["model"] = seconds
        extra = " (G: prediction / ground truth)" if self.gt is not None else ""
        self.note("info", f"model: {', '.join(arrays)} in {seconds:.1f} s{extra}")
        self._refresh_pins()

    def _on_gt(self, payload) -> None:
        gt, arrays = payload
        # the file's layers are the ground truth now; the prediction starts from the image only
        for name in list(self.arrays):
            if name != "image":
                del self.arrays[name]
                tex = self._textures.pop(("pred", name), None)
                if tex is not None:
                    tex.release()
        self.scene = PanoScene(image=gt.image, meta=dict(gt.meta))
        self._set_gt(gt, arrays)
        self.show_gt = True  # the file's layers, at once; G switches to the prediction when it is in
        self.note("info", "the file's layers are ground truth: predicting all layers to compare (G switches)")
        self._refresh_pins()

    def _on_rendered(self, payload) -> None:
        arrays, self.timings["render"] = payload
        self.arrays.update(arrays)
        self._queue_upload("pred", arrays)

    def _on_gt_rendered(self, payload) -> None:
        arrays, self.timings["render_gt"] = payload
        self.gt_arrays.update(arrays)
        self._queue_upload("gt", arrays)

    def _on_note(self, text: str) -> None:
        self.note("info", text)

    def _on_error(self, payload) -> None:
        stage, text = payload
        self.note("error", text if stage == "loading" else f"{stage} failed: {text}")
        self.busy, self.progress = False, None
        self.timings["job"] = time.perf_counter() - self._job_start

    def _on_done(self, _payload) -> None:
        self.busy, self.progress = False, None
        self.timings["job"] = time.perf_counter() - self._job_start
        self._refresh_pins()

    def _auto_ranges(self, ranges: dict[str, tuple[float, float]]) -> None:
        """Automatic colour-map ranges; with ground truth its ranges rule, so G compares like with like."""
        for name, r in ranges.items():
            if self.scalar[name].auto and not (self.gt is not None and name in self.gt_arrays):
                self.scalar[name].range = r

    # -- textures -----------------------------------------------------------------------------
    def _queue_upload(self, source: str, arrays: dict[str, np.ndarray]) -> None:
        for name in arrays:
            key = (source, name)
            if key not in self._pending:
                self._pending.append(key)

    def _upload_some(self) -> bool:
        """Upload queued layers, the shown one first, within a time budget per frame; True if any
        was uploaded."""
        if not self._pending:
            return False
        shown = ("gt" if self.show_gt else "pred", self.layer)
        self._pending.sort(key=lambda k: k != shown)
        t0 = time.perf_counter()
        while self._pending and (time.perf_counter() - t0 < UPLOAD_BUDGET_S or self._pending[0] == shown):
            source, name = self._pending.pop(0)
            arrays = self.gt_arrays if source == "gt" else self.arrays
            if name in arrays:
                key = (source, name)
                self._textures[key] = self.renderer.texture(arrays[name], self._textures.get(key))
                self._tex_version[key] = self._tex_version.get(key, 0) + 1
        return True

    # -- state changes (what clicks and keys call) --------------------------------------------
    def set_layer(self, name: str) -> None:
        if name not in LAYERS:
            raise PhyIRError(f"unknown layer {name!r} (choose from {', '.join(LAYERS)})")
        self.layer = name
        self._redraw = max(self._redraw, 2)

    def set_source(self, gt: bool) -> None:
        """Show the ground truth (True) or the prediction/file layers (False)."""
        self.show_gt = bool(gt) and self.gt is not None

    def display(self, layer: str | None = None) -> Display:
        """The display settings the given (default: shown) layer is drawn with."""
        spec = SPECS[layer or self.layer]
        if spec.kind == "scalar":
            sd = self.scalar[spec.name]
            return Display(kind="scalar", colormap=sd.colormap, range=sd.range)
        if spec.kind == "hdr":
            return Display(kind="hdr", tonemap=self.hdr.tonemap, exposure=self.hdr.exposure,
                           offset=self.hdr.offset, false_range=self.hdr.false_range)
        return Display(kind=spec.kind)

    def set_exposure(self, ev: float) -> None:
        self.hdr.exposure = float(ev)
        self._dirty_pins()

    def set_offset(self, offset: float) -> None:
        self.hdr.offset = float(offset)

    def set_tonemap(self, name: str) -> None:
        if name not in TONEMAPS:
            raise PhyIRError(f"unknown tone map {name!r} (choose from {', '.join(TONEMAPS)})")
        self.hdr.tonemap = name
        self._dirty_pins()

    def _scalar(self, layer: str | None) -> ScalarDisplay:
        name = layer or self.layer
        if name not in self.scalar:
            raise PhyIRError(f"layer {name!r} is not shown through a colour map "
                             f"(those are: {', '.join(self.scalar)})")
        return self.scalar[name]

    def set_colormap(self, name: str, layer: str | None = None) -> None:
        if name not in COLORMAPS:
            raise PhyIRError(f"unknown colour map {name!r} (choose from {', '.join(COLORMAPS)})")
        self._scalar(layer).colormap = name

    def set_range(self, lo: float | None, hi: float | None = None, layer: str | None = None) -> None:
        """Colour-map range of a scalar layer; ``lo=None`` returns to the automatic range."""
        name = layer or self.layer
        sd = self._scalar(name)
        if lo is None:
            sd.auto = SPECS[name].range is None
            arrays = self.shown_arrays
            fixed = SPECS[name].range or (0.0, 1.0)
            sd.range = auto_range(arrays[name]) if sd.auto and name in arrays else fixed
        else:
            sd.auto, sd.range = False, (float(lo), float(hi))

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
        if self.size is not None:
            self.views["equirect"].fit(self.view_size(), self.size)

    def one_to_one(self) -> None:
        self.views["equirect"].zoom_about(1.0 / self.views["equirect"].zoom, self.view_size())

    # -- mouse (positions in framebuffer pixels relative to the view's top-left) ---------------
    def screen_to_uv(self, x: float, y: float) -> tuple[float, float] | None:
        """Panorama coordinates under a view position, None outside the panorama."""
        if self.size is None:
            return None
        H, W = self.size
        u, v = self.view.screen_to_uv(np.float64(x), np.float64(y), self.view_size(), self.size)
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
        return None if uv is None else self.pin_probe(*uv)

    def hover_at(self, x: float | None, y: float | None) -> None:
        self.hover = None if x is None else self.screen_to_uv(x, y)

    # -- probes -------------------------------------------------------------------------------
    def pin_probe(self, u: float, v: float) -> Pin:
        """Pin the probe at panorama coordinates (u, v) (column, row; pixel centres at +0.5)."""
        if self.scene is None:
            raise PhyIRError("no panorama is open")
        pin = make_pin(u, v, len(self.pins), self.scene, self.arrays, self.gt, self.hdr.exposure)
        self.pins.append(pin)
        if self.gui is not None:
            self.gui.scroll_to_pin = len(self.pins) - 1
        return pin

    @_gl
    def unpin(self, index: int = -1) -> None:
        if self.pins:
            self._release_pin(self.pins.pop(index))

    def set_pin_exposure(self, index: int, ev: float) -> None:
        self.pins[index].exposure = float(ev)
        self.pins[index].textures["stale"] = {"pred", "gt"}

    def pin_values(self, u: float, v: float, source: str = "pred") -> dict[str, np.ndarray]:
        """Every layer's value at (u, v) (what the read-out shows)."""
        arrays = self.gt_arrays if source == "gt" else self.arrays
        return pixel_values(arrays, u, v, self.size) if self.size else {}

    def _refresh_pins(self) -> None:
        for pin in self.pins:
            update_pin(pin, self.scene, self.arrays, self.gt)
            pin.textures["stale"] = {"pred", "gt"}

    def _dirty_pins(self) -> None:
        for pin in self.pins:
            pin.textures["stale"] = {"pred", "gt"}

    def _release_pin(self, pin: Pin) -> None:
        for obj in pin.textures.values():
            if isinstance(obj, (moderngl.Texture, moderngl.Framebuffer)):
                obj.release()
        pin.textures.clear()

    def probe_image(self, pin: Pin, which: str, size: tuple[int, int]) -> moderngl.Texture | None:
        """The pin's probe ("pred" or "gt") drawn into an RGBA8 texture of ``size`` (w, h) with the
        pin's exposure and the HDR tone map, nearest-neighbour (its texels stay visible)."""
        probe = pin.probe if which == "pred" else pin.probe_gt
        if probe is None:
            return None
        t = pin.textures
        key = f"img-{which}"
        stale = t.setdefault("stale", {"pred", "gt"})
        if which in stale or t.get(key + "-size") != size or key not in t:
            src = self.renderer.texture(probe.transpose(1, 2, 0), t.get(f"src-{which}"))
            t[f"src-{which}"] = src
            if t.get(key + "-size") != size:
                for k in (key, key + "-fbo"):
                    if k in t:
                        t.pop(k).release()
                t[key] = self.ctx.texture(size, 4)
                t[key + "-fbo"] = self.ctx.framebuffer([t[key]])
                t[key + "-size"] = size
            h, w = probe.shape[1:]
            view = EquirectView()
            view.fit(size, (h, w))
            d = Display(kind="hdr", tonemap=self.hdr.tonemap, exposure=pin.exposure, offset=self.hdr.offset,
                        false_range=self.hdr.false_range)
            self.renderer.render(t[key + "-fbo"], (0, 0, *size),
                                 Frame(texture=src, pano_size=(h, w), view=view, display=d, nearest=True,
                                       background=BACKGROUND))
            stale.discard(which)
        return t[key]

    # -- drawing ------------------------------------------------------------------------------
    def markers(self) -> list[Marker]:
        """Pinned probes in view coordinates (those in front of the camera)."""
        if self.size is None or not self.pins:
            return []
        u = np.array([p.u for p in self.pins])
        v = np.array([p.v for p in self.pins])
        x, y, front = self.view.uv_to_screen(u, v, self.view_size(), self.size)
        return [Marker(float(a), float(b), p.colour, str(k + 1))
                for k, (a, b, f, p) in enumerate(zip(x, y, front, self.pins)) if f]

    def frame_spec(self) -> Frame | None:
        """What the view draws: the shown layer, or the image while that layer is still missing."""
        if self.size is None:
            return None
        src = "gt" if self.show_gt and self.gt is not None else "pred"
        layers = {name: t for (s, name), t in self._textures.items() if s == src}
        layer = self.layer if self.layer in layers else "image"
        tex = layers.get(layer)
        if tex is None:
            return None
        near = self.view_kind == "equirect" and self.view.zoom > NEAREST_ZOOM
        if layer == "probes":  # the atlas has its own resolution: nearest once its texels are big
            near = self.view_kind == "equirect" and self.view.zoom * tex.size[0] / self.size[1] > NEAREST_ZOOM
        return Frame(texture=tex, pano_size=self.size, view=self.view, display=self.display(layer),
                     nearest=near, markers=self.markers(), background=BACKGROUND,
                     extras={"marker_radius": 9.0 * self.ui_scale, "layers": layers, "scene": self.scene,
                             "insert": layer == "image"})

    def _view_key(self, spec: Frame, rect) -> tuple | None:
        """Everything the view's picture depends on (the renderer redraws it when this changes);
        None when linear passes (e.g. inserted objects) draw: they keep their own state."""
        if self.renderer.linear_passes or self.objects.active():
            return None
        fields = dataclasses.astuple
        version = next((self._tex_version.get(k, 0) for k, t in self._textures.items()
                        if t is spec.texture), 0)
        return (id(spec.texture), version, spec.pano_size, fields(spec.view), fields(spec.display),
                spec.nearest, tuple(map(fields, spec.markers)), spec.background, spec.extras["marker_radius"],
                tuple(rect[2:]))

    @property
    def ui_scale(self) -> float:
        return self.gui.scale if self.gui is not None else self.surface.content_scale

    @_gl
    def frame(self, capture: bool = False) -> float:
        """Apply updates, build the UI, draw the view and the UI and present them; with ``capture``
        keep the pixels drawn (``last_capture``).  Returns the frame's duration in seconds (also
        recorded in ``frame_times``)."""
        t0 = time.perf_counter()
        parts = _PartTimer(self.surface if self.sync_parts else None)
        self.surface.refresh()
        self.poll()
        parts.mark("poll")
        uploaded = self._upload_some()
        if uploaded:
            self.request_redraw(2)  # the view catches up next frame
        self._last_uploaded = uploaded
        parts.mark("upload")
        fw, fh = self.surface.framebuffer_size
        if self.gui is not None:
            self.gui.begin_frame()
        if self._fit_pending and self.size is not None:
            self.fit()
            self._fit_pending = False
        if self.gui is not None:
            self.gui.build()
        parts.mark("ui build")
        target = self.surface.target()
        target.use()
        self.ctx.viewport = (0, 0, fw, fh)
        target.clear(*BACKGROUND, 1.0, viewport=(0, 0, fw, fh))
        spec = self.frame_spec()
        if spec is not None:
            rect = self.view_rect()
            # a frame that uploaded a texture shows the previous picture: the redraw waits a frame
            self.renderer.render(target, rect, spec, fb_size=(fw, fh), cache_key=self._view_key(spec, rect),
                                 stale_ok=uploaded)
        parts.mark("view")
        if self.gui is not None:
            self.gui.end_frame(target)
        parts.mark("ui draw")
        if capture:
            self.last_capture = self.surface.read()
        self.surface.present()
        parts.mark("present")
        dt = time.perf_counter() - t0
        self.frame_times.append(dt)
        self.frame_parts = parts.times
        if self.busy:
            if dt > self.job_max_frame:
                self.job_max_parts = dict(parts.times)
            self.job_max_frame = max(self.job_max_frame, dt)
            self.job_frames += 1
        self._redraw = max(0, self._redraw - 1)
        return dt

    @_gl
    def screenshot(self, path: str | os.PathLike | None = None) -> np.ndarray:
        """Draw a frame of the current state and return it as uint8 RGB (rows from the top);
        written atomically as PNG to ``path`` if given."""
        self.frame(capture=True)
        while self._last_uploaded or self._pending:  # the view lags uploads by a frame
            self.frame(capture=True)
        img = self.last_capture
        if path is not None:
            from PIL import Image

            from phyir.io import atomic_write

            with atomic_write(path) as tmp:
                Image.fromarray(img).save(tmp, format="PNG")
        return img

    @_gl
    def wait_idle(self, timeout: float = 120.0, frames: bool = True) -> bool:
        """Draw frames (or just poll) until the job is done and layers are uploaded; False on timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if frames:
                self.frame()
            else:
                self.poll()
                self._upload_some()
            if not self.busy and not self._pending:
                return True
            if self.window is not None:
                self.surface.wait(0.01)
            else:
                time.sleep(0.005)
        return False

    def _title(self) -> None:
        if self.window is not None:
            self.surface.set_title(f"{self.name} - {self.title}" if self.name else self.title)

    # -- event loop ---------------------------------------------------------------------------
    def request_redraw(self, frames: int = 3) -> None:
        self._redraw = max(self._redraw, frames)

    def run(self) -> None:
        """The interactive loop: draws only when something changed (input, worker, animation)."""
        assert self.window is not None, "run() needs a window"
        while not self.surface.should_close():
            changed = self.poll()
            if changed or self._redraw > 0 or self.busy or self._pending or \
                    (self.gui is not None and self.gui.animating()):
                self.frame()
            if self._redraw > 0 or self._pending:
                timeout = 0.0
            elif self.busy or (self.gui is not None and self.gui.animating()):
                timeout = 0.1  # progress animation, slow: leaves the CPU to the model
            else:
                timeout = 1.0  # idle: sleep until an event (the worker wakes us too)
            self.surface.wait(timeout)

    def close(self) -> None:
        """Stop the worker and free the GL resources, the UI and the window."""
        self.worker.cancel()
        self.worker._wake = lambda: None
        self.worker.join(10.0)  # let torch finish its op: exiting under it aborts the process
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
                self.gui.shutdown()
                self.gui = None
            self._clear()
            self.objects.release()
            self.renderer.release()
        self.surface.close()
        sys.setswitchinterval(self._switch_interval)


class _PartTimer:
    """Wall and UI-thread CPU seconds spent in each named part of a frame.  Wall far above CPU means
    the UI thread waited: for the GL's threads, for the GIL (held by the worker) or for a core.
    With a ``surface`` each part waits for the GL work it queued (without holding the GIL), so GL
    time is billed to its part instead of all to the final present."""

    def __init__(self, surface=None):
        self.surface = surface
        self.times: dict[str, tuple[float, float]] = {}
        self._t, self._cpu = time.perf_counter(), time.thread_time()

    def mark(self, name: str) -> None:
        if self.surface is not None and name != "present":
            self.surface.finish()
        t, cpu = time.perf_counter(), time.thread_time()
        self.times[name] = (t - self._t, cpu - self._cpu)
        self._t, self._cpu = t, cpu


# ---------------------------------------------------------------------------------------------
# command line


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 1280x720), got {text!r}") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"window size {w}x{h} out of range (64..8192)")
    return w, h


def _uv(text: str) -> tuple[float, float]:
    try:
        u, v = (float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected U,V (panorama column,row), got {text!r}") from None
    return u, v


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="phyir-view",
        description="Inspect an indoor panorama and what PhyIR infers from it (layers, light probes).")
    p.add_argument("path", nargs="?", help="panorama (.hdr/.exr/.png/.jpg) or scene file (.exr); "
                                           "default: the demo scene")
    p.add_argument("--layer", choices=LAYERS, help="layer to show")
    p.add_argument("--probe", type=_uv, action="append", default=[], metavar="U,V",
                   help="pin the probe at panorama column U, row V (repeatable)")
    p.add_argument("--view", choices=("equirect", "perspective"), help="view")
    p.add_argument("--yaw", type=float, help="perspective view: yaw in degrees (toward +x)")
    p.add_argument("--pitch", type=float, help="perspective view: pitch in degrees (up)")
    p.add_argument("--fov", type=float, help="perspective view: vertical field of view in degrees")
    p.add_argument("--zoom", type=float, help="equirect view: screen pixels per panorama pixel (default fit)")
    p.add_argument("--center", type=_uv, metavar="U,V", help="equirect view: panorama point at the centre")
    p.add_argument("--exposure", type=float, help="exposure in EV")
    p.add_argument("--tonemap", choices=TONEMAPS, help="tone map of HDR layers")
    p.add_argument("--colormap", choices=COLORMAPS, help="colour map of scalar layers")
    p.add_argument("--compare", action="store_true",
                   help="treat the file's layers as ground truth: predict all layers and compare "
                        "(automatic for complete synthetic scenes)")
    p.add_argument("--show", choices=("prediction", "truth"),
                   help="with ground truth: which layers to show (key G)")
    p.add_argument("--gt", metavar="SCENE", help="ground-truth scene file to compare with")
    p.add_argument("--no-model", action="store_true", help="don't run the model (show the file's layers)")
    p.add_argument("--weights", metavar="FILE", help="model weights (default: the shipped ones)")
    p.add_argument("--device", help="torch device for the model (default: CUDA when available)")
    p.add_argument("--screenshot", metavar="OUT.png", help="render once, save a PNG and exit")
    p.add_argument("--size", type=_size, default=None, metavar="WxH", help="window size (default 1400x820)")
    p.add_argument("--headless", action="store_true",
                   help="render through EGL without a window (with --screenshot)")
    p.add_argument("--no-ui", action="store_true", help="with --screenshot: only the view, no panels")
    p.add_argument("--timeout", type=float, default=600.0,
                   help="with --screenshot: longest wait for loading and the model (s)")
    p.add_argument("--threads", type=int, help="torch threads for inference (default: cores - 1)")
    p.add_argument("--bench", action="store_true",
                   help="print frame times (idle view, and while the model runs) and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    scripted = bool(args.screenshot or args.bench)
    if args.headless and not scripted:
        print("phyir-view: --headless needs --screenshot OUT.png (or --bench)", file=sys.stderr)
        return 2
    headless = args.headless or (scripted and not surfaces.has_display())
    if not headless and not surfaces.has_display():
        print("phyir-view: no display (DISPLAY/WAYLAND_DISPLAY unset); use --screenshot OUT.png "
              "[--headless] to render without a window", file=sys.stderr)
        return 2
    path = args.path
    if path is None:
        path = _demo_path()
        if path is None:
            print("phyir-view: no PATH given and the demo scene is not available "
                  "(phyir.synth.demo_scene_path)", file=sys.stderr)
            return 2
    try:
        app = App(args.size or ((1280, 720) if scripted else (1400, 820)), headless=headless,
                  ui=not args.no_ui, visible=not scripted, threads=args.threads,
                  recent=False if scripted else None, run_model=not args.no_model,
                  weights=args.weights, device=args.device)
    except Exception as e:  # noqa: BLE001 - no GL: say so in one line
        print(f"phyir-view: cannot create an OpenGL 3.3 context: {e}", file=sys.stderr)
        return 2
    try:
        gt = None
        if args.gt:
            from phyir import io

            gt = io.load_scene(args.gt)
        app.open(path, gt=gt, compare=True if args.compare else None)
        if args.bench:
            return _bench(app, args)
        if not scripted:
            _apply_args(app, args, wait=False)
            app.run()
            return 0
        if not app.wait_idle(args.timeout):
            print(f"phyir-view: {path}: still loading after {args.timeout:g} s", file=sys.stderr)
            return 2
        _apply_args(app, args, wait=True)
        for _ in range(3):  # imgui lays windows out over a couple of frames
            app.frame()
        app.screenshot(args.screenshot)
        if app.error:
            print(f"phyir-view: {app.error}", file=sys.stderr)
            return 2
        return 0
    except PhyIRError as e:
        print(f"phyir-view: {e}", file=sys.stderr)
        return 2
    finally:
        app.close()


def _apply_args(app: App, args, wait: bool) -> None:
    if args.layer:
        if wait and args.layer not in app.available():
            raise PhyIRError(f"{app.name}: layer {args.layer!r} is not available "
                             f"(have: {', '.join(app.available()) or 'none'})")
        app.set_layer(args.layer)
    if args.view:
        app.set_view(args.view)
    persp = {k: v for k, v in (("fov", args.fov), ("yaw", args.yaw and math.radians(args.yaw)),
                                ("pitch", args.pitch and math.radians(args.pitch))) if v is not None}
    if persp:
        app.views["perspective"].__dict__.update(persp)
    if wait and (args.zoom or args.center):
        eq = app.views["equirect"]
        if args.zoom:
            eq.zoom_about(args.zoom / eq.zoom, app.view_size())
        if args.center:
            eq.center = args.center
    if args.show:
        app.set_source(args.show == "truth")
    if args.exposure is not None:
        app.set_exposure(args.exposure)
    if args.tonemap:
        app.set_tonemap(args.tonemap)
    if args.colormap:
        for name in app.scalar:
            app.set_colormap(args.colormap, name)
    if wait:
        for u, v in args.probe:
            app.pin_probe(u, v)


def _bench(app: App, args) -> int:
    """Frame times while the job runs, then of the idle view: the view pass alone, whole frames
    that redraw the view (exposure nudged each frame) and whole frames that reuse it (UI only)."""
    app.sync_parts = True  # each part waits for its GL work: the longest frame's parts say where it went
    ok = app.wait_idle(args.timeout)
    app.sync_parts = False
    during, n_during, parts = app.job_max_frame, app.job_frames, app.job_max_parts
    for _ in range(3):
        app.frame()
    ev = app.hdr.exposure
    redrawn = []
    for k in range(30):
        app.set_exposure(ev + 1e-3 * (k % 2))
        redrawn.append(app.frame())
    app.set_exposure(ev)
    app.frame()
    cached = sorted(app.frame() for _ in range(30))
    redrawn.sort()
    x, y, w, h = app.view_rect()
    passes = sorted(_time_view_pass(app) for _ in range(30))
    med = lambda t: 1000 * t[len(t) // 2]  # noqa: E731
    print(f"{app.name}: view {w}x{h} px, panorama {app.size[1]}x{app.size[0]}, layer {app.layer}, "
          f"GL {app.ctx.info['GL_RENDERER']}")
    print(f"view pass alone: median {med(passes):.1f} ms, max {1000 * passes[-1]:.1f} ms")
    print(f"whole frame redrawing the view: median {med(redrawn):.1f} ms, max {1000 * redrawn[-1]:.1f} ms")
    print(f"whole frame reusing the view (UI changes only): median {med(cached):.1f} ms, "
          f"max {1000 * cached[-1]:.1f} ms")
    print(f"while loading/inferring: longest frame {1000 * during:.1f} ms over {n_during} frames "
          f"(job {app.timings.get('job', float('nan')):.1f} s: {_fmt_timings(app.timings)})")
    print("  its parts, wall (UI-thread CPU) ms: " +
          ", ".join(f"{k} {1000 * w:.1f} ({1000 * c:.1f})" for k, (w, c) in parts.items()))
    return 0 if ok else 2


@_gl
def _time_view_pass(app: App) -> float:
    target, spec = app.surface.target(), app.frame_spec()
    fw, fh = app.surface.framebuffer_size
    app.ctx.finish()
    t0 = time.perf_counter()
    app.renderer.render(target, app.view_rect(), spec, fb_size=(fw, fh))
    app.ctx.finish()
    return time.perf_counter() - t0


def _fmt_timings(t: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.2f} s" for k, v in t.items() if k != "job")


def _demo_path() -> str | None:
    import phyir.synth

    demo = getattr(phyir.synth, "demo_scene_path", None)
    return None if demo is None else os.fspath(demo())


if __name__ == "__main__":
    sys.exit(main())
