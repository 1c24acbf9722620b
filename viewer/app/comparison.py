"""The shown layer against the same layer of the reference image (:class:`Comparison`): the mode
(``viewer.compare.MODES``), the split position and the colour-map extent, and the
:class:`~viewer.renderer.Compare` the view is drawn with (``shaders/compare.glsl``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from phyir.errors import PhyIRError
from viewer import compare
from viewer.app.display import DisplaySettings
from viewer.app.images import ImageList
from viewer.app.loader import Loader
from viewer.layers import SPECS
from viewer.renderer import Compare


class Comparison:
    """Owns ``mode`` (None: the layer alone), ``split`` and ``extent``; the reference is the image
    list's (``ImageList.reference``), and the comparison ends when it goes."""

    def __init__(self, images: ImageList, display: DisplaySettings, loader: Loader, renderer,
                 redraw: Callable[[], None]):
        self.images = images
        self.display = display
        self.loader = loader
        self.renderer = renderer
        self.redraw = redraw
        self.mode: str | None = None
        self.split = 0.5  # split view: where the reference starts, fraction of the view's width
        self.extent: dict[str, float | None] = dict.fromkeys(compare.METRICS)  # None: automatic
        self._auto_extent: tuple | None = None  # (what it was computed from, extent)
        images.on_no_reference = self._end

    def _end(self) -> None:
        self.mode = None

    # -- state changes --------------------------------------------------------------------------
    def set_mode(self, mode: str | None) -> None:
        """Compare with the reference: one of viewer.compare.MODES, or None for the layer alone."""
        if mode is not None and mode not in compare.MODES:
            raise PhyIRError(f"unknown comparison {mode!r} (choose from {', '.join(compare.MODES)})")
        if mode is not None and self.images.reference is None:
            raise PhyIRError("no reference image to compare with (open a second image and make it "
                             "the reference: Shift+R, or --reference FILE)")
        self.mode = mode
        self.redraw()

    def set_split(self, x: float) -> None:
        """The split view's divide, as a fraction of the view's width (clamped to [0, 1])."""
        x = float(x)
        if not np.isfinite(x):
            raise PhyIRError(f"split position must be finite, got {x}")
        self.split = min(1.0, max(0.0, x))
        self.redraw()

    def set_extent(self, extent: float | None, mode: str | None = None) -> None:
        """The value at the ends of the colour map (±extent; [0, extent] for sqerr); None: automatic."""
        mode = mode or self.mode
        if mode not in compare.METRICS:
            raise PhyIRError(f"the extent belongs to a metric ({', '.join(compare.METRICS)}), not {mode!r}")
        if extent is not None and not (np.isfinite(extent) and extent > 0):
            raise PhyIRError(f"comparison extent must be a positive finite number, got {extent}")
        self.extent[mode] = None if extent is None else float(extent)
        self.redraw()

    # -- what is drawn --------------------------------------------------------------------------
    def reference_arrays(self) -> dict[str, np.ndarray]:
        """The reference's layers as it shows them (its ground truth when it shows that)."""
        e = self.images.reference
        return {} if e is None else e.doc.shown_arrays

    def problem(self, layer: str) -> str | None:
        """Why the comparison can't be drawn for ``layer`` (None: it can, or none is asked for)."""
        if self.mode is None or self.images.reference is None:
            return None
        if layer not in self.reference_arrays():
            name = self.images.label(self.images.reference)
            return f"the reference {name} has no {layer} layer" + (" yet" if self.loader.busy else "")
        return None

    def current_extent(self, layer: str) -> float:
        """The colour map's extent of the current metric: the user's, else the 99th percentile of
        the metric's magnitude (viewer.compare.auto_extent), computed once per pair of layers."""
        mode = self.mode
        if self.extent.get(mode) is not None:
            return self.extent[mode]
        a, b = self.images.doc.shown_arrays.get(layer), self.reference_arrays().get(layer)
        if a is None or b is None:
            return compare.DEFAULT_RANGE[mode]
        kind, channel = SPECS[layer].kind, self.display.hdr.channel
        key = (id(a), id(b), mode, kind, channel)
        if self._auto_extent is None or self._auto_extent[0] != key:
            values = compare.compare_values(a, compare.resample_nearest(b, a.shape[:2]), mode, kind, channel)
            self._auto_extent = (key, compare.auto_extent(values))
        return self._auto_extent[1]

    def spec(self, layer: str) -> tuple[Compare, int] | None:
        """The view's comparison for ``layer`` and the reference texture's upload count (cache key)."""
        if self.mode is None or self.problem(layer) is not None:
            return None
        tex, version = self.images.reference.doc.texture(self.renderer, layer)
        mode = self.mode
        if mode == "split":
            return Compare(mode, tex, split=self.split), version
        return Compare(mode, tex, range=compare.colour_range(mode, self.current_extent(layer)),
                       colormap=compare.COLORMAP[mode]), version
