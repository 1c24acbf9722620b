"""The side panel: the open images and the reference, layers, display settings, view controls, the
read-out under the mouse, the pinned probes, the inserted objects and the messages."""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from phyir import pano
from viewer.layers import KEYS, LAYERS, SPECS, histogram
from viewer.renderer import CHANNELS, COLORMAPS, TONEMAPS
from viewer.ui.widgets import (
    FLAGS_FIXED,
    LEVEL_COLOURS,
    PANEL_WIDTH,
    col32,
    colour_bar,
    fmt_number,
    fmt_value,
    imgui,
)


class SidePanel:
    """Part of :class:`viewer.ui.gui.Gui` (``gui``: its scale and sections): the panel right of the
    view.  ``histogram_open`` forces the Histogram section open or closed (None: the user's);
    ``probe_rects`` keeps where each probe image was drawn (screen px), for tests."""

    def __init__(self, app, gui, images_panel):
        self.app = app
        self.gui = gui
        self.images_panel = images_panel
        self.histogram_open: bool | None = None
        self.probe_rects: dict[tuple[int, str], tuple[float, float, float, float]] = {}
        self.scroll_to_pin: int | None = None  # a new pin: its probe is brought into view
        self._images_counted: int | None = None
        self._hist_key: tuple | None = None  # the histogram: what it was computed for
        self._hist = None

    def draw(self, W: float, H: float) -> None:
        app = self.app
        top = self.gui.bar_height()
        pw = PANEL_WIDTH * self.gui.scale
        imgui.set_next_window_pos(imgui.ImVec2(W - pw, top))
        imgui.set_next_window_size(imgui.ImVec2(pw, H - 2 * top))
        imgui.begin("##panel", None, FLAGS_FIXED)
        imgui.text_wrapped(app.doc.name or "(no file)")  # long names wrap: nothing is cut at the right
        if app.loader.busy:
            frac, text = app.loader.progress or (None, "")
            if frac is None:  # indeterminate: a moving bar
                frac = (time.monotonic() * 0.5) % 1.0
            imgui.progress_bar(frac, imgui.ImVec2(-60 * self.gui.scale, 0), text or "working")
            imgui.same_line()
            if imgui.button("Cancel"):
                app.images.cancel()
        n = len(app.images)
        if n != self._images_counted:  # shut for one image (room for the layers),
            imgui.set_next_item_open(n > 1)  # opened when a second one arrives
            self._images_counted = n
        if imgui.collapsing_header(f"Images ({n})###images"):
            self.images_panel.draw()
        if imgui.collapsing_header("Layers", imgui.TreeNodeFlags_.default_open):
            self._layers()
        if imgui.collapsing_header("Display", imgui.TreeNodeFlags_.default_open):
            self._display()
        if self.histogram_open is not None:  # phyir-view --histogram, scripts: open (or close) it
            imgui.set_next_item_open(self.histogram_open, imgui.Cond_.always)
        if imgui.collapsing_header("Histogram"):
            self._histogram()
        if imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
            self._view_controls()
        if imgui.collapsing_header("Read-out", imgui.TreeNodeFlags_.default_open):
            self._readout()
        if imgui.collapsing_header(f"Probes ({len(app.pins)})###probes", imgui.TreeNodeFlags_.default_open):
            self._probes()
        for section in self.gui.sections:  # the objects' panel and any added (Gui.add_section)
            flags = imgui.TreeNodeFlags_.default_open if section.default_open else 0
            if imgui.collapsing_header(section.title, flags):
                section.draw()
        if imgui.collapsing_header("Messages"):
            for m in list(app.messages)[::-1]:
                imgui.push_text_wrap_pos(0)
                imgui.text_colored(imgui.ImVec4(*LEVEL_COLOURS.get(m.level, (0.8, 0.8, 0.8, 1))), m.text)
                imgui.pop_text_wrap_pos()
        imgui.end()

    def _layers(self) -> None:
        app = self.app
        avail = app.doc.available()
        if app.doc.gt is not None:
            if imgui.radio_button("prediction", not app.doc.show_gt):
                app.display.set_source(False)
            imgui.same_line()
            if imgui.radio_button("ground truth (G)", app.doc.show_gt):
                app.display.set_source(True)
        for k, (name, key) in enumerate(zip(LAYERS, KEYS)):
            if k % 2:
                imgui.same_line(170 * self.gui.scale)
            present = name in avail
            if not present:
                imgui.begin_disabled()
            if imgui.radio_button(f"{key} {name}", app.display.layer == name):
                app.display.set_layer(name)
            if not present:
                imgui.end_disabled()
            if imgui.is_item_hovered(imgui.HoveredFlags_.allow_when_disabled):
                why = "" if present else (" (computing...)" if app.loader.busy else " (not available)")
                imgui.set_tooltip(SPECS[name].help + why)

    def _display(self) -> None:
        app = self.app
        spec = SPECS[app.display.layer]
        if spec.kind == "hdr":
            ch, ev = imgui.slider_float("exposure (E)", app.display.hdr.exposure, -12.0, 12.0, "%+.1f EV")
            if ch:
                app.display.set_exposure(ev)
            ch, off = imgui.slider_float("offset (O)", app.display.hdr.offset, -1.0, 1.0, "%+.3f")
            if ch:
                app.display.set_offset(off)
            ch, i = imgui.combo("tone map (T)", TONEMAPS.index(app.display.hdr.tonemap),
                                ["sRGB", "ACES", "false colour"])
            if ch:
                app.display.set_tonemap(TONEMAPS[i])
            self._channel_combo()
            if app.display.hdr.tonemap == "false":
                lo, hi = app.display.hdr.false_range
                colour_bar("turbo", f"{lo:+.0f} EV", f"{hi:+.0f} EV", self.gui.scale)
        elif spec.kind == "colour":
            self._channel_combo()
        elif spec.kind == "scalar":
            sd = app.display.scalar[app.display.layer]
            ch, i = imgui.combo("colour map (C)", COLORMAPS.index(sd.colormap), list(COLORMAPS))
            if ch:
                app.display.set_colormap(COLORMAPS[i])
            lo, hi = sd.range
            speed = max(1e-3, (hi - lo) / 200)
            ch, lo2, hi2 = imgui.drag_float_range2("range", lo, hi, speed, 0.0, 0.0, "%.4g", "%.4g")
            if ch and hi2 > lo2:
                app.display.set_range(lo2, hi2)
            imgui.same_line()
            if imgui.small_button("auto"):
                app.display.set_range(None)
            colour_bar(sd.colormap, fmt_number(lo) + spec.unit, fmt_number(hi) + spec.unit, self.gui.scale)
        else:
            imgui.push_text_wrap_pos(0)
            note = "normal n shown as 0.5 n + 0.5 (x red, y green, z blue)" if spec.kind == "normal" \
                else "base colour shown as sRGB"
            imgui.text_disabled(note)
            imgui.pop_text_wrap_pos()

    def _histogram(self) -> None:
        """The shown layer's histogram (log2 for HDR) and where the display puts white / its range."""
        app = self.app
        arrays = app.doc.shown_arrays
        if app.display.layer not in arrays:
            imgui.text_disabled("the layer is not there yet")
            return
        spec = SPECS[app.display.layer]
        key = (id(arrays[app.display.layer]), app.display.layer, app.display.hdr.channel)
        if self._hist_key != key:
            self._hist_key, self._hist = key, histogram(arrays[app.display.layer], spec.kind, key[2])
        if self._hist is None:
            imgui.text_disabled("no histogram for normals")
            return
        counts, lo, hi, unit = self._hist
        imgui.plot_histogram("##hist", counts, graph_size=imgui.ImVec2(-1, 70 * self.gui.scale))
        imgui.text(f"{unit}: {fmt_number(lo)} .. {fmt_number(hi)}")
        if spec.kind == "hdr" and app.display.hdr.tonemap != "false":
            ev = app.display.hdr.exposure
            imgui.text(f"white at {0.0 - ev:+.1f} EV (exposure {ev:+.1f})")
        elif spec.kind == "scalar":
            r = app.display.scalar[app.display.layer].range
            imgui.text(f"colour map over {fmt_number(r[0])} .. {fmt_number(r[1])}")

    def _channel_combo(self) -> None:
        app = self.app
        names = ["RGB", "R", "G", "B", "luminance"]
        ch, i = imgui.combo("channel (X)", CHANNELS.index(app.display.hdr.channel), names)
        if ch:
            app.display.set_channel(CHANNELS[i])

    def _view_controls(self) -> None:
        app = self.app
        if imgui.radio_button("equirect", app.camera.view_kind == "equirect"):
            app.camera.set_view("equirect")
        imgui.same_line()
        if imgui.radio_button("perspective (V)", app.camera.view_kind == "perspective"):
            app.camera.set_view("perspective")
        if app.camera.view_kind == "equirect":
            if imgui.button("Fit (F)"):
                app.camera.fit()
            imgui.same_line()
            if imgui.button("1:1 (Z)"):
                app.camera.one_to_one()
            imgui.same_line()
            imgui.text(f"zoom {100 * app.camera.view.zoom:.0f}%")
        else:
            v = app.camera.view
            ch, fov = imgui.slider_float("field of view", v.fov, 10.0, 150.0, "%.0f deg")
            if ch:
                app.camera.set_view(fov=fov)
            imgui.text(f"yaw {math.degrees(v.yaw):+.1f} deg, pitch {math.degrees(v.pitch):+.1f} deg")
            imgui.same_line()
            if imgui.small_button("reset"):
                app.camera.set_view(yaw=0.0, pitch=0.0, fov=75.0)

    def _readout(self) -> None:
        app = self.app
        if app.camera.hover is None or app.doc.size is None:
            imgui.text_disabled("hover over the panorama; click to pin a probe")
            return
        u, v = app.camera.hover
        H, W = app.doc.size
        lon = 360 * u / W - 180
        lat = 90 - 180 * v / H
        d = self._direction(u, v)
        imgui.text_wrapped(f"pixel col {int(u)}, row {int(v)}  (u {u:.1f}, v {v:.1f})")
        imgui.text(f"lon {lon:+.2f}, lat {lat:+.2f} deg")
        imgui.text(f"dir ({d[0]:+.3f}, {d[1]:+.3f}, {d[2]:+.3f})")
        sources = [("pred", app.doc.arrays)] + ([("gt", app.doc.gt_arrays)] if app.doc.gt is not None else [])
        flags = imgui.TableFlags_.borders_inner_h | imgui.TableFlags_.sizing_fixed_fit
        if imgui.begin_table("values", 1 + len(sources), flags):
            imgui.table_setup_column("layer")
            for src, _ in sources:
                title = "value" if len(sources) == 1 else ("predicted" if src == "pred" else "true")
                imgui.table_setup_column(title)
            imgui.table_headers_row()
            vals = {src: app.doc.values_at(u, v, src) for src, _ in sources}
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
        H, W = self.app.doc.size
        return pano.uv_to_dir(torch.tensor(u, dtype=torch.float64), torch.tensor(v, dtype=torch.float64),
                              H, W).numpy()

    def _probes(self) -> None:
        app = self.app
        if not app.pins:
            imgui.text_disabled("click the view to pin a probe")
            return
        if imgui.small_button("remove all"):
            while app.pins:
                app.pins.unpin()
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
            pairs = [("pred", "predicted" if app.doc.gt is not None else None)]
            if pin.probe_gt is not None:
                pairs.append(("gt", "true"))
            if pin.probe is None and pin.probe_gt is None:
                imgui.text_disabled("no light probes yet" + (" (computing...)" if app.loader.busy else ""))
            else:
                h, w = (pin.probe if pin.probe is not None else pin.probe_gt).shape[1:]
                cell = (avail_w - 8 * self.gui.scale * (len(pairs) - 1)) / len(pairs)
                f = max(1, int(cell * self.gui.fb_scale // w))  # integer texel size: texels stay square
                size = (w * f, h * f)
                for n, (which, label) in enumerate(pairs):
                    if n:
                        imgui.same_line()
                    imgui.begin_group()
                    if label:
                        imgui.text(label)
                    tex = app.pins.probe_image(pin, which, size)
                    if tex is None:
                        imgui.text_disabled("-")
                    else:
                        imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(size[0] / self.gui.fb_scale,
                                                                               size[1] / self.gui.fb_scale),
                                    imgui.ImVec2(0, 1), imgui.ImVec2(1, 0))
                        mn, mx = imgui.get_item_rect_min(), imgui.get_item_rect_max()
                        self.probe_rects[(k, which)] = (mn.x, mn.y, mx.x, mx.y)
                    imgui.end_group()
                ch, ev = imgui.slider_float("probe EV", pin.exposure, -12.0, 12.0, "%+.1f EV")
                if ch:
                    app.pins.set_pin_exposure(k, ev)
            if self.scroll_to_pin == k:  # a new pin: bring its probe into view
                imgui.set_scroll_here_y(1.0)
                self.scroll_to_pin = None
            if pin.block is not None:
                row, col = pin.block
                imgui.text_wrapped(f"grid cell row {row}, col {col} (bilinear between cells)")
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
            app.pins.unpin(remove)

