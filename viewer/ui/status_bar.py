"""The status bar (which image of how many, the comparison, mouse position, value, frame time, the
last message) and the error banner."""

from __future__ import annotations

from phyir.commands.info import format_confidence
from viewer.ui.widgets import ERROR_BG, FLAGS_FIXED, LEVEL_COLOURS, fmt_value, imgui


class StatusBar:
    """Part of :class:`viewer.ui.gui.Gui` (``gui``: its scale): the bar under the view and the error
    banner over it."""

    def __init__(self, app, gui):
        self.app = app
        self.gui = gui

    def draw(self, W: float, H: float) -> None:
        app = self.app
        bh = self.gui.bar_height()
        imgui.set_next_window_pos(imgui.ImVec2(0, H - bh))
        imgui.set_next_window_size(imgui.ImVec2(W, bh))
        sc = self.gui.scale
        imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(6 * sc, 3 * sc))
        imgui.begin("##status", None, FLAGS_FIXED | imgui.WindowFlags_.no_scrollbar)
        last = app.messages[-1] if app.messages else None
        imgui.text(status_text(app))
        if app.objects.problem:  # stays while it holds, whatever the last message
            imgui.same_line()
            imgui.text_colored(imgui.ImVec4(*LEVEL_COLOURS["warning"]), "  camera inside an object")
        if last is not None:
            imgui.same_line()
            colour = LEVEL_COLOURS.get(last.level, (0.7, 0.7, 0.7, 1))
            imgui.text_colored(imgui.ImVec4(*colour), "  " + last.text)
        imgui.end()
        imgui.pop_style_var()

    def error_banner(self, fw: int, fh: int) -> None:
        app = self.app
        if not app.messages.error:
            return
        s = self.gui.fb_scale
        x, y, w, _ = app.view_rect()
        imgui.set_next_window_pos(imgui.ImVec2(x / s + 10 * self.gui.scale, y / s + 10 * self.gui.scale))
        imgui.set_next_window_size(imgui.ImVec2(w / s - 20 * self.gui.scale, 0))
        imgui.push_style_color(imgui.Col_.window_bg, imgui.ImVec4(*ERROR_BG))
        flags = FLAGS_FIXED | imgui.WindowFlags_.always_auto_resize
        flags |= imgui.WindowFlags_.no_focus_on_appearing
        flags &= ~imgui.WindowFlags_.no_bring_to_front_on_focus  # over the view window
        imgui.begin("##error", None, flags)
        imgui.push_text_wrap_pos(0)
        imgui.text(app.messages.error)
        imgui.pop_text_wrap_pos()
        if imgui.small_button("dismiss"):
            app.messages.error = None
        imgui.end()
        imgui.pop_style_color()


def status_text(app) -> str:
    """The status bar's text (before the last message): the image, the comparison, the pixel under
    the mouse and its value, the geometry confidence (as ``phyir info`` writes it), frame times."""
    parts = []
    if len(app.images) > 1:
        parts.append(f"image {app.images.current + 1}/{len(app.images)} {app.images.label(app.images.entry)}")
    if app.comparison.mode is not None and app.images.reference is not None:
        parts.append(f"{app.comparison.mode} vs {app.images.label(app.images.reference)}")
    if app.camera.hover is not None and app.doc.size is not None:
        u, v = app.camera.hover
        vals = app.doc.values_at(u, v).get(app.display.layer)
        parts.append(f"col {int(u)} row {int(v)}")
        if vals is not None:
            parts.append(f"{app.display.layer} {fmt_value(vals)}")
    if app.doc.confidence is not None:
        parts.append(f"geometry confidence {format_confidence(app.doc.confidence)}")
    if app.frame_times:
        parts.append(f"frame {1000 * app.frame_times[-1]:.0f} ms")
    if app.loader.busy and app.loader.job_frames:
        parts.append(f"longest frame while busy {1000 * app.loader.job_max_frame:.0f} ms")
    return "   ".join(parts)
