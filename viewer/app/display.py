"""What the App's view shows and how: the layer, prediction or ground truth, exposure, tone and
colour maps, the layer textures (uploaded a few per frame) and the frame the renderer draws."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from phyir.errors import PhyIRError
from viewer.app.common import BACKGROUND, NEAREST_ZOOM, UPLOAD_BUDGET_S, ScalarDisplay
from viewer.layers import LAYERS, SPECS, auto_range
from viewer.renderer import CHANNELS, COLORMAPS, TONEMAPS, Display, Frame, Marker


class DisplaySettings:
    """Part of :class:`viewer.app.App`: display state, textures and the view's frame."""

    def apply_auto_ranges(self, ranges: dict[str, tuple[float, float]]) -> None:
        """Automatic colour-map ranges; with ground truth its ranges rule, so G compares like with like."""
        for name, r in ranges.items():
            if self.scalar[name].auto and not (self.gt is not None and name in self.gt_arrays):
                self.scalar[name].range = r

    # -- textures -----------------------------------------------------------------------------
    def queue_upload(self, source: str, arrays: dict[str, np.ndarray]) -> None:
        for name in arrays:
            key = (source, name)
            if key not in self.pending_uploads:
                self.pending_uploads.append(key)

    def upload_some(self) -> bool:
        """Upload queued layers, the shown one first, within a time budget per frame; True if any
        was uploaded."""
        if not self.pending_uploads:
            return False
        shown = ("gt" if self.show_gt else "pred", self.layer)
        self.pending_uploads.sort(key=lambda k: k != shown)
        t0 = time.perf_counter()
        pending = self.pending_uploads
        while pending and (time.perf_counter() - t0 < UPLOAD_BUDGET_S or pending[0] == shown):
            source, name = pending.pop(0)
            arrays = self.gt_arrays if source == "gt" else self.arrays
            if name in arrays:
                key = (source, name)
                self.layer_textures[key] = self.renderer.texture(arrays[name], self.layer_textures.get(key))
                self.texture_versions[key] = self.texture_versions.get(key, 0) + 1
        return True

    # -- state changes (what clicks and keys call) --------------------------------------------
    def set_layer(self, name: str) -> None:
        if name not in LAYERS:
            raise PhyIRError(f"unknown layer {name!r} (choose from {', '.join(LAYERS)})")
        self.layer = name
        self.request_redraw(2)

    def set_source(self, gt: bool) -> None:
        """Show the ground truth (True) or the prediction/file layers (False)."""
        self.show_gt = bool(gt) and self.gt is not None

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
        self.request_redraw(2)

    def set_exposure(self, ev: float) -> None:
        self.hdr.exposure = float(ev)
        self.dirty_pins()

    def set_offset(self, offset: float) -> None:
        self.hdr.offset = float(offset)

    def set_tonemap(self, name: str) -> None:
        if name not in TONEMAPS:
            raise PhyIRError(f"unknown tone map {name!r} (choose from {', '.join(TONEMAPS)})")
        self.hdr.tonemap = name
        self.dirty_pins()

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
            arrays = self.shown_arrays
            fixed = SPECS[name].range or (0.0, 1.0)
            sd.range = auto_range(arrays[name]) if sd.auto and name in arrays else fixed
        else:
            sd.auto, sd.range = False, (float(lo), float(hi))

    # -- drawing ------------------------------------------------------------------------------
    def markers(self) -> list[Marker]:
        """Pinned probes in view coordinates (those in front of the camera)."""
        if self.size is None or not self.pins:
            return []
        u = np.array([p.u for p in self.pins])
        v = np.array([p.v for p in self.pins])
        x, y, front = self.view.uv_to_screen(u, v, self.view_size(), self.size)
        return [Marker(float(a), float(b), p.colour, str(k + 1))
                for k, (a, b, f, p) in enumerate(zip(x, y, front, self.pins)) if f]

    def frame_spec(self) -> Frame | None:
        """What the view draws: the shown layer, or the image while that layer is still missing."""
        if self.size is None:
            return None
        src = "gt" if self.show_gt and self.gt is not None else "pred"
        layers = {name: t for (s, name), t in self.layer_textures.items() if s == src}
        layer = self.layer if self.layer in layers else "image"
        tex = layers.get(layer)
        if tex is None:
            return None
        near = self.view_kind == "equirect" and self.view.zoom > NEAREST_ZOOM
        if layer == "probes":  # the atlas has its own resolution: nearest once its texels are big
            near = self.view_kind == "equirect" and self.view.zoom * tex.size[0] / self.size[1] > NEAREST_ZOOM
        versus = self.compare_spec(layer)  # viewer.app.comparison: against the reference
        extras = {"marker_radius": 9.0 * self.ui_scale, "layers": layers, "scene": self.scene,
                  "insert": layer == "image" and versus is None,
                  "layer_version": self.texture_versions.get((src, layer), 0),
                  "reference_version": versus[1] if versus else 0}
        return Frame(texture=tex, pano_size=self.size, view=self.view, display=self.display(layer),
                     nearest=near, markers=self.markers(), background=BACKGROUND, extras=extras,
                     compare=versus[0] if versus else None)

    def view_key(self, spec: Frame, rect) -> tuple | None:
        """Everything the view's picture depends on (the renderer redraws it when this changes);
        None when linear passes draw (they keep their own state) or objects are dragged."""
        objects = ()
        if (self.renderer.linear_passes or self.objects_active()) and spec.compare is None:
            objects = None if self.renderer.linear_passes else self.objects.picture_key(spec, tuple(rect[2:]))
            if objects is None:
                return None
        fields = dataclasses.astuple
        version = next((self.texture_versions.get(k, 0) for k, t in self.layer_textures.items()
                        if t is spec.texture), 0)
        return (id(spec.texture), version, spec.pano_size, fields(spec.view), fields(spec.display),
                spec.nearest, tuple(map(fields, spec.markers)), spec.background, spec.extras["marker_radius"],
                tuple(rect[2:]), _compare_key(spec), objects)


def _compare_key(spec: Frame) -> tuple | None:
    """What the view's picture takes from the comparison (the texture by identity and upload count)."""
    c = spec.compare
    if c is None:
        return None
    return c.mode, id(c.texture), spec.extras["reference_version"], c.split, c.range, c.colormap
