"""Input: the view's mouse (objects first, then pan, pin, zoom and hover; pixel values when
zoomed in) and the keyboard shortcuts."""

from __future__ import annotations

from viewer.layers import LAYERS
from viewer.renderer import CHANNELS, COLORMAPS, TONEMAPS
from viewer.ui.object_keys import handle_object_keys
from viewer.ui.widgets import FLAGS_FIXED, col32, fmt_number, imgui

VALUES_ZOOM = 56.0     # logical px per panorama pixel above which pixel values are printed
EV_STEP, OFFSET_STEP = 0.5, 0.05  # keys E and O


class ViewInput:
    """Part of :class:`viewer.ui.gui.Gui` (``gui``: its scale and imgui io): mouse over the view and
    keys, handed on to the menu bar's actions and the images' and objects' panels."""

    def __init__(self, app, gui, menu, images_panel, objects_panel):
        self.app = app
        self.gui = gui
        self.menu = menu
        self.images_panel = images_panel
        self.objects_panel = objects_panel
        self._dragged = False

    def view_window(self, fw: int, fh: int) -> None:
        """An undecorated window over the view: an invisible button takes the mouse."""
        app = self.app
        s = self.gui.fb_scale
        x, y, w, h = app.view_rect()
        imgui.set_next_window_pos(imgui.ImVec2(x / s, y / s))
        imgui.set_next_window_size(imgui.ImVec2(w / s, h / s))
        imgui.push_style_var(imgui.StyleVar_.window_padding, imgui.ImVec2(0, 0))
        imgui.push_style_var(imgui.StyleVar_.window_border_size, 0.0)
        flags = (FLAGS_FIXED | imgui.WindowFlags_.no_background | imgui.WindowFlags_.no_scrollbar
                 | imgui.WindowFlags_.no_scroll_with_mouse | imgui.WindowFlags_.no_focus_on_appearing)
        imgui.begin("##view", None, flags)
        imgui.invisible_button("view", imgui.ImVec2(max(1.0, w / s), max(1.0, h / s)))
        io = self.gui.io
        mx, my = (io.mouse_pos.x - x / s) * s, (io.mouse_pos.y - y / s) * s  # framebuffer px in the view
        hovered = imgui.is_item_hovered()
        # inserted objects first: the gizmo, click-to-drop and dragging take the mouse from the view
        activated, active = imgui.is_item_activated(), imgui.is_item_active()
        took = self.images_panel.split_mouse(hovered, activated, active, mx, w)
        took = self.objects_panel.gizmo((x / s, y / s, w / s, h / s), (w, h)) or took
        moved = bool(io.mouse_delta.x or io.mouse_delta.y)
        took = self.objects_panel.view_mouse(hovered, imgui.is_item_activated(), imgui.is_item_active(),
                                             imgui.is_item_deactivated(), moved, mx, my) or took
        if imgui.is_item_activated():
            self._dragged = took
        if not took and imgui.is_item_active() and imgui.is_mouse_dragging(0, 2.0):
            d = io.mouse_delta
            if d.x or d.y:
                app.camera.drag(d.x * s, d.y * s)
                self._dragged = True
        if imgui.is_item_deactivated() and not self._dragged and hovered:
            app.camera.click(mx, my)
        if hovered and io.mouse_wheel:
            app.camera.scroll(io.mouse_wheel, mx, my)
        if hovered or imgui.is_item_active():
            app.camera.hover_at(mx, my)
        else:
            app.camera.hover_at(None, None)
        dl = imgui.get_window_draw_list()
        self._pixel_values(dl, x / s, y / s)
        for m in app.composer.markers():
            r = 9.0 * self.gui.scale
            p = imgui.ImVec2(x / s + m.x / s + r + 2, y / s + m.y / s - r - 8 * self.gui.scale)
            dl.add_text(imgui.ImVec2(p.x + 1, p.y + 1), col32(0, 0, 0), m.label)
            dl.add_text(p, col32(*m.colour), m.label)
        imgui.end()
        imgui.pop_style_var(2)

    def _pixel_values(self, dl, ox: float, oy: float) -> None:
        """Print every visible pixel's value when zoomed in far enough (equirect view)."""
        app = self.app
        if app.camera.view_kind != "equirect" or app.doc.size is None:
            return
        a = app.doc.shown_arrays.get(app.display.layer)
        if a is None:
            return
        view, s = app.camera.view, self.gui.fb_scale
        H, W = app.doc.size
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
                    t = fmt_number(float(val))
                    tw = imgui.calc_text_size(t).x
                    p = imgui.ImVec2(ox + cx / s - tw / 2, top + c * line)
                    dl.add_text(imgui.ImVec2(p.x + 1, p.y + 1), col32(0, 0, 0), t)
                    dl.add_text(p, col32(*colours[c % len(colours)]), t)

    # -- keyboard ----------------------------------------------------------------------------------
    def handle_keys(self) -> None:
        app, io = self.app, self.gui.io
        K = imgui.Key
        pressed = imgui.is_key_pressed
        shift = io.key_shift
        handle_object_keys(self.objects_panel, shift, io.key_ctrl)  # viewer.ui.object_keys
        if io.key_ctrl:
            if pressed(K.o):
                self.menu.open_dialog()
            if pressed(K.q):
                self.menu.request_quit()
            if pressed(K.r, False) and app.doc.path is not None:
                app.images.reload()
            if pressed(K.w, False):
                app.images.close()
            return
        digits = [K._1, K._2, K._3, K._4, K._5, K._6, K._7, K._8, K._9, K._0, K.minus]
        for name, key in zip(LAYERS, digits):
            if pressed(key, False) and name in app.doc.available():
                app.display.set_layer(name)
        if pressed(K.e):
            app.display.set_exposure(app.display.hdr.exposure + (-EV_STEP if shift else EV_STEP))
        if pressed(K.o):
            app.display.set_offset(app.display.hdr.offset + (-OFFSET_STEP if shift else OFFSET_STEP))
        if pressed(K.r, False) and not shift:
            app.display.set_exposure(0.0)
            app.display.set_offset(0.0)
        self.images_panel.image_keys(shift)  # [ ] PageUp/PageDown, Shift+R, D (viewer.ui.images_panel)
        if pressed(K.x, False):
            app.display.set_channel(_cycle(CHANNELS, app.display.hdr.channel, -1 if shift else 1))
        if pressed(K.t, False):
            app.display.set_tonemap(_cycle(TONEMAPS, app.display.hdr.tonemap, -1 if shift else 1))
        if pressed(K.c, False) and app.display.layer in app.display.scalar:
            sd = app.display.scalar[app.display.layer]
            app.display.set_colormap(_cycle(COLORMAPS, sd.colormap, -1 if shift else 1))
        if pressed(K.f, False):
            app.camera.set_view("equirect")
            app.camera.fit()
        if pressed(K.z, False):
            app.camera.set_view("equirect")
            app.camera.one_to_one()
        if pressed(K.v, False):
            app.camera.set_view("perspective" if app.camera.view_kind == "equirect" else "equirect")
        if pressed(K.g, False) and app.doc.gt is not None:
            app.display.set_source(not app.doc.show_gt)
        if pressed(K.backspace, False) or pressed(K.delete, False):
            app.pins.unpin()
        if pressed(K.escape, False):
            if app.messages.error:
                app.messages.error = None
            elif app.loader.busy:
                app.images.cancel()
        if pressed(K.h, False):
            self.menu.show_help = not self.menu.show_help
        if pressed(K.f12, False):
            self.menu.save_screenshot()


def _cycle(options: tuple[str, ...], current: str, step: int) -> str:
    return options[(options.index(current) + step) % len(options)]
