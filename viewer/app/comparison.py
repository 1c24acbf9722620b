"""The shown layer against the same layer of a reference image: which image is the reference, the
mode (``viewer.compare.MODES``), the split position and the colour-map extent, and the
:class:`~viewer.renderer.Compare` the view is drawn with (``shaders/compare.glsl``)."""

from __future__ import annotations

import numpy as np

from phyir.errors import PhyIRError
from viewer import compare
from viewer.app.images import Entry
from viewer.layers import SPECS
from viewer.renderer import Compare


class Comparison:
    """Part of :class:`viewer.app.App`: comparing with a reference image."""

    def init_comparison(self) -> None:
        self.reference: Entry | None = None
        self.compare_mode: str | None = None  # None: the layer alone
        self.split = 0.5  # split view: where the reference starts, fraction of the view's width
        self.compare_extent: dict[str, float | None] = dict.fromkeys(compare.METRICS)  # None: automatic
        self._auto_extent: tuple | None = None  # (what it was computed from, extent)

    # -- state changes --------------------------------------------------------------------------
    def set_reference(self, index: int | None) -> None:
        """Make image ``index`` (0-based) the reference; None: no reference (and no comparison)."""
        if index is None:
            self.reference, self.compare_mode = None, None
        elif not 0 <= index < len(self.images):
            raise PhyIRError(f"no image {index + 1} to use as the reference (there are {len(self.images)})")
        else:
            self.reference = self.images[index]
            self.reference.held = False
            self.schedule_jobs()  # its model's layers, to compare those too
        self.request_redraw()

    @property
    def reference_index(self) -> int | None:
        return None if self.reference is None else self.images.index(self.reference)

    def set_compare(self, mode: str | None) -> None:
        """Compare with the reference: one of viewer.compare.MODES, or None for the layer alone."""
        if mode is not None and mode not in compare.MODES:
            raise PhyIRError(f"unknown comparison {mode!r} (choose from {', '.join(compare.MODES)})")
        if mode is not None and self.reference is None:
            raise PhyIRError("no reference image to compare with (open a second image and make it "
                             "the reference: Shift+R, or --reference FILE)")
        self.compare_mode = mode
        self.request_redraw()

    def set_split(self, x: float) -> None:
        """The split view's divide, as a fraction of the view's width (clamped to [0, 1])."""
        x = float(x)
        if not np.isfinite(x):
            raise PhyIRError(f"split position must be finite, got {x}")
        self.split = min(1.0, max(0.0, x))
        self.request_redraw()

    def set_compare_extent(self, extent: float | None, mode: str | None = None) -> None:
        """The value at the ends of the colour map (±extent; [0, extent] for sqerr); None: automatic."""
        mode = mode or self.compare_mode
        if mode not in compare.METRICS:
            raise PhyIRError(f"the extent belongs to a metric ({', '.join(compare.METRICS)}), not {mode!r}")
        if extent is not None and not (np.isfinite(extent) and extent > 0):
            raise PhyIRError(f"comparison extent must be a positive finite number, got {extent}")
        self.compare_extent[mode] = None if extent is None else float(extent)
        self.request_redraw()

    def forget_image(self, e: Entry) -> None:
        """Image ``e`` was closed: it is no longer the reference."""
        if self.reference is e:
            self.set_reference(None)

    # -- what is drawn --------------------------------------------------------------------------
    def reference_arrays(self) -> dict[str, np.ndarray]:
        """The reference's layers as it shows them (its ground truth when it shows that)."""
        e = self.reference
        if e is None:
            return {}
        gt = self.image_state(e, "show_gt") and self.image_state(e, "gt") is not None
        return self.image_state(e, "gt_arrays" if gt else "arrays")

    def compare_problem(self, layer: str) -> str | None:
        """Why the comparison can't be drawn for ``layer`` (None: it can, or none is asked for)."""
        if self.compare_mode is None or self.reference is None:
            return None
        if layer not in self.reference_arrays():
            name = self.image_label(self.reference)
            return f"the reference {name} has no {layer} layer" + (" yet" if self.busy else "")
        return None

    def extent(self, layer: str) -> float:
        """The colour map's extent of the current metric: the user's, else the 99th percentile of
        the metric's magnitude (viewer.compare.auto_extent), computed once per pair of layers."""
        mode = self.compare_mode
        if self.compare_extent.get(mode) is not None:
            return self.compare_extent[mode]
        a, b = self.shown_arrays.get(layer), self.reference_arrays().get(layer)
        if a is None or b is None:
            return compare.DEFAULT_RANGE[mode]
        kind, channel = SPECS[layer].kind, self.hdr.channel
        key = (id(a), id(b), mode, kind, channel)
        if self._auto_extent is None or self._auto_extent[0] != key:
            values = compare.compare_values(a, compare.resample_nearest(b, a.shape[:2]), mode, kind, channel)
            self._auto_extent = (key, compare.auto_extent(values))
        return self._auto_extent[1]

    def compare_spec(self, layer: str) -> tuple[Compare, int] | None:
        """The view's comparison for ``layer`` and the reference texture's upload count (cache key)."""
        if self.compare_mode is None or self.compare_problem(layer) is not None:
            return None
        tex, version = self._reference_texture(layer)
        mode = self.compare_mode
        if mode == "split":
            return Compare(mode, tex, split=self.split), version
        return Compare(mode, tex, range=compare.colour_range(mode, self.extent(layer)),
                       colormap=compare.COLORMAP[mode]), version

    def _reference_texture(self, layer: str):
        """The reference's texture of ``layer``, uploaded here if it is new (the reference is
        usually not the image shown, whose uploads ``upload_some`` spreads over frames)."""
        e = self.reference
        gt = self.image_state(e, "show_gt") and self.image_state(e, "gt") is not None
        key = ("gt" if gt else "pred", layer)
        textures, versions = self.image_state(e, "layer_textures"), self.image_state(e, "texture_versions")
        pending = self.image_state(e, "pending_uploads")
        if key not in textures or key in pending:
            textures[key] = self.renderer.texture(self.reference_arrays()[layer], textures.get(key))
            versions[key] = versions.get(key, 0) + 1
            if key in pending:
                pending.remove(key)
        return textures[key], versions[key]
