"""The GL surfaces the app draws on: a GLFW window, or a standalone EGL context (headless).

Both give a moderngl context and a ``target()`` framebuffer to draw a frame into: the window's
back buffer (read back before the swap for screenshots), or an off-screen canvas.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable

import moderngl
import numpy as np


def has_display() -> bool:
    """Whether a window can be opened (X11/Wayland on Linux; always elsewhere)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def fast_pyopengl() -> None:
    """PyOpenGL (imgui's renderer) without a glGetError after every call: several ms per frame.
    moderngl still checks its own calls.  Must run before ``OpenGL.GL`` is imported."""
    if "OpenGL.platform" not in sys.modules:
        import OpenGL

        OpenGL.ERROR_CHECKING = False


def prefer_egl() -> None:
    """Make PyOpenGL (used by imgui's renderer) talk EGL; must run before ``OpenGL.GL`` is imported."""
    if "OpenGL.platform" not in sys.modules:
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def pyopengl_is_egl() -> bool:
    plat = os.environ.get("PYOPENGL_PLATFORM", "")
    return plat == "egl" or ("OpenGL.platform" in sys.modules and
                             type(sys.modules["OpenGL.platform"].PLATFORM).__name__ == "EGLPlatform")


def gl_context() -> moderngl.Context:
    """A standalone OpenGL 3.3 context through EGL (``phyir insert``); :class:`~phyir.errors.PhyIRError`
    in one line when there is none."""
    from phyir.errors import PhyIRError

    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # noqa: BLE001 - any driver failure means no headless GL here
        raise PhyIRError(f"cannot create a headless OpenGL context (EGL): {str(e).splitlines()[0]}") from None


def _finish_without_gil(ctx: moderngl.Context) -> None:
    """``glFinish`` through PyOpenGL, whose ctypes call drops the GIL while it waits (moderngl's
    ``finish`` holds it and stalls the worker thread meanwhile)."""
    from OpenGL import GL as gl

    _ = ctx.error  # clear moderngl's pending GL errors: PyOpenGL would raise on them
    gl.glFinish()


def _read_canvas(canvas: moderngl.Framebuffer) -> np.ndarray:
    """An off-screen canvas's pixels, uint8 RGB, rows from the top."""
    w, h = canvas.size
    return np.frombuffer(canvas.read(components=3), np.uint8).reshape(h, w, 3)[::-1].copy()


class _CanvasOwner:
    """A surface that may draw into an off-screen canvas (``_canvas``: a framebuffer, one colour
    attachment) of its own."""

    _canvas: moderngl.Framebuffer | None = None
    _drawn: moderngl.Framebuffer | None = None  # the framebuffer of the frame being drawn

    def _release_canvas(self) -> None:
        if self._canvas is not None:
            self._canvas.color_attachments[0].release()
            self._canvas.release()
            self._canvas = None


_windows = 0  # open GLFW windows: GLFW is terminated when the last one closes
_made_current: list = [None]  # the window whose context this module made current last


class Headless(_CanvasOwner):
    """A standalone EGL context (no window, no input)."""

    window = None

    def __init__(self, size: tuple[int, int], scale: float = 1.0):
        self.ctx = moderngl.create_standalone_context(backend="egl", require=330)
        self.size = (int(size[0]), int(size[1]))  # logical (UI) pixels
        self.scale = float(scale)                 # framebuffer pixels per logical pixel

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        return round(self.size[0] * self.scale), round(self.size[1] * self.scale)

    def refresh(self) -> None:
        pass

    @contextlib.contextmanager
    def current(self):
        """Context manager: make this context current (and leave it current, like a window's)."""
        self.ctx.__enter__()
        yield

    @property
    def content_scale(self) -> float:
        return self.scale

    def target(self, offscreen: bool = True) -> moderngl.Framebuffer:
        """The framebuffer frames are drawn into (an off-screen canvas of framebuffer_size, always)."""
        size = self.framebuffer_size
        if self._canvas is None or self._canvas.size != size:
            self._release_canvas()
            self._canvas = self.ctx.framebuffer([self.ctx.texture(size, 4)])
        return self._canvas


    def read(self) -> np.ndarray:
        """The frame just drawn, uint8 RGB, rows from the top."""
        return _read_canvas(self._canvas)

    def present(self) -> None:
        """Wait for the frame (there is nothing to show it on)."""
        self.finish()

    def finish(self) -> None:
        """Wait for the GL work queued so far.  Through PyOpenGL (ctypes drops the GIL while
        waiting) when it talks EGL: moderngl's finish() would hold the GIL and stall the worker
        thread meanwhile."""
        if pyopengl_is_egl():
            _finish_without_gil(self.ctx)
        else:
            self.ctx.finish()

    def close(self) -> None:
        self._release_canvas()
        self.ctx.release()


