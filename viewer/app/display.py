"""What the view shows and how (:class:`DisplaySettings`): the layer, prediction or ground truth,
exposure, tone and colour maps, and the :class:`~viewer.renderer.Display` a layer is drawn with."""

from __future__ import annotations

from collections.abc import Callable

from phyir.errors import PhyIRError
from viewer.app.common import ScalarDisplay
from viewer.app.document import Document
from viewer.app.images import ImageList
from viewer.layers import LAYERS, SPECS, auto_range
from viewer.renderer import CHANNELS, COLORMAPS, TONEMAPS, Display


class DisplaySettings:
    """Shared by all images: ``layer`` (the one shown), ``hdr`` (HDR and colour layers' exposure,
    offset, tone map, channel) and ``scalar`` (each scalar layer's colour map and range).
    ``settings_changed`` is told when what probe images show changes (exposure, tone map)."""

    def __init__(self, images: ImageList, redraw: Callable[[int], None]):
        self.images = images
        self.redraw = redraw
        self.settings_changed: Callable[[], None] = lambda: None
        self.layer = "image"
        self.hdr = Display()
        self.scalar = {n: ScalarDisplay(s.colormap, s.range or (0.0, 1.0), s.range is None)
                       for n, s in SPECS.items() if s.kind == "scalar"}

    def apply_auto_ranges(self, ranges: dict[str, tuple[float, float]], doc: Document) -> None:
        """Automatic colour-map ranges; with ground truth its ranges rule, so G compares like with like."""
        for name, r in ranges.items():
            if self.scalar[name].auto and not (doc.gt is not None and name in doc.gt_arrays):
                self.scalar[name].range = r

    # -- state changes (what clicks and keys call) --------------------------------------------
    def set_layer(self, name: str) -> None:
        if name not in LAYERS:
            raise PhyIRError(f"unknown layer {name!r} (choose from {', '.join(LAYERS)})")
        self.layer = name
        self.redraw(2)

    def set_source(self, gt: bool) -> None:
        """Show the ground truth (True) or the prediction/file layers (False)."""
        doc = self.images.doc
        doc.show_gt = bool(gt) and doc.gt is not None

    def display(self, layer: str | None = None) -> Display:
        """The display settings the given (default: shown) layer is drawn with."""
        spec = SPECS[layer or self.layer]
        if spec.kind == "scalar":
            sd = self.scalar[spec.name]
            return Display(kind="scalar", colormap=sd.colormap, range=sd.range)
        if spec.kind == "hdr":
            return Display(kind="hdr", tonemap=self.hdr.tonemap, exposure=self.hdr.exposure,
                           offset=self.hdr.offset, false_range=self.hdr.false_range, channel=self.hdr.channel)
        return Display(kind=spec.kind, channel=self.hdr.channel if spec.kind == "colour" else "rgb")

    def set_channel(self, name: str) -> None:
        """What HDR and colour layers show: all channels, one of R, G, B, or the luminance (as grey)."""
        if name not in CHANNELS:
            raise PhyIRError(f"unknown channel {name!r} (choose from {', '.join(CHANNELS)})")
        self.hdr.channel = name
        self.redraw(2)

    def set_exposure(self, ev: float) -> None:
        self.hdr.exposure = float(ev)
        self.settings_changed()

    def set_offset(self, offset: float) -> None:
        self.hdr.offset = float(offset)

    def set_tonemap(self, name: str) -> None:
        if name not in TONEMAPS:
            raise PhyIRError(f"unknown tone map {name!r} (choose from {', '.join(TONEMAPS)})")
        self.hdr.tonemap = name
        self.settings_changed()

    def _scalar(self, layer: str | None) -> ScalarDisplay:
        name = layer or self.layer
        if name not in self.scalar:
            raise PhyIRError(f"layer {name!r} is not shown through a colour map "
                             f"(those are: {', '.join(self.scalar)})")
        return self.scalar[name]

    def set_colormap(self, name: str, layer: str | None = None) -> None:
        if name not in COLORMAPS:
            raise PhyIRError(f"unknown colour map {name!r} (choose from {', '.join(COLORMAPS)})")
        self._scalar(layer).colormap = name

    def set_range(self, lo: float | None, hi: float | None = None, layer: str | None = None) -> None:
        """Colour-map range of a scalar layer; ``lo=None`` returns to the automatic range."""
        name = layer or self.layer
        sd = self._scalar(name)
        if lo is None:
            sd.auto = SPECS[name].range is None
            arrays = self.images.doc.shown_arrays
            fixed = SPECS[name].range or (0.0, 1.0)
            sd.range = auto_range(arrays[name]) if sd.auto and name in arrays else fixed
        else:
            sd.auto, sd.range = False, (float(lo), float(hi))
