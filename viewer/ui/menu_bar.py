"""The menu bar and what its File and Help menus open: the file dialog or the "open path"
popup, screenshots, quitting and the keys-and-mouse help."""

from __future__ import annotations

import os
import shutil
import sys

from phyir.errors import PhyIRError
from viewer.compare import MODES
from viewer.layers import KEYS, LAYERS
from viewer.ui.images_panel import MODE_NAMES
from viewer.ui.object_keys import OBJECT_KEYS, OBJECT_MOUSE
from viewer.ui.widgets import imgui


class MenuBar:
    """Part of :class:`viewer.ui.gui.Gui` (``gui``: its scale): the menu bar, file dialogs and the
    help window (``show_help``; ``help_lines`` keeps each line drawn and where, for tests)."""

    def __init__(self, app, gui):
        self.app = app
        self.gui = gui
        self._dialog = None          # portable_file_dialogs.open_file in flight
        self._path_popup = False     # the fallback "open path" popup
        self._path_text = ""
        self.show_help = False
        self.help_lines: list[tuple[str, float, float]] = []
        self.quit_requested = False

    def animating(self) -> bool:
        """A file dialog is open: frames go on until it answers."""
        return self._dialog is not None

    def draw(self) -> None:
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
                        app.images.add(f)
                imgui.end_menu()
            if imgui.menu_item_simple("Reload", "Ctrl+R", enabled=app.doc.path is not None):
                app.images.reload()
            if imgui.menu_item_simple("Close image", "Ctrl+W", enabled=app.images.entry.source is not None):
                app.images.close()
            _, app.images.watch = imgui.menu_item("Reload when the file changes", "", app.images.watch)
            imgui.separator()
            if imgui.menu_item_simple("Save screenshot", "F12", enabled=app.doc.path is not None):
                self.save_screenshot()
            scene = app.doc.scene is not None
            if imgui.menu_item_simple("Export glTF (room, lights, objects)", enabled=scene):
                self._export_gltf()
            if imgui.menu_item_simple("Quit", "Ctrl+Q"):
                self.request_quit()
            imgui.end_menu()
        if imgui.begin_menu("View"):
            for kind, key in (("equirect", "V"), ("perspective", "V")):
                if imgui.menu_item_simple(kind.capitalize(), key, app.camera.view_kind == kind):
                    app.camera.set_view(kind)
            imgui.separator()
            if imgui.menu_item_simple("Fit", "F"):
                app.camera.set_view("equirect")
                app.camera.fit()
            if imgui.menu_item_simple("1:1", "Z"):
                app.camera.set_view("equirect")
                app.camera.one_to_one()
            imgui.end_menu()
        if imgui.begin_menu("Images"):
            self._images_menu()
            imgui.end_menu()
        if imgui.begin_menu("Layer"):
            avail = app.doc.available()
            for name, key in zip(LAYERS, KEYS):
                if imgui.menu_item_simple(name, key, app.display.layer == name, name in avail):
                    app.display.set_layer(name)
            if app.doc.gt is not None:
                imgui.separator()
                if imgui.menu_item_simple("Show ground truth", "G", app.doc.show_gt):
                    app.display.set_source(not app.doc.show_gt)
            imgui.end_menu()
        if imgui.begin_menu("Model"):
            can = app.doc.path is not None and not app.loader.busy
            if imgui.menu_item_simple("Predict all layers and compare with the file's", enabled=can):
                app.open(app.doc.path, compare=True)
            if imgui.menu_item_simple("Cancel", "Esc", enabled=app.loader.busy):
                app.images.cancel()
            imgui.end_menu()
        if imgui.begin_menu("Help"):
            if imgui.menu_item_simple("Keys and mouse", "H"):
                self.show_help = True
            imgui.end_menu()
        imgui.end_main_menu_bar()

    def open_popups(self) -> None:
        app = self.app
        if self._path_popup:
            imgui.open_popup("Open path")
            self._path_popup = False
        if imgui.begin_popup_modal("Open path", None, imgui.WindowFlags_.always_auto_resize)[0]:
            imgui.text("Panorama (.hdr, .exr, .png, .jpg) or scene file (.exr):")
            if imgui.is_window_appearing():
                imgui.set_keyboard_focus_here()
            imgui.set_next_item_width(520 * self.gui.scale)
            enter, self._path_text = imgui.input_text("##path", self._path_text,
                                                      imgui.InputTextFlags_.enter_returns_true)
            if (imgui.button("Open") or enter) and self._path_text.strip():
                app.images.add(os.path.expanduser(self._path_text.strip()))
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

        start = os.path.dirname(self.app.doc.path) if self.app.doc.path else os.getcwd()
        filters = ["Panoramas and scenes", "*.hdr *.exr *.png *.jpg *.jpeg", "All files", "*"]
        self._dialog = pfd.open_file("Open panoramas or scenes", start, filters, pfd.opt.multiselect)

    def poll_dialog(self) -> None:
        if self._dialog is not None and self._dialog.ready(0):
            files = self._dialog.result()
            self._dialog = None
            for k, f in enumerate(files or ()):  # added to the open images, the first shown
                self.app.images.add(f) if k == 0 else self.app.images.queue(f)

    def _images_menu(self) -> None:
        """The open images (select one), switching, the reference and the comparison modes."""
        app = self.app
        for k, e in enumerate(app.images):
            if imgui.menu_item_simple(f"{k + 1} {app.images.label(e)}", "", k == app.images.current):
                app.images.select(k)
        imgui.separator()
        many = len(app.images) > 1
        if imgui.menu_item_simple("Next image", "] / PageDown", enabled=many):
            app.images.next(1)
        if imgui.menu_item_simple("Previous image", "[ / PageUp", enabled=many):
            app.images.next(-1)
        if imgui.menu_item_simple("Use as reference", "Shift+R", app.images.reference is app.images.entry):
            app.images.set_reference(None if app.images.reference is app.images.entry else app.images.current)
        for mode in (None, *MODES):
            if imgui.menu_item_simple(f"Compare: {MODE_NAMES[mode]}", "D", app.comparison.mode == mode,
                                      app.images.reference is not None):
                app.comparison.set_mode(mode)

    def save_screenshot(self) -> None:
        self.app.request_screenshot()

    def _export_gltf(self) -> None:
        try:
            self.app.objects.export_gltf()
        except (PhyIRError, OSError) as e:  # a scene without depth, a read-only folder: say so, keep running
            self.app.messages.note("error", f"export: {e}")

    def request_quit(self) -> None:
        self.quit_requested = True
        if self.app.window is not None:
            import glfw

            glfw.set_window_should_close(self.app.window, True)

    def help_window(self) -> None:
        """Every key and mouse action, in sections laid out in two columns, the window sized to them
        (at 1x it fits a 1394x556 window) and centred on the view; ``help_lines`` keeps each line
        drawn and where (screen px), for tests."""
        s, sc = self.gui.fb_scale, self.gui.scale
        x, y, w, h = self.app.view_rect()
        imgui.set_next_window_pos(imgui.ImVec2((x + w / 2) / s, (y + h / 2) / s), imgui.Cond_.always,
                                  imgui.ImVec2(0.5, 0.5))
        flags = (imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse
                 | imgui.WindowFlags_.no_saved_settings)
        opened, keep = imgui.begin("Keys and mouse", True, flags)
        self.help_lines = []
        if opened:
            sections = help_sections()
            key_w = max(imgui.calc_text_size(k).x for _, rows in sections for k, _ in rows) + 12 * sc
            for c, column in enumerate(_columns(sections, 2)):
                if c:
                    imgui.same_line(0.0, 28 * sc)
                imgui.begin_group()
                for n, (title, rows) in enumerate(column):
                    if n:
                        imgui.spacing()
                    self._help_line(title, disabled=True)
                    for keys, what in rows:
                        self._help_line(keys)
                        imgui.same_line(key_w)  # from the group's left edge
                        self._help_line(what)
                imgui.end_group()
        imgui.end()
        if not keep:
            self.show_help = False

    def _help_line(self, text: str, disabled: bool = False) -> None:
        p = imgui.get_cursor_screen_pos()
        (imgui.text_disabled if disabled else imgui.text)(text)
        self.help_lines.append((text, p.x, p.y))