class Window(_CanvasOwner):
    """A GLFW window with an OpenGL 3.3 core context."""

    def __init__(self, size: tuple[int, int], title: str, visible: bool = True):
        import glfw

        self.glfw = glfw
        if not glfw.init():
            raise RuntimeError("GLFW could not be initialised (is there a display?)")
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, bool(visible))
        glfw.window_hint(glfw.SCALE_TO_MONITOR, True)
        egl = sys.platform.startswith("linux") and pyopengl_is_egl()
        if egl:  # PyOpenGL (imgui's renderer) is bound to EGL, e.g. headless tests in this process
            glfw.window_hint(glfw.CONTEXT_CREATION_API, glfw.EGL_CONTEXT_API)
        self.window = glfw.create_window(int(size[0]), int(size[1]), title, None, None)
        if not self.window:
            if not _windows:
                glfw.terminate()
            raise RuntimeError("GLFW could not create an OpenGL 3.3 window")
        _count(+1)
        glfw.make_context_current(self.window)
        glfw.swap_interval(0)  # redraws are event driven; don't block on vsync
        # wrap the current (GLX or EGL) context; moderngl's "detect" mode only knows GLX on Linux
        moderngl.init_context()
        self.ctx = moderngl.get_context()
        if self.ctx.version_code < 330:
            raise RuntimeError(f"OpenGL 3.3 needed, the window has {self.ctx.version_code}")
        _made_current[0] = self.window
        self.refresh()

    # Sizes are read once per frame (refresh): every GLFW/PyOpenGL call drops and retakes the GIL,
    # and while the worker runs Python each retake can wait a switch interval.
    def refresh(self) -> None:
        """Re-read the window's sizes (the app calls this once per frame and after resizes)."""
        self._size = tuple(self.glfw.get_window_size(self.window))
        self._fb_size = tuple(self.glfw.get_framebuffer_size(self.window))

    @property
    def size(self) -> tuple[int, int]:
        return self._size

    @property
    def framebuffer_size(self) -> tuple[int, int]:
        return self._fb_size

    @contextlib.contextmanager
    def current(self):
        """Context manager: this window's context is current inside."""
        if _made_current[0] is not self.window:
            self.glfw.make_context_current(self.window)
            _made_current[0] = self.window
        yield

    @property
    def content_scale(self) -> float:
        return float(max(self.glfw.get_window_content_scale(self.window)))

    @property
    def scale(self) -> float:
        (w, _), (fw, _) = self.size, self.framebuffer_size
        return fw / w if w else 1.0

    def target(self, offscreen: bool = False) -> moderngl.Framebuffer:
        """The window's back buffer (drawn directly: a blit costs ~10 ms on software GL; its ``size``
        is stale after a resize: use ``framebuffer_size``), or with ``offscreen`` a canvas of
        framebuffer_size that ``read`` reads and then copies to the back buffer: a frame to capture.
        The back buffer's pixels are the window system's (read back all black in a loaded CI run
        while the window was being resized), the canvas's are ours."""
        if offscreen:
            size = self.framebuffer_size
            if self._canvas is None or self._canvas.size != size:
                self._release_canvas()
                self._canvas = self.ctx.framebuffer([self.ctx.renderbuffer(size, 4)])
            self._drawn = self._canvas
            return self._canvas
        if getattr(self, "_screen", None) is None:
            self._screen = self.ctx.detect_framebuffer(0)
        self._drawn = self._screen
        return self._screen


    def read(self) -> np.ndarray:
        """The frame just drawn (before ``present``), uint8 RGB, rows from the top.  A frame drawn
        off-screen is read from its canvas, then copied to the back buffer to be shown."""
        from OpenGL import GL as gl

        w, h = self.framebuffer_size
        canvas = self._canvas
        if canvas is not None and self._drawn is canvas:
            cw, ch = canvas.size
            img = _read_canvas(canvas)
            gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, canvas.glo)
            gl.glBindFramebuffer(gl.GL_DRAW_FRAMEBUFFER, 0)
            gl.glBlitFramebuffer(0, 0, cw, ch, 0, 0, cw, ch, gl.GL_COLOR_BUFFER_BIT, gl.GL_NEAREST)
            gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, 0)
            return img
        gl.glBindFramebuffer(gl.GL_READ_FRAMEBUFFER, 0)
        gl.glReadBuffer(gl.GL_BACK)
        gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
        data = gl.glReadPixels(0, 0, w, h, gl.GL_RGB, gl.GL_UNSIGNED_BYTE)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)[::-1].copy()

    def present(self) -> None:
        self.glfw.swap_buffers(self.window)

    def finish(self) -> None:
        """Wait for the GL work queued so far (PyOpenGL drops the GIL while waiting)."""
        _finish_without_gil(self.ctx)

    def set_title(self, title: str) -> None:
        self.glfw.set_window_title(self.window, title)

    def should_close(self) -> bool:
        return bool(self.glfw.window_should_close(self.window))

    def wait(self, timeout: float) -> None:
        if timeout <= 0:
            self.glfw.poll_events()
        else:
            self.glfw.wait_events_timeout(timeout)

    def wake(self) -> None:
        """Thread-safe: make a waiting ``wait`` return."""
        self.glfw.post_empty_event()

    def on_drop(self, fn: Callable[[list[str]], None]) -> None:
        self.glfw.set_drop_callback(self.window, lambda _w, paths: fn(list(paths)))

    def close(self) -> None:
        with self.current():
            self._release_canvas()
        self.glfw.destroy_window(self.window)
        if _made_current[0] is self.window:
            _made_current[0] = None
        if _count(-1) == 0:
            self.glfw.terminate()


def _count(delta: int) -> int:
    global _windows
    _windows += delta
    return _windows
