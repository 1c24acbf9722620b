"""The imgui interface: menu bar, side panel, status bar and the view's mouse/keyboard handling.

Everything here only reads the :class:`~viewer.app.App`'s state and calls its methods, so a click
and a script take the same path.  Sizes are in imgui's logical pixels; the view and the GL calls
use framebuffer pixels (``* scale`` on high-DPI screens).
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import time
from typing import TYPE_CHECKING

import numpy as np
import torch

from viewer.window import fast_pyopengl

fast_pyopengl()
from imgui_bundle import imgui  # noqa: E402

from phyir import pano  # noqa: E402
from viewer.layers import KEYS, LAYERS, SPECS  # noqa: E402
from viewer.renderer import COLORMAPS, TONEMAPS, colormap_lut  # noqa: E402

if TYPE_CHECKING:
    from viewer.app import App

PANEL_WIDTH = 370      # logical pixels
ERROR_BG = (0.55, 0.08, 0.08, 0.95)
VALUES_ZOOM = 56.0     # logical px per panorama pixel above which pixel values are printed
EV_STEP, OFFSET_STEP = 0.5, 0.05  # keys E and O
_FLAGS_FIXED = (imgui.WindowFlags_.no_title_bar | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_move
                | imgui.WindowFlags_.no_collapse | imgui.WindowFlags_.no_saved_settings
                | imgui.WindowFlags_.no_bring_to_front_on_focus)


LEVEL_COLOURS = {"error": (1, 0.4, 0.4, 1), "warning": (1, 0.8, 0.3, 1)}


def col32(r: float, g: float, b: float, a: float = 1.0) -> int:
    return imgui.color_convert_float4_to_u32(imgui.ImVec4(r, g, b, a))


def _fmt(x: float) -> str:
    return f"{x:.4g}" if abs(x) < 1e5 else f"{x:.3e}"


def fmt_value(a: np.ndarray) -> str:
    a = np.atleast_1d(a)
    return ", ".join(_fmt(float(x)) for x in a)


class Gui:
    def __init__(self, app: App):
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
        if app.window is not None:
            from imgui_bundle.python_backends.glfw_backend import GlfwRenderer

            self.impl = GlfwRenderer(app.window, attach_callbacks=False)
            self._install_callbacks()
        else:
            from imgui_bundle.python_backends.opengl_backend_programmable import ProgrammablePipelineRenderer

            self.impl = ProgrammablePipelineRenderer()
        self._last = time.perf_counter()
        self._dialog = None          # portable_file_dialogs.open_file in flight
        self._path_popup = False     # the fallback "open path" popup
        self._path_text = ""
        self._dragged = False
        self._show_help = False
        self._lut_cache: dict[str, np.ndarray] = {}
        self.probe_rects: dict[tuple[int, str], tuple[float, float, float, float]] = {}  # for tests
        self.quit_requested = False
        self.scroll_to_pin: int | None = None

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
        return self._dialog is not None

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
        self._menu_bar()
        self._view_window(fw, fh)
        self._side_panel(W, H)
        self._status_bar(W, H)
        self._error_banner(fw, fh)
        self._open_popups()
        self._poll_dialog()
        if not self.io.want_capture_keyboard and not self.io.want_text_input:
            self._keys()
        if self._show_help:
            self._help_window()

    def _menu_bar(self) -> None:
        app = self.app
        if not imgui.begin_main_menu_bar():
            return
        if imgui.begin_menu("File"):
            if imgui.menu_item_simple("Open...", "Ctrl+O"):
                self.open_dialog()
            if imgui.menu_item_simple("Open path..."):
                self._path_popup = True
            recent = app.recent.files if app.recent is not None else []
            if imgui.begin_menu("Recent files", bool(recent)):
                for f in recent:
                    if imgui.menu_item_simple(f):
                        app.open(f)
                imgui.end_menu()
            imgui.separator()
            if imgui.menu_item_simple("Save screenshot", "F12", enabled=app.path is not None):
                self._save_screenshot()
            if imgui.menu_item_simple("Quit", "Ctrl+Q"):
                self._quit()
            imgui.end_menu()
        if imgui.begin_menu("View"):
            for kind, key in (("equirect", "V"), ("perspective", "V")):
                if imgui.menu_item_simple(kind.capitalize(), key, app.view_kind == kind):
                    app.set_view(kind)
            imgui.separator()
            if imgui.menu_item_simple("Fit", "F"):
                app.set_view("equirect")
                app.fit()
            if imgui.menu_item_simple("1:1", "Z"):
                app.set_view("equirect")
                app.one_to_one()
            imgui.end_menu()
        if imgui.begin_menu("Layer"):
            avail = app.available()
            for name, key in zip(LAYERS, KEYS):
                if imgui.menu_item_simple(name, key, app.layer == name, name in avail):
                    app.set_layer(name)
            if app.gt is not None:
                imgui.separator()
                if imgui.menu_item_simple("Show ground truth", "G", app.show_gt):
                    app.set_source(not app.show_gt)
            imgui.end_menu()
        if imgui.begin_menu("Model"):
            can = app.path is not None and not app.busy
            if imgui.menu_item_simple("Predict all layers and compare with the file's", enabled=can):
                app.open(app.path, compare=True)
            if imgui.menu_item_simple("Cancel", "Esc", enabled=app.busy):
                app.cancel()
            imgui.end_menu()
        if imgui.begin_menu("Help"):
            if imgui.menu_item_simple("Keys and mouse", "H"):
                self._show_help = True
            imgui.end_menu()
        imgui.end_main_menu_bar()

    def _view_window(self, fw: int, fh: int) -> None:
        """An undecorated window over the view: an invisible button takes the mouse."""
        app = self.app
        s = self.fb_scale
        x, y, w, h = app.view_rect()
        imgui.set_next_window_pos(imgui.ImVec2(x / s, y / s))
        imgui.set_next_window_size(imgui.ImVec2(w / s, h / s))
        imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(0, 0))
        imgui.push_style_var(imgui.StyleVar_.window_border_size, 0.0)
        flags = (_FLAGS_FIXED | imgui.WindowFlags_.no_background | imgui.WindowFlags_.no_scrollbar
                 | imgui.WindowFlags_.no_scroll_with_mouse | imgui.WindowFlags_.no_focus_on_appearing)
        imgui.begin("##view", None, flags)
        imgui.invisible_button("view", imgui.ImVec2(max(1.0, w / s), max(1.0, h / s)))
        io = self.io
        mx, my = (io.mouse_pos.x - x / s) * s, (io.mouse_pos.y - y / s) * s  # framebuffer px in the view
        hovered = imgui.is_item_hovered()
        # inserted objects first: the gizmo, click-to-drop and dragging take the mouse from the view
        took = app.objects.gizmo((x / s, y / s, w / s, h / s), (w, h))
        took = app.objects.view_mouse(hovered, imgui.is_item_activated(), imgui.is_item_active(),
                                      imgui.is_item_deactivated(), bool(io.mouse_delta.x or io.mouse_delta.y),
                                      mx, my) or took
        if imgui.is_item_activated():
            self._dragged = took
        if not took and imgui.is_item_active() and imgui.is_mouse_dragging(0, 2.0):
            d = io.mouse_delta
            if d.x or d.y:
                app.drag(d.x * s, d.y * s)
                self._dragged = True
        if imgui.is_item_deactivated() and not self._dragged and hovered:
            app.click(mx, my)
        if hovered and io.mouse_wheel:
            app.scroll(io.mouse_wheel, mx, my)
        if hovered or imgui.is_item_active():
            app.hover_at(mx, my)
        else:
            app.hover_at(None, None)
        dl = imgui.get_window_draw_list()
        self._pixel_values(dl, x / s, y / s)
        for m in app.markers():
            r = 9.0 * self.scale
            p = imgui.ImVec2(x / s + m.x / s + r + 2, y / s + m.y / s - r - 8 * self.scale)
            dl.add_text(imgui.ImVec2(p.x + 1, p.y + 1), col32(0, 0, 0), m.label)
            dl.add_text(p, col32(*m.colour), m.label)
        imgui.end()
        imgui.pop_style_var(2)

    def _pixel_values(self, dl, ox: float, oy: float) -> None:
        """Print every visible pixel's value when zoomed in far enough (equirect view)."""
        app = self.app
        if app.view_kind != "equirect" or app.size is None:
            return
        a = app.shown_arrays.get(app.layer)
        if a is None:
            return
        view, s = app.view, self.fb_scale
        H, W = app.size
        scale_x = a.shape[1] / W  # array pixels per panorama pixel (the probe atlas differs)
        if view.zoom / scale_x / s < VALUES_ZOOM:
            return
        _, _, w, h = app.view_rect()
        u0, v0 = view.screen_to_uv(0.0, 0.0, (w, h))
        u1, v1 = view.screen_to_uv(float(w), float(h), (w, h))
        hh, ww = a.shape[:2]
        j0, j1 = max(0, int(u0 * scale_x)), min(ww - 1, int(u1 * scale_x))
        i0, i1 = max(0, int(v0 * hh / H)), min(hh - 1, int(v1 * hh / H))
        colours = ((1, 0.45, 0.45), (0.45, 1, 0.45), (0.5, 0.6, 1)) if a.shape[2] == 3 else ((1, 1, 1),)
        line = imgui.get_text_line_height()
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                cx, cy, _ = view.uv_to_screen((j + 0.5) / scale_x, (i + 0.5) * H / hh, (w, h))
                vals = a[i, j]
                top = oy + cy / s - line * len(vals) / 2
                for c, val in enumerate(vals):
                    t = _fmt(float(val))
                    tw = imgui.calc_text_size(t).x
                    p = imgui.ImVec2(ox + cx / s - tw / 2, top + c * line)
                    dl.add_text(imgui.ImVec2(p.x + 1, p.y + 1), col32(0, 0, 0), t)
                    dl.add_text(p, col32(*colours[c % len(colours)]), t)

    def _side_panel(self, W: float, H: float) -> None:
        app = self.app
        top = self.bar_height()
        pw = PANEL_WIDTH * self.scale
        imgui.set_next_window_pos(imgui.ImVec2(W - pw, top))
        imgui.set_next_window_size(imgui.ImVec2(pw, H - 2 * top))
        imgui.begin("##panel", None, _FLAGS_FIXED)
        imgui.text(app.name or "(no file)")
        if app.busy:
            frac, text = app.progress or (None, "")
            if frac is None:  # indeterminate: a moving bar
                frac = (time.monotonic() * 0.5) % 1.0
            imgui.progress_bar(frac, imgui.ImVec2(-60 * self.scale, 0), text or "working")
            imgui.same_line()
            if imgui.button("Cancel"):
                app.cancel()
        if imgui.collapsing_header("Layers", imgui.TreeNodeFlags_.default_open):
            self._layers()
        if imgui.collapsing_header("Display", imgui.TreeNodeFlags_.default_open):
            self._display()
        if imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
            self._view_controls()
        if imgui.collapsing_header("Read-out", imgui.TreeNodeFlags_.default_open):
            self._readout()
        if imgui.collapsing_header(f"Probes ({len(app.pins)})###probes", imgui.TreeNodeFlags_.default_open):
            self._probes()
        if imgui.collapsing_header(f"Objects ({len(app.objects.objects)})###objects"):
            app.objects.build_ui()
        if imgui.collapsing_header("Messages"):
            for m in list(app.messages)[::-1]:
                imgui.push_text_wrap_pos(0)
                imgui.text_colored(imgui.ImVec4(*LEVEL_COLOURS.get(m.level, (0.8, 0.8, 0.8, 1))), m.text)
                imgui.pop_text_wrap_pos()
        imgui.end()

    def _layers(self) -> None:
        app = self.app
        avail = app.available()
        if app.gt is not None:
            if imgui.radio_button("prediction", not app.show_gt):
                app.set_source(False)
            imgui.same_line()
            if imgui.radio_button("ground truth (G)", app.show_gt):
                app.set_source(True)
        for k, (name, key) in enumerate(zip(LAYERS, KEYS)):
            if k % 2:
                imgui.same_line(170 * self.scale)
            present = name in avail
            if not present:
                imgui.begin_disabled()
            if imgui.radio_button(f"{key} {name}", app.layer == name):
                app.set_layer(name)
            if not present:
                imgui.end_disabled()
            if imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
                why = "" if present else (" (computing...)" if app.busy else " (not available)")
                imgui.set_tooltip(SPECS[name].help + why)

    def _display(self) -> None:
        app = self.app
        spec = SPECS[app.layer]
        if spec.kind == "hdr":
            ch, ev = imgui.slider_float("exposure (E)", app.hdr.exposure, -12.0, 12.0, "%+.1f EV")
            if ch:
                app.set_exposure(ev)
            ch, off = imgui.slider_float("offset (O)", app.hdr.offset, -1.0, 1.0, "%+.3f")
            if ch:
                app.set_offset(off)
            ch, i = imgui.combo("tone map (T)", TONEMAPS.index(app.hdr.tonemap),
                                ["sRGB", "ACES", "false colour"])
            if ch:
                app.set_tonemap(TONEMAPS[i])
            if app.hdr.tonemap == "false":
                lo, hi = app.hdr.false_range
                self._colour_bar("turbo", f"{lo:+.0f} EV", f"{hi:+.0f} EV")
        elif spec.kind == "scalar":
            sd = app.scalar[app.layer]
            ch, i = imgui.combo("colour map (C)", COLORMAPS.index(sd.colormap), list(COLORMAPS))
            if ch:
                app.set_colormap(COLORMAPS[i])
            lo, hi = sd.range
            speed = max(1e-3, (hi - lo) / 200)
            ch, lo2, hi2 = imgui.drag_float_range2("range", lo, hi, speed, 0.0, 0.0, "%.4g", "%.4g")
            if ch and hi2 > lo2:
                app.set_range(lo2, hi2)
            imgui.same_line()
            if imgui.small_button("auto"):
                app.set_range(None)
            self._colour_bar(sd.colormap, _fmt(lo) + spec.unit, _fmt(hi) + spec.unit)
        else:
            imgui.push_text_wrap_pos(0)
            note = "normal n shown as 0.5 n + 0.5 (x red, y green, z blue)" if spec.kind == "normal" \
                else "base colour shown as sRGB"
            imgui.text_disabled(note)
            imgui.pop_text_wrap_pos()

    def _colour_bar(self, name: str, lo: str, hi: str) -> None:
        if name not in self._lut_cache:
            self._lut_cache[name] = colormap_lut(name, 64)
        lut = self._lut_cache[name]
        dl = imgui.get_window_draw_list()
        p = imgui.get_cursor_screen_pos()
        w = imgui.get_content_region_avail().x
        h = 10 * self.scale
        n = len(lut)
        for k, c in enumerate(lut):
            x0, x1 = p.x + w * k / n, p.x + w * (k + 1) / n + 1
            dl.add_rect_filled(imgui.ImVec2(x0, p.y), imgui.ImVec2(x1, p.y + h), col32(*c))
        imgui.dummy(imgui.ImVec2(w, h))
        imgui.text(lo)
        imgui.same_line(max(0.0, w - imgui.calc_text_size(hi).x))
        imgui.text(hi)

    def _view_controls(self) -> None:
        app = self.app
        if imgui.radio_button("equirect", app.view_kind == "equirect"):
            app.set_view("equirect")
        imgui.same_line()
        if imgui.radio_button("perspective (V)", app.view_kind == "perspective"):
            app.set_view("perspective")
        if app.view_kind == "equirect":
            if imgui.button("Fit (F)"):
                app.fit()
            imgui.same_line()
            if imgui.button("1:1 (Z)"):
                app.one_to_one()
            imgui.same_line()
            imgui.text(f"zoom {100 * app.view.zoom:.0f}%")
        else:
            v = app.view
            ch, fov = imgui.slider_float("field of view", v.fov, 10.0, 150.0, "%.0f deg")
            if ch:
                app.set_view(fov=fov)
            imgui.text(f"yaw {math.degrees(v.yaw):+.1f} deg, pitch {math.degrees(v.pitch):+.1f} deg")
            imgui.same_line()
            if imgui.small_button("reset"):
                app.set_view(yaw=0.0, pitch=0.0, fov=75.0)

    def _readout(self) -> None:
        app = self.app
        if app.hover is None or app.size is None:
            imgui.text_disabled("hover over the panorama; click to pin a probe")
            return
        u, v = app.hover
        H, W = app.size
        lon = 360 * u / W - 180
        lat = 90 - 180 * v / H
        d = self._direction(u, v)
        imgui.text(f"pixel col {int(u)}, row {int(v)}   (u {u:.1f}, v {v:.1f})")
        imgui.text(f"lon {lon:+.2f}, lat {lat:+.2f} deg")
        imgui.text(f"dir ({d[0]:+.3f}, {d[1]:+.3f}, {d[2]:+.3f})")
        sources = [("pred", app.arrays)] + ([("gt", app.gt_arrays)] if app.gt is not None else [])
        flags = imgui.TableFlags_.borders_inner_h | imgui.TableFlags_.sizing_fixed_fit
        if imgui.begin_table("values", 1 + len(sources), flags):
            imgui.table_setup_column("layer")
            for src, _ in sources:
                title = "value" if len(sources) == 1 else ("predicted" if src == "pred" else "true")
                imgui.table_setup_column(title)
            imgui.table_headers_row()
            vals = {src: app.pin_values(u, v, src) for src, _ in sources}
            for name in LAYERS:
                if not any(name in vals[src] for src, _ in sources):
                    continue
                imgui.table_next_row()
                imgui.table_next_column()
                imgui.text(name)
                for src, _ in sources:
                    imgui.table_next_column()
                    imgui.text(fmt_value(vals[src][name]) if name in vals[src] else "-")
            imgui.end_table()

    def _direction(self, u: float, v: float) -> np.ndarray:
        H, W = self.app.size
        return pano.uv_to_dir(torch.tensor(u, dtype=torch.float64), torch.tensor(v, dtype=torch.float64),
                              H, W).numpy()

    def _probes(self) -> None:
        app = self.app
        if not app.pins:
            imgui.text_disabled("click the view to pin a probe")
            return
        if imgui.small_button("remove all"):
            while app.pins:
                app.unpin()
        remove = None
        avail_w = imgui.get_content_region_avail().x
        self.probe_rects.clear()
        for k, pin in enumerate(app.pins):
            imgui.push_id(k)
            dl = imgui.get_window_draw_list()
            p = imgui.get_cursor_screen_pos()
            sz = imgui.get_text_line_height()
            dl.add_rect_filled(p, imgui.ImVec2(p.x + sz, p.y + sz), col32(*pin.colour))
            imgui.dummy(imgui.ImVec2(sz, sz))
            imgui.same_line()
            imgui.text(f"probe {k + 1} at col {pin.u:.1f}, row {pin.v:.1f}")
            imgui.same_line()
            if imgui.small_button("x"):
                remove = k
            pairs = [("pred", "predicted" if app.gt is not None else None)]
            if pin.probe_gt is not None:
                pairs.append(("gt", "true"))
            if pin.probe is None and pin.probe_gt is None:
                imgui.text_disabled("no light probes yet" + (" (computing...)" if app.busy else ""))
            else:
                h, w = (pin.probe if pin.probe is not None else pin.probe_gt).shape[1:]
                cell = (avail_w - 8 * self.scale * (len(pairs) - 1)) / len(pairs)
                f = max(1, int(cell * self.fb_scale // w))  # integer texel size: texels stay square
                size = (w * f, h * f)
                for n, (which, label) in enumerate(pairs):
                    if n:
                        imgui.same_line()
                    imgui.begin_group()
                    if label:
                        imgui.text(label)
                    tex = app.probe_image(pin, which, size)
                    if tex is None:
                        imgui.text_disabled("-")
                    else:
                        imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(size[0] / self.fb_scale,
                                                                               size[1] / self.fb_scale),
                                    imgui.ImVec2(0, 1), imgui.ImVec2(1, 0))
                        mn, mx = imgui.get_item_rect_min(), imgui.get_item_rect_max()
                        self.probe_rects[(k, which)] = (mn.x, mn.y, mx.x, mx.y)
                    imgui.end_group()
                ch, ev = imgui.slider_float("probe EV", pin.exposure, -12.0, 12.0, "%+.1f EV")
                if ch:
                    app.set_pin_exposure(k, ev)
            if self.scroll_to_pin == k:  # a new pin: bring its probe into view
                imgui.set_scroll_here_y(1.0)
                self.scroll_to_pin = None
            if pin.block is not None:
                imgui.text(f"grid cell (row {pin.block[0]}, col {pin.block[1]}), bilinear between cells")
            if pin.position is not None:
                x, y, z = pin.position
                imgui.text(f"probe at ({x:+.3f}, {y:+.3f}, {z:+.3f}) m")
            if pin.point is not None:
                imgui.text(f"surface at {np.linalg.norm(pin.point):.3f} m")
            for name in ("normal", "albedo", "roughness", "metallic"):
                if name in pin.surface:
                    imgui.text(f"  {name}: {fmt_value(pin.surface[name])}")
            imgui.separator()
            imgui.pop_id()
        if remove is not None:
            app.unpin(remove)

    def _status_bar(self, W: float, H: float) -> None:
        app = self.app
        bh = self.bar_height()
        imgui.set_next_window_pos(imgui.ImVec2(0, H - bh))
        imgui.set_next_window_size(imgui.ImVec2(W, bh))
        imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(6 * self.scale, 3 * self.scale))
        imgui.begin("##status", None, _FLAGS_FIXED | imgui.WindowFlags_.no_scrollbar)
        parts = []
        if app.hover is not None and app.size is not None:
            u, v = app.hover
            vals = app.pin_values(u, v).get(app.layer)
            parts.append(f"col {int(u)} row {int(v)}")
            if vals is not None:
                parts.append(f"{app.layer} {fmt_value(vals)}")
        if app.frame_times:
            parts.append(f"frame {1000 * app.frame_times[-1]:.0f} ms")
        if app.busy and app.job_frames:
            parts.append(f"longest frame while busy {1000 * app.job_max_frame:.0f} ms")
        last = app.messages[-1] if app.messages else None
        imgui.text("   ".join(parts))
        if last is not None:
            imgui.same_line()
            colour = LEVEL_COLOURS.get(last.level, (0.7, 0.7, 0.7, 1))
            imgui.text_colored(imgui.ImVec4(*colour), "  " + last.text)
        imgui.end()
        imgui.pop_style_var()

    def _error_banner(self, fw: int, fh: int) -> None:
        app = self.app
        if not app.error:
            return
        s = self.fb_scale
        x, y, w, _ = app.view_rect()
        imgui.set_next_window_pos(imgui.ImVec2(x / s + 10 * self.scale, y / s + 10 * self.scale))
        imgui.set_next_window_size(imgui.ImVec2(w / s - 20 * self.scale, 0))
        imgui.push_style_color(imgui.Col_.window_bg, imgui.ImVec4(*ERROR_BG))
        flags = _FLAGS_FIXED | imgui.WindowFlags_.always_auto_resize
        flags |= imgui.WindowFlags_.no_focus_on_appearing
        flags &= ~imgui.WindowFlags_.no_bring_to_front_on_focus  # over the view window
        imgui.begin("##error", None, flags)
        imgui.push_text_wrap_pos(0)
        imgui.text(app.error)
        imgui.pop_text_wrap_pos()
        if imgui.small_button("dismiss"):
            app.error = None
        imgui.end()
        imgui.pop_style_color()

    def _open_popups(self) -> None:
        app = self.app
        if self._path_popup:
            imgui.open_popup("Open path")
            self._path_popup = False
        if imgui.begin_popup_modal("Open path", None, imgui.WindowFlags_.always_auto_resize)[0]:
            imgui.text("Panorama (.hdr, .exr, .png, .jpg) or scene file (.exr):")
            if imgui.is_window_appearing():
                imgui.set_keyboard_focus_here()
            imgui.set_next_item_width(520 * self.scale)
            enter, self._path_text = imgui.input_text("##path", self._path_text,
                                                      imgui.InputTextFlags_.enter_returns_true)
            if (imgui.button("Open") or enter) and self._path_text.strip():
                app.open(os.path.expanduser(self._path_text.strip()))
                imgui.close_current_popup()
            imgui.same_line()
            if imgui.button("Cancel") or imgui.is_key_pressed(imgui.Key.escape):
                imgui.close_current_popup()
            imgui.end_popup()

    def open_dialog(self) -> None:
        """The system's file dialog when one is installed, else the "open path" popup."""
        if sys.platform.startswith("linux") and not any(shutil.which(t) for t in
                                                        ("zenity", "kdialog", "qarma", "matedialog")):
            self._path_popup = True
            return
        from imgui_bundle import portable_file_dialogs as pfd

        start = os.path.dirname(self.app.path) if self.app.path else os.getcwd()
        filters = ["Panoramas and scenes", "*.hdr *.exr *.png *.jpg *.jpeg", "All files", "*"]
        self._dialog = pfd.open_file("Open a panorama or scene", start, filters)

    def _poll_dialog(self) -> None:
        if self._dialog is not None and self._dialog.ready(0):
            files = self._dialog.result()
            self._dialog = None
            if files:
                self.app.open(files[0])

    def _save_screenshot(self) -> None:
        app = self.app
        stem = os.path.splitext(app.path or "phyir-view")[0]
        out = f"{stem}.{app.layer}.png"
        try:
            app.screenshot(out)
            app.note("info", f"saved {out}")
        except Exception as e:  # noqa: BLE001 - e.g. a read-only folder: report, keep running
            app.note("error", f"cannot save {out}: {e}")

    def _quit(self) -> None:
        self.quit_requested = True
        if self.app.window is not None:
            import glfw

            glfw.set_window_should_close(self.app.window, True)

    def _help_window(self) -> None:
        imgui.set_next_window_size(imgui.ImVec2(430 * self.scale, 0), imgui.Cond_.appearing)
        opened, keep = imgui.begin("Keys and mouse", True)
        if opened:
            for k, t in HELP:
                imgui.text(f"{k:<16}{t}")
        imgui.end()
        if not keep:
            self._show_help = False

    # -- keyboard ----------------------------------------------------------------------------------
    def _keys(self) -> None:
        app, io = self.app, self.io
        K = imgui.Key
        pressed = imgui.is_key_pressed
        shift = io.key_shift
        if io.key_ctrl:
            if pressed(K.o):
                self.open_dialog()
            if pressed(K.q):
                self._quit()
            return
        digits = [K._1, K._2, K._3, K._4, K._5, K._6, K._7, K._8, K._9, K._0, K.minus]
        for name, key in zip(LAYERS, digits):
            if pressed(key, False) and name in app.available():
                app.set_layer(name)
        if pressed(K.e):
            app.set_exposure(app.hdr.exposure + (-EV_STEP if shift else EV_STEP))
        if pressed(K.o):
            app.set_offset(app.hdr.offset + (-OFFSET_STEP if shift else OFFSET_STEP))
        if pressed(K.r, False):
            app.set_exposure(0.0)
            app.set_offset(0.0)
        if pressed(K.t, False):
            app.set_tonemap(_cycle(TONEMAPS, app.hdr.tonemap, -1 if shift else 1))
        if pressed(K.c, False) and app.layer in app.scalar:
            sd = app.scalar[app.layer]
            app.set_colormap(_cycle(COLORMAPS, sd.colormap, -1 if shift else 1))
        if pressed(K.f, False):
            app.set_view("equirect")
            app.fit()
        if pressed(K.z, False):
            app.set_view("equirect")
            app.one_to_one()
        if pressed(K.v, False):
            app.set_view("perspective" if app.view_kind == "equirect" else "equirect")
        if pressed(K.g, False) and app.gt is not None:
            app.set_source(not app.show_gt)
        if pressed(K.backspace, False) or pressed(K.delete, False):
            app.unpin()
        if pressed(K.escape, False):
            if app.error:
                app.error = None
            elif app.busy:
                app.cancel()
        if pressed(K.h, False):
            self._show_help = not self._show_help
        if pressed(K.f12, False):
            self._save_screenshot()


def _cycle(options: tuple[str, ...], current: str, step: int) -> str:
    return options[(options.index(current) + step) % len(options)]


HELP = (
    ("1-9, 0, -", "layers: " + ", ".join(LAYERS)),
    ("G", "prediction / ground truth"),
    ("E / Shift+E", "exposure +/- 0.5 EV"),
    ("O / Shift+O", "offset +/- 0.05"),
    ("R", "reset exposure and offset"),
    ("T / C", "next tone map / colour map"),
    ("F / Z", "fit / 1:1 (equirect view)"),
    ("V", "equirect / perspective view"),
    ("drag", "pan (equirect) / look around"),
    ("wheel", "zoom (equirect) / field of view"),
    ("click", "pin the probe under the mouse"),
    ("Backspace", "remove the last probe"),
    ("Esc", "dismiss the error / cancel the model"),
    ("Ctrl+O", "open a file (or drop it on the window)"),
    ("F12", "save a screenshot next to the file"),
    ("H", "this help"),
)