HELP = (
    ("Layers and display", (
        ("1-9, 0, -", "layers (numbered in the side panel)"),
        ("G", "prediction / ground truth"),
        ("E / Shift+E", "exposure +/- 0.5 EV"),
        ("O / Shift+O", "offset +/- 0.05"),
        ("R", "reset exposure and offset"),
        ("T / C", "next tone map / colour map"),
        ("X / Shift+X", "channel: RGB, R, G, B, luminance"),
    )),
    ("View and probes", (
        ("F / Z", "fit / 1:1 (equirect view)"),
        ("V", "equirect / perspective view"),
        ("drag", "pan (equirect) / look around"),
        ("wheel", "zoom (equirect) / field of view"),
        ("click", "pin the probe under the mouse"),
        ("Backspace", "remove the last probe (also Delete)"),
    )),
    ("Images and comparison", (
        ("] / [", "next / previous image (PageDown / PageUp)"),
        ("Shift+R", "the image shown is the reference (again: none)"),
        ("D / Shift+D", "compare: diff, reldiff, sqerr, split, off"),
        ("drag the line", "split view: move the divide"),
    )),
    ("Files and the app", (
        ("Ctrl+O", "open files (or drop them on the window)"),
        ("Ctrl+W", "close the image shown"),
        ("Ctrl+R", "reload the file (File menu: on every change)"),
        ("F12", "save a screenshot next to the file"),
        ("Esc", "dismiss the error / cancel the model"),
        ("Ctrl+Q", "quit"),
        ("H", "this help"),
    )),
)


def help_sections() -> list[tuple[str, tuple[tuple[str, str], ...]]]:
    """The help window's sections: :data:`HELP`, then the objects' mouse actions and every key of
    :data:`viewer.ui.object_keys.OBJECT_KEYS` (read from the bindings themselves)."""
    objects = OBJECT_MOUSE + tuple((k.label, k.help) for k in OBJECT_KEYS)
    return [*HELP, ("Inserted objects (side panel: Objects)", objects)]


def _columns(sections: list, n: int) -> list[list]:
    """``sections`` in order over ``n`` columns of about the same number of lines."""
    sizes = [len(rows) + 2 for _, rows in sections]  # + the title and the space before it
    target, out, count = sum(sizes) / n, [[]], 0
    for section, size in zip(sections, sizes):
        if out[-1] and count + size / 2 > target * len(out) and len(out) < n:
            out.append([])
        out[-1].append(section)
        count += size
    return out
