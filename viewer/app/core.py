"""``phyir-view``: the interactive panorama inspector.

:class:`App` is what the UI, the command line and the tests drive.  It owns the window (or headless
surface), the renderer, the worker and the frame loop, and a few collaborators, each with its own
state: ``images`` (the open images and their documents, the reference, which one the worker loads
next: ``viewer.app.images``), ``loader`` (the bridge to the worker: ``viewer.app.loader``, its events
applied by ``viewer.app.events``), ``display`` (layer, exposure, tone and colour maps),
``camera`` (the views and the mouse), ``pins`` (pinned probes), ``comparison`` (with the reference),
``objects`` (inserted objects and their renderer), ``composer`` (what the view draws), ``messages``,
``remote`` (the control socket) and ``gui`` (the imgui interface, ``viewer.ui``).  The panels call
the same methods a script does (``images.open``, ``display.set_layer``, ``pins.pin_probe``,
``camera.set_view``, ...), then ``frame()`` draws and ``screenshot()`` reads the result.  All GL
work happens on the thread that created the App; loading, inference and re-rendering run in
``viewer.worker``.
"""

from __future__ import annotations

import contextlib
import gc
import os

# Idle OpenMP threads sleep instead of spinning (set before torch loads, as phyir.cli does): a
# spinning inference thread would take the UI thread's core on a small CPU.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import sys
import time
from collections import deque
from collections.abc import Callable

import moderngl
import numpy as np

from phyir.scene import PanoScene
from viewer.app.camera import Camera
from viewer.app.common import BACKGROUND, Messages, gl_current
from viewer.app.comparison import Comparison
from viewer.app.composer import ViewComposer
from viewer.app.display import DisplaySettings
from viewer.app.document import Document
from viewer.app.events import WorkerEvents
from viewer.app.images import ImageList
from viewer.app.loader import Loader
from viewer.app.objects import InsertedObjects
from viewer.app.pins import Pins
from viewer.app.remote import RemoteControl
from viewer.gl import window as surfaces
from viewer.recent import RecentFiles
from viewer.renderer import Renderer
from viewer.worker import Worker, preload

