"""The open images and the comparison with a reference: the side panel's section, the keys, and the
split view's divide that the mouse drags."""

from __future__ import annotations

from phyir.errors import PhyIRError
from viewer.compare import METRICS, MODES
from viewer.ui.widgets import colour_bar, fmt_number, imgui

MODE_NAMES = {None: "off", "diff": "difference a - b", "reldiff": "relative (a - b) / (|b| + 0.01)",
              "sqerr": "squared error (a - b)^2", "split": "split view"}
SPLIT_GRAB_PX = 6.0  # logical px either side of the divide that grab it


class ImagesPanel:
    """Part of :class:`viewer.ui.gui.Gui` (``gui``: its scale): several images and the reference."""

    def __init__(self, app, gui):
        self.app = app
        self.gui = gui
        self._split_drag = False  # the split view's divide is being dragged

    def draw(self) -> None:
        """The side panel's Images section."""
        app = self.app
        ref = app.images.reference_index
        for k, e in enumerate(app.images):
            mark = " (reference)" if k == ref else ""
            key = f"{k + 1}/{len(app.images)}"
            if imgui.selectable(f"{key}  {app.images.label(e)}{mark}##img{k}", k == app.images.current)[0]:
                app.images.select(k)
        if len(app.images) < 2:
            imgui.text_disabled("File > Open adds images; [ ] switch")
        names = ["none"] + [f"{k + 1} {app.images.label(e)}" for k, e in enumerate(app.images)]
        ch, i = imgui.combo("ref (Shift+R)", 0 if ref is None else ref + 1, names)
        if ch:
            app.images.set_reference(None if i == 0 else i - 1)
        if app.images.reference is None:
            return
        modes = [None, *MODES]
        ch, i = imgui.combo("compare (D)", modes.index(app.comparison.mode), [MODE_NAMES[m] for m in modes])
        if ch:
            app.comparison.set_mode(modes[i])
        self._compare_controls()

    def _compare_controls(self) -> None:
        app = self.app
        problem = app.comparison.problem(app.display.layer)
        if problem:
            imgui.text_disabled(problem)
        elif app.comparison.mode == "split":
            ch, x = imgui.slider_float("split", app.comparison.split, 0.0, 1.0, "%.2f")
            if ch:
                app.comparison.set_split(x)
            imgui.text_disabled("left: this, right: reference; drag the line")
        elif app.comparison.mode in METRICS:
            spec = app.composer.frame_spec()
            if spec is None or spec.compare is None:
                return
            lo, hi = spec.compare.range
            ch, ext = imgui.slider_float("extent", hi, 1e-4, 1e3, "%.4g", imgui.SliderFlags_.logarithmic)
            if ch:
                app.comparison.set_extent(ext)
            imgui.same_line()
            if imgui.small_button("auto##extent"):
                app.comparison.set_extent(None)
            colour_bar(spec.compare.colormap, fmt_number(lo), fmt_number(hi), self.gui.scale)

    def image_keys(self, shift: bool) -> None:
        """[ ] and PageUp/PageDown switch images, Shift+R makes the shown one the reference (again:
        none), D / Shift+D cycle the comparison."""
        app, K, pressed = self.app, imgui.Key, imgui.is_key_pressed
        if len(app.images) > 1 and (pressed(K.right_bracket) or pressed(K.page_down)):
            app.images.next(1)
        if len(app.images) > 1 and (pressed(K.left_bracket) or pressed(K.page_up)):
            app.images.next(-1)
        if shift and pressed(K.r, False):
            app.images.set_reference(None if app.images.reference is app.images.entry else app.images.current)
            ref = app.images.reference
            label = "no reference" if ref is None else f"reference: {app.images.label(ref)}"
            app.messages.note("info", label)
        if pressed(K.d, False):
            modes = [None, *MODES]
            mode = modes[(modes.index(app.comparison.mode) + (-1 if shift else 1)) % len(modes)]
            try:
                app.comparison.set_mode(mode)
            except PhyIRError as e:  # no reference yet: say how to choose one
                app.messages.note("info", str(e))

    def split_mouse(self, hovered: bool, activated: bool, active: bool, mx: float, w: float) -> bool:
        """The split view's divide: grabbed within a few pixels, dragged while held; True while it
        has the mouse (the view does not pan)."""
        app = self.app
        if app.comparison.mode != "split" or app.comparison.problem(app.display.layer):
            self._split_drag = False
            return False
        near = abs(mx - app.comparison.split * w) <= SPLIT_GRAB_PX * self.gui.fb_scale * self.gui.scale
        if hovered and near or self._split_drag:
            imgui.set_mouse_cursor(imgui.MouseCursor_.resize_ew)
        if activated and near:
            self._split_drag = True
        if self._split_drag and active:
            app.comparison.set_split(mx / max(w, 1.0))
        elif not active:
            self._split_drag = False
        return self._split_drag
