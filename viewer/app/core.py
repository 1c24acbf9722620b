"""``phyir-view``: the interactive panorama inspector.

:class:`App` holds the viewer's state and is what the UI, the command line and the tests drive: the
imgui panels (``viewer/ui/``) call the same methods a script does (``open``, ``set_layer``,
``pin_probe``, ``set_view``, ...), then ``frame()`` draws and ``screenshot()`` reads the result.
All GL work happens on the thread that created the App; loading, inference and re-rendering run in
``viewer.worker``.  The App's code is split by concern: state and lifecycle here, and the parts it
is made of: the open images (``images``) and the comparison with a reference (``comparison``),
file I/O (``files``), worker events (``events``), what is displayed (``display``), the view and
mouse (``camera``), pinned probes (``pins``), inserted objects (``objects``) and the control socket
(``remote``).
"""

from __future__ import annotations

import gc
import os

# Idle OpenMP threads sleep instead of spinning (set before torch loads, as phyir.cli does): a
# spinning inference thread would take the UI thread's core on a small CPU.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import sys
import time
from collections import deque

import moderngl
import numpy as np

from phyir.insert.views import EquirectView, PerspectiveView
from phyir.scene import PanoScene
from viewer.app.camera import Camera
from viewer.app.common import BACKGROUND, Message, ScalarDisplay, gl_current
from viewer.app.comparison import Comparison
from viewer.app.display import DisplaySettings
from viewer.app.events import WorkerEvents
from viewer.app.files import FileActions
from viewer.app.images import ImageList
from viewer.app.objects import InsertedObjects
from viewer.app.pins import Pins
from viewer.app.remote import Remote
from viewer.gl import window as surfaces
from viewer.layers import LAYERS, SPECS
from viewer.probes import Pin
from viewer.recent import RecentFiles
from viewer.renderer import Display, Renderer
from viewer.worker import Worker, preload

# GIL switch interval while an App lives (see App.__init__): 0.5 ms left frames of 135-192 ms while
# loading (imgui's draw waits once per GL call), 0.1 ms 34-65 ms (headless, quiet machine)
SWITCH_INTERVAL_S = 0.0001


class App(ImageList, Comparison, FileActions, WorkerEvents, DisplaySettings, Camera, Pins, InsertedObjects,
          Remote):
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
        self.watch = False  # reload the file when it changes on disk (phyir-view --watch)
        self._watch_stamp: tuple | None = None  # (mtime, size) of the file as loaded
        self._watch_last = 0.0
        self._opening = None  # the file being opened (viewer.app.files), until it loads or fails
        self._screenshot_request: str | None = None  # F12 / the menu: saved after the frame
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
        self.confidence: float | None = None  # geometry confidence of the scene (status bar)
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
        self.layer_textures: dict[tuple[str, str], moderngl.Texture] = {}
        self.texture_versions: dict[tuple[str, str], int] = {}  # uploads per texture: in the view's cache key
        self.pending_uploads: list[tuple[str, str]] = []
        self._fit_pending = True
        self._redraw = 2
        self.uploaded_last_frame = False
        self.init_images()  # several images open (viewer.app.images), a reference to compare with
        self.init_comparison()
        self.attach_objects()
        self.gui = None
        if ui:
            from viewer.ui.gui import Gui

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

    def note(self, level: str, text: str) -> None:
        self.messages.append(Message(level, text))
        if level == "error":
            self.error = text
        self._redraw = max(self._redraw, 2)

    @property
    def ui_scale(self) -> float:
        return self.gui.scale if self.gui is not None else self.surface.content_scale

    @gl_current
    def frame(self, capture: bool = False) -> float:
        """Apply updates, build the UI, draw the view and the UI and present them; with ``capture``
        keep the pixels drawn (``last_capture``).  Returns the frame's duration in seconds (also
        recorded in ``frame_times``)."""
        t0 = time.perf_counter()
        parts = _PartTimer(self.surface if self.sync_parts else None)
        self.surface.refresh()
        self.poll()
        parts.mark("poll")
        uploaded = self.upload_some()
        if uploaded:
            self.request_redraw(2)  # the view catches up next frame
        self.uploaded_last_frame = uploaded
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
        target = self.surface.target(offscreen=capture)
        target.use()
        self.ctx.viewport = (0, 0, fw, fh)
        target.clear(*BACKGROUND, 1.0, viewport=(0, 0, fw, fh))
        spec = self.frame_spec()
        rect = self.view_rect()
        # a slice of the objects' full-quality picture (a capture finishes it: it shows it)
        self.objects.refine(spec, tuple(rect[2:]), final=capture)
        if spec is not None:
            # a frame that uploaded a texture shows the previous picture: the redraw waits a frame
            self.renderer.render(target, rect, spec, fb_size=(fw, fh), cache_key=self.view_key(spec, rect),
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
        if self._screenshot_request is not None and not capture:
            self.save_requested_screenshot()
        return dt

    @gl_current
    def wait_idle(self, timeout: float = 120.0, frames: bool = True) -> bool:
        """Draw frames (or just poll) until the job is done and layers are uploaded; False on timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if frames:
                self.frame()
            else:
                self.poll()
                self.upload_some()
            if not self.busy and not self.pending_uploads:
                return True
            if self.window is not None:
                self.surface.wait(0.01)
            else:
                time.sleep(0.005)
        return False

    def update_title(self) -> None:
        if self.window is not None:
            self.surface.set_title(f"{self.name} - {self.title}" if self.name else self.title)

    # -- event loop ---------------------------------------------------------------------------
    def request_redraw(self, frames: int = 3) -> None:
        self._redraw = max(self._redraw, frames)

    @property
    def redraw_pending(self) -> bool:
        """Whether frames are still owed (a change asked for them)."""
        return self._redraw > 0

    def run(self) -> None:
        """The interactive loop: draws only when something changed (input, worker, animation, a
        command on the control socket: viewer.app.remote)."""
        assert self.window is not None, "run() needs a window"
        while not (self.surface.should_close() or self.quit_requested):
            self.wait_events(self.step())

    def close(self) -> None:
        """Stop the control socket and the worker and free the GL resources, the UI and the window."""
        self.stop_remote()
        self.worker.cancel()
        self.worker.set_wake(None)
        self.worker.join(10.0)  # let torch finish its op: exiting under it aborts the process
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
                self.gui.shutdown()
                self.gui = None
            self.clear_shown()
            self.close_other_images()
            self.detach_objects()
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
