"""The open images and the comparison with a reference: the side panel's section, the keys, and the
split view's divide that the mouse drags."""

from __future__ import annotations

from phyir.errors import PhyIRError
from viewer.compare import METRICS, MODES
from viewer.ui.widgets import fmt_number, imgui

MODE_NAMES = {None: "off", "diff": "difference a - b", "reldiff": "relative (a - b) / (|b| + 0.01)",
              "sqerr": "squared error (a - b)^2", "split": "split view"}
SPLIT_GRAB_PX = 6.0  # logical px either side of the divide that grab it


class ImagesPanel:
    """Part of :class:`viewer.ui.gui.Gui`: several images and the reference."""

    def images_section(self) -> None:
        app = self.app
        ref = app.reference_index
        for k, e in enumerate(app.images):
            mark = " (reference)" if k == ref else ""
            key = f"{k + 1}/{len(app.images)}"
            if imgui.selectable(f"{key}  {app.image_label(e)}{mark}##img{k}", k == app.current)[0]:
                app.select_image(k)
        if len(app.images) < 2:
            imgui.text_disabled("File > Open adds images; [ ] switch")
        names = ["none"] + [f"{k + 1} {app.image_label(e)}" for k, e in enumerate(app.images)]
        ch, i = imgui.combo("ref (Shift+R)", 0 if ref is None else ref + 1, names)
        if ch:
            app.set_reference(None if i == 0 else i - 1)
        if app.reference is None:
            return
        modes = [None, *MODES]
        ch, i = imgui.combo("compare (D)", modes.index(app.compare_mode), [MODE_NAMES[m] for m in modes])
        if ch:
            app.set_compare(modes[i])
        self._compare_controls()

    def _compare_controls(self) -> None:
        app = self.app
        problem = app.compare_problem(app.layer)
        if problem:
            imgui.text_disabled(problem)
        elif app.compare_mode == "split":
            ch, x = imgui.slider_float("split", app.split, 0.0, 1.0, "%.2f")
            if ch:
                app.set_split(x)
            imgui.text_disabled("left: this, right: reference; drag the line")
        elif app.compare_mode in METRICS:
            spec = app.frame_spec()
            if spec is None or spec.compare is None:
                return
            lo, hi = spec.compare.range
            ch, ext = imgui.slider_float("extent", hi, 1e-4, 1e3, "%.4g", imgui.SliderFlags_.logarithmic)
            if ch:
                app.set_compare_extent(ext)
            imgui.same_line()
            if imgui.small_button("auto##extent"):
                app.set_compare_extent(None)
            self.colour_bar(spec.compare.colormap, fmt_number(lo), fmt_number(hi))

    def image_keys(self, shift: bool) -> None:
        """[ ] and PageUp/PageDown switch images, Shift+R makes the shown one the reference (again:
        none), D / Shift+D cycle the comparison."""
        app, K, pressed = self.app, imgui.Key, imgui.is_key_pressed
        if len(app.images) > 1 and (pressed(K.right_bracket) or pressed(K.page_down)):
            app.next_image(1)
        if len(app.images) > 1 and (pressed(K.left_bracket) or pressed(K.page_up)):
            app.next_image(-1)
        if shift and pressed(K.r, False):
            app.set_reference(None if app.reference is app.entry else app.current)
            ref = app.reference
            app.note("info", f"reference: {app.image_label(ref)}" if ref is not None else "no reference")
        if pressed(K.d, False):
            modes = [None, *MODES]
            mode = modes[(modes.index(app.compare_mode) + (-1 if shift else 1)) % len(modes)]
            try:
                app.set_compare(mode)
            except PhyIRError as e:  # no reference yet: say how to choose one
                app.note("info", str(e))

    def split_mouse(self, hovered: bool, activated: bool, active: bool, mx: float, w: float) -> bool:
        """The split view's divide: grabbed within a few pixels, dragged while held; True while it
        has the mouse (the view does not pan)."""
        app = self.app
        if app.compare_mode != "split" or app.compare_problem(app.layer):
            self._split_drag = False
            return False
        near = abs(mx - app.split * w) <= SPLIT_GRAB_PX * self.fb_scale * self.scale
        if hovered and near or self._split_drag:
            imgui.set_mouse_cursor(imgui.MouseCursor_.resize_ew)
        if activated and near:
            self._split_drag = True
        if self._split_drag and active:
            app.set_split(mx / max(w, 1.0))
        elif not active:
            self._split_drag = False
        return self._split_drag