# GIL switch interval while an App lives (see App.__init__): 0.5 ms left frames of 135-192 ms while
# loading (imgui's draw waits once per GL call), 0.1 ms 34-65 ms (headless, quiet machine)
SWITCH_INTERVAL_S = 0.0001


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
        self.gui = None
        self.last_capture: np.ndarray | None = None
        self.quit_requested = False  # the ``quit`` command: the loops end
        self._screenshot_request: str | None = None  # F12 / the menu: saved after the frame
        model_kw = {k: v for k, v in (("weights", weights), ("device", device)) if v is not None}
        preload()  # what jobs would import in the worker, holding the GIL the UI needs
        worker = Worker(wake=getattr(self.surface, "wake", None), predict=predict, render=render,
                        threads=threads, predict_kwargs=model_kw)
        self.recent = (RecentFiles() if recent is None or recent is True else recent) or None
        self.frame_times: deque[float] = deque(maxlen=240)
        self.frame_parts: dict[str, tuple[float, float]] = {}  # the last frame's parts
        self.sync_parts = False  # wait for the GL after each part, so GL time lands in its part
        self._redraw = 2
        self.uploaded_last_frame = False
        self._make_collaborators(worker, run_model)
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

    def _make_collaborators(self, worker: Worker, run_model: bool) -> None:
        """The parts the App is made of, each handed the others it uses."""
        self.messages = Messages(self.request_redraw)
        self.loader = Loader(worker, self.messages, run_model)
        self.images = ImageList(self.loader, self.messages, gl_context=self.gl_context,
                                retitle=self.update_title, redraw=self.request_redraw)
        self.display = DisplaySettings(self.images, self.request_redraw)
        self.pins = Pins(self.images, self.renderer, self.ctx, self.display.hdr, self.gl_context)
        self.display.settings_changed = self.pins.dirty
        self.camera = Camera(self.images, self.pins, self.view_size)
        self.comparison = Comparison(self.images, self.display, self.loader, self.renderer,
                                     self.request_redraw)
        with self.surface.current():
            self.objects = InsertedObjects(self.renderer, self.ctx, self.surface.finish, self.images,
                                           self.camera, self.messages, self.request_redraw)
        self.composer = ViewComposer(self.images, self.display, self.camera, self.comparison, self.objects,
                                     self.renderer, lambda: self.ui_scale)
        self.events = WorkerEvents(self.loader, self.images, self.display, self.pins, self.objects,
                                   self.messages, self.recent, self.update_title)
        self.remote = RemoteControl(getattr(self.surface, "wake", None))

    # -- properties ---------------------------------------------------------------------------
    @property
    def window(self):
        return self.surface.window

    @property
    def worker(self) -> Worker:
        return self.loader.worker

    @property
    def doc(self) -> Document:
        """The shown image's document (scene, layers, pins, textures)."""
        return self.images.doc

    @contextlib.contextmanager
    def gl_context(self):
        """The App's GL and imgui contexts current for the block (several Apps may coexist)."""
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
            yield

    def view_rect(self) -> tuple[int, int, int, int]:
        """(x, y, w, h) of the view in framebuffer pixels (y from the top)."""
        fw, fh = self.surface.framebuffer_size
        if self.gui is None:
            return 0, 0, fw, fh
        return self.gui.view_rect(fw, fh)

    def view_size(self) -> tuple[int, int]:
        return self.view_rect()[2:]

    @property
    def ui_scale(self) -> float:
        return self.gui.scale if self.gui is not None else self.surface.content_scale

    def open(self, source: str | os.PathLike | PanoScene, **kw) -> None:
        """Open a file or scene into the image shown (``ImageList.open``: ``gt``, ``name``,
        ``compare``, ``model``)."""
        self.images.open(source, **kw)

    def on_drop(self, paths: list[str]) -> None:
        """Files dropped on the window: added to the open images, the first shown."""
        for k, path in enumerate(paths):
            self.images.add(path) if k == 0 else self.images.queue(path)
        self.request_redraw()

    def poll(self) -> bool:
        """Apply the worker's events (after reloading a watched file that changed); True if any came."""
        self.images.check_file_changed()
        return self.events.poll()

    # -- frames -------------------------------------------------------------------------------
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
        doc = self.images.doc
        uploaded = doc.upload_some(self.renderer, self.display.layer)
        if uploaded:
            self.request_redraw(2)  # the view catches up next frame
        self.uploaded_last_frame = uploaded
        parts.mark("upload")
        fw, fh = self.surface.framebuffer_size
        if self.gui is not None:
            self.gui.begin_frame()
        doc = self.images.doc
        if doc.fit_pending and doc.size is not None:
            self.camera.fit()
            doc.fit_pending = False
        if self.gui is not None:
            self.gui.build()
        parts.mark("ui build")
        target = self.surface.target(offscreen=capture)
        target.use()
        self.ctx.viewport = (0, 0, fw, fh)
        target.clear(*BACKGROUND, 1.0, viewport=(0, 0, fw, fh))
        spec = self.composer.frame_spec()
        rect = self.view_rect()
        # a slice of the objects' full-quality picture (a capture finishes it: it shows it)
        self.objects.refine(spec, tuple(rect[2:]), final=capture)
        if spec is not None:
            # a frame that uploaded a texture shows the previous picture: the redraw waits a frame
            self.renderer.render(target, rect, spec, fb_size=(fw, fh),
                                 cache_key=self.composer.view_key(spec, rect), stale_ok=uploaded)
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
        self.loader.record_frame(dt, parts.times)
        self._redraw = max(0, self._redraw - 1)
        if self._screenshot_request is not None and not capture:
            self._save_requested_screenshot()
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
                self.images.doc.upload_some(self.renderer, self.display.layer)
            if not self.loader.busy and not self.images.doc.pending_uploads:
                return True
            if self.window is not None:
                self.surface.wait(0.01)
            else:
                time.sleep(0.005)
        return False

    @gl_current
    def screenshot(self, path: str | os.PathLike | None = None) -> np.ndarray:
        """Draw a frame of the current state and return it as uint8 RGB (rows from the top);
        written atomically as PNG to ``path`` if given."""
        self.frame(capture=True)
        while self.uploaded_last_frame or self.images.doc.pending_uploads:  # the view lags uploads by a frame
            self.frame(capture=True)
        img = self.last_capture
        if path is not None:
            from PIL import Image

            from phyir.io import atomic_write

            with atomic_write(path) as tmp:
                Image.fromarray(img).save(tmp, format="PNG")
        return img

    def request_screenshot(self, path: str | os.PathLike | None = None) -> None:
        """Save a screenshot after the frame being built (F12, the menu): ``screenshot`` draws frames
        itself, which it cannot do from inside the UI's frame (imgui's frame is open)."""
        if path is None:
            stem = os.path.splitext(self.images.doc.path or "phyir-view")[0]
            path = f"{stem}.{self.display.layer}.png"
        self._screenshot_request = os.fspath(path)
        self.request_redraw()

    def _save_requested_screenshot(self) -> None:
        """After a frame: the screenshot asked for while it was built, with a note on the outcome."""
        out, self._screenshot_request = self._screenshot_request, None
        try:
            self.screenshot(out)
        except OSError as e:  # e.g. a read-only folder: report, keep running
            self.messages.note("error", f"cannot save {out}: {e.strerror or e}")
            return
        self.messages.note("info", f"saved {out}")

    def update_title(self) -> None:
        if self.window is not None:
            name = self.images.doc.name
            self.surface.set_title(f"{name} - {self.title}" if name else self.title)

    # -- event loop ---------------------------------------------------------------------------
    def request_redraw(self, frames: int = 3) -> None:
        self._redraw = max(self._redraw, frames)

    @property
    def redraw_pending(self) -> bool:
        """Whether frames are still owed (a change asked for them)."""
        return self._redraw > 0

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start the control socket (``phyir-view --listen``) on a loopback ``host``; returns the
        address (port 0: a free one).  The event loops serve its commands between frames."""
        return self.remote.listen(host, port)

    def step(self) -> float:
        """One turn of the event loop: commands, worker events, a frame if anything changed.  Returns
        how long the loop may then wait for events (s)."""
        changed = self.remote.serve(self)
        if changed:
            self.request_redraw()
        changed = self.poll() or changed
        animating = self.gui is not None and self.gui.animating()
        refining = self.objects.refining()
        busy, pending = self.loader.busy, self.images.doc.pending_uploads
        if changed or self.redraw_pending or busy or pending or animating or refining:
            self.frame()
        if self.redraw_pending or self.images.doc.pending_uploads:
            return 0.0
        if refining:
            return 0.01  # a background job's result shows in the next frame
        if self.loader.busy or animating:
            return 0.1  # progress animation, slow: leaves the CPU to the model
        return 1.0  # idle: sleep until an event (the worker and the socket wake a window)

    def wait_events(self, timeout: float) -> None:
        """Sleep until input, the worker or a command, or ``timeout``; headless, the worker is polled
        at least every 20 ms."""
        if self.window is not None:
            self.surface.wait(timeout)
        elif self.remote.listening:
            self.remote.wait(min(timeout, 0.02))
        else:
            time.sleep(min(timeout, 0.02))

    def serve_until(self, done: Callable[[], bool], timeout: float | None = None) -> bool:
        """Run the event loop (commands, frames) until ``done()`` or ``timeout`` s (None: no limit);
        False on timeout.  What a headless ``--listen`` and the tests run."""
        end = None if timeout is None else time.monotonic() + timeout
        while not done():
            if end is not None and time.monotonic() > end:
                return False
            self.wait_events(self.step())
        return True

    def run(self) -> None:
        """The interactive loop: draws only when something changed (input, worker, animation, a
        command on the control socket)."""
        assert self.window is not None, "run() needs a window"
        while not (self.surface.should_close() or self.quit_requested):
            self.wait_events(self.step())

    def close(self) -> None:
        """Stop the control socket and the worker and free the GL resources, the UI and the window."""
        self.remote.close()
        worker = self.loader.worker
        worker.cancel()
        worker.set_wake(None)
        worker.join(10.0)  # let torch finish its op: exiting under it aborts the process
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
                self.gui.shutdown()
                self.gui = None
            self.images.release()
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
