"""The imgui interface: :class:`Gui` owns the imgui context and its frame, and the parts the interface
is made of, each with its own state: the menu bar (``menu``: ``menu_bar``), the side panel
(``side_panel``, with the open images: ``images_panel``), the status bar (``status_bar``), the view's
mouse and keyboard handling (``input``) and the side panel's sections after the probes
(``sections``: the inserted objects' ``objects_panel``, and any added with ``add_section``).

Everything here reads the app's collaborators (:class:`ViewerApp`) and calls their methods, so a
click and a script take the same path.  Sizes are in imgui's logical pixels; the view and the GL
calls use framebuffer pixels (``* scale`` on high-DPI screens).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Protocol

from viewer.ui.images_panel import ImagesPanel
from viewer.ui.input import ViewInput
from viewer.ui.menu_bar import MenuBar
from viewer.ui.objects_panel import ObjectsPanel
from viewer.ui.side_panel import SidePanel
from viewer.ui.status_bar import StatusBar
from viewer.ui.widgets import PANEL_WIDTH, imgui

if TYPE_CHECKING:
    from viewer.app.camera import Camera
    from viewer.app.common import Messages
    from viewer.app.comparison import Comparison
    from viewer.app.composer import ViewComposer
    from viewer.app.display import DisplaySettings
    from viewer.app.document import Document
    from viewer.app.images import ImageList
    from viewer.app.loader import Loader
    from viewer.app.objects import InsertedObjects
    from viewer.app.pins import Pins

__all__ = ["PANEL_WIDTH", "Gui", "Section", "ViewerApp"]


class ViewerApp(Protocol):
    """What the interface uses of the app (:class:`viewer.app.App`): its collaborators and window."""

    surface: object
    ctx: object
    recent: object
    frame_times: object
    images: ImageList
    loader: Loader
    display: DisplaySettings
    camera: Camera
    pins: Pins
    comparison: Comparison
    objects: InsertedObjects
    composer: ViewComposer
    messages: Messages

    @property
    def window(self): ...

    @property
    def doc(self) -> Document: ...

    def view_rect(self) -> tuple[int, int, int, int]: ...

    def open(self, source, **kw) -> None: ...

    def request_redraw(self, frames: int = 3) -> None: ...

    def request_screenshot(self, path=None) -> None: ...


class Section(Protocol):
    """A section of the side panel: ``draw()`` fills it under a collapsing header ``title`` (an
    imgui label: ``"Name (3)###name"`` keeps its id while the count changes), open at first if
    ``default_open``."""

    title: str
    default_open: bool

    def draw(self) -> None: ...


class Gui:
    """The imgui context and its frame, the scale (``scale``: logical px, ``fb_scale``: framebuffer
    px per logical px); the interface is built by the parts it owns."""

    def __init__(self, app: ViewerApp):
        self.app = app
        self.ctx = imgui.create_context()
        imgui.set_current_context(self.ctx)  # create_context keeps an existing context current
        self.io = imgui.get_io()
        self.io.set_ini_filename("")  # no imgui.ini next to the user's files
        self.scale = max(1.0, app.surface.content_scale)
        style = imgui.get_style()
        style.scale_all_sizes(self.scale)
        style.font_scale_dpi = self.scale
        style.window_rounding = 0.0
        # a thin, translucent slider grab: the default one covers a digit of the value ("+0.▮ EV")
        style.grab_min_size = 3.0 * self.scale
        for col in (imgui.Col_.slider_grab, imgui.Col_.slider_grab_active):
            c = style.color_(col)
            style.set_color_(col, imgui.ImVec4(c.x, c.y, c.z, 0.45))
        if app.window is not None:
            from imgui_bundle.python_backends.glfw_backend import GlfwRenderer

            self.impl = GlfwRenderer(app.window, attach_callbacks=False)
            self._install_callbacks()
        else:
            from imgui_bundle.python_backends.opengl_backend_programmable import ProgrammablePipelineRenderer

            self.impl = ProgrammablePipelineRenderer()
        self._last = time.perf_counter()
        self.objects_panel = ObjectsPanel(app.objects, app.camera, app.messages)
        self.sections: list[Section] = [self.objects_panel]
        self.menu = MenuBar(app, self)
        self.images_panel = ImagesPanel(app, self)
        self.side_panel = SidePanel(app, self, self.images_panel)
        self.status_bar = StatusBar(app, self)
        self.input = ViewInput(app, self, self.menu, self.images_panel, self.objects_panel)
        app.pins.on_pinned = self._scroll_to_pin

    def add_section(self, section: Section) -> None:
        """Draw ``section`` in the side panel, after the probes and the sections added before it."""
        self.sections.append(section)

    def _scroll_to_pin(self, index: int) -> None:
        self.side_panel.scroll_to_pin = index

    # -- frame --------------------------------------------------------------------------------
    @property
    def fb_scale(self) -> float:
        return self.app.surface.scale

    def bar_height(self) -> float:
        """Height of the menu bar and of the status bar (logical px)."""
        return 13.0 * self.scale + 2 * 3.0 * self.scale + 2

    def view_rect(self, fw: int, fh: int) -> tuple[int, int, int, int]:
        s = self.fb_scale
        top = math.ceil(self.bar_height() * s)
        bottom = math.ceil(self.bar_height() * s)
        right = math.ceil(PANEL_WIDTH * self.scale * s)
        return 0, top, max(1, fw - right), max(1, fh - top - bottom)

    def begin_frame(self) -> None:
        io = self.io
        if self.app.window is not None:
            self.impl.process_inputs()
        else:
            w, h = self.app.surface.size
            io.display_size = imgui.ImVec2(w, h)
            io.display_framebuffer_scale = imgui.ImVec2(self.fb_scale, self.fb_scale)
            now = time.perf_counter()
            io.delta_time = max(1e-4, now - self._last)
            self._last = now
        imgui.new_frame()

    def end_frame(self, target) -> None:
        target.use()
        imgui.render()
        _ = self.app.ctx.error  # drop GL errors moderngl left behind; PyOpenGL would raise on them
        self.impl.render(imgui.get_draw_data())

    def animating(self) -> bool:
        return self.menu.animating()

    def make_current(self) -> None:
        imgui.set_current_context(self.ctx)

    def shutdown(self) -> None:
        self.impl.shutdown()
        imgui.destroy_context(self.ctx)

    # -- callbacks (window) ---------------------------------------------------------------------
    def _install_callbacks(self) -> None:
        import glfw

        impl, app, win = self.impl, self.app, self.app.window

        def wrap(fn):
            def cb(*args):
                fn(*args)
                app.request_redraw()
            return cb

        glfw.set_key_callback(win, wrap(impl.keyboard_callback))
        glfw.set_char_callback(win, wrap(impl.char_callback))
        glfw.set_cursor_pos_callback(win, wrap(lambda w, x, y: self.io.add_mouse_pos_event(x, y)))
        glfw.set_cursor_enter_callback(win, wrap(
            lambda w, entered: None if entered else self.io.add_mouse_pos_event(-3.4e38, -3.4e38)))
        glfw.set_mouse_button_callback(win, wrap(impl.mouse_button_callback))
        glfw.set_scroll_callback(win, wrap(impl.scroll_callback))
        glfw.set_window_size_callback(win, wrap(lambda *a: None))
        glfw.set_framebuffer_size_callback(win, wrap(lambda *a: None))
        glfw.set_window_refresh_callback(win, wrap(lambda *a: None))
        glfw.set_window_focus_callback(win, wrap(lambda *a: None))
        glfw.set_window_content_scale_callback(win, wrap(lambda w, sx, sy: self._rescale(max(sx, sy))))

    def _rescale(self, scale: float) -> None:
        scale = max(1.0, scale)
        style = imgui.get_style()
        style.scale_all_sizes(scale / self.scale)
        style.font_scale_dpi = scale
        self.scale = scale

    # -- the interface --------------------------------------------------------------------------
    def build(self) -> None:
        app = self.app
        fw, fh = app.surface.framebuffer_size
        s = self.fb_scale
        W, H = fw / s, fh / s  # logical
        self.menu.draw()
        self.input.view_window(fw, fh)
        self.side_panel.draw(W, H)
        self.status_bar.draw(W, H)
        self.status_bar.error_banner(fw, fh)
        self.menu.open_popups()
        self.menu.poll_dialog()
        if not self.io.want_capture_keyboard and not self.io.want_text_input:
            self.input.handle_keys()
        if self.menu.show_help:
            self.menu.help_window()
