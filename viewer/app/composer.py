"""What the view draws (:class:`ViewComposer`): the shown layer's :class:`~viewer.renderer.Frame` --
texture, view, display settings, comparison, pin markers -- and the key of the picture it makes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from viewer.app.camera import Camera
from viewer.app.common import BACKGROUND, NEAREST_ZOOM
from viewer.app.comparison import Comparison
from viewer.app.display import DisplaySettings
from viewer.app.images import ImageList
from viewer.app.objects import InsertedObjects
from viewer.renderer import Frame, Marker


class ViewComposer:
    """Reads the shown image, the display settings, the camera, the comparison and the objects;
    owns nothing.  ``view_size()`` and ``ui_scale()`` come from the window."""

    def __init__(self, images: ImageList, display: DisplaySettings, camera: Camera, comparison: Comparison,
                 objects: InsertedObjects, renderer, ui_scale: Callable[[], float]):
        self.images, self.display, self.camera = images, display, camera
        self.comparison, self.objects, self.renderer = comparison, objects, renderer
        self.ui_scale = ui_scale

    def markers(self) -> list[Marker]:
        """Pinned probes in view coordinates (those in front of the camera)."""
        doc = self.images.doc
        if doc.size is None or not doc.pins:
            return []
        u = np.array([p.u for p in doc.pins])
        v = np.array([p.v for p in doc.pins])
        x, y, front = self.camera.view.uv_to_screen(u, v, self.camera.view_size(), doc.size)
        return [Marker(float(a), float(b), p.colour, str(k + 1))
                for k, (a, b, f, p) in enumerate(zip(x, y, front, doc.pins)) if f]

    def frame_spec(self) -> Frame | None:
        """What the view draws: the shown layer, or the image while that layer is still missing."""
        doc, cam = self.images.doc, self.camera
        if doc.size is None:
            return None
        src = doc.shown_source
        layers = {name: t for (s, name), t in doc.layer_textures.items() if s == src}
        layer = self.display.layer if self.display.layer in layers else "image"
        tex = layers.get(layer)
        if tex is None:
            return None
        near = cam.view_kind == "equirect" and cam.view.zoom > NEAREST_ZOOM
        if layer == "probes":  # the atlas has its own resolution: nearest once its texels are big
            near = cam.view_kind == "equirect" and cam.view.zoom * tex.size[0] / doc.size[1] > NEAREST_ZOOM
        versus = self.comparison.spec(layer)  # against the reference
        extras = {"marker_radius": 9.0 * self.ui_scale(), "layers": layers, "scene": doc.scene,
                  "insert": layer == "image" and versus is None,
                  "layer_version": doc.texture_versions.get((src, layer), 0),
                  "reference_version": versus[1] if versus else 0}
        return Frame(texture=tex, pano_size=doc.size, view=cam.view, display=self.display.display(layer),
                     nearest=near, markers=self.markers(), background=BACKGROUND, extras=extras,
                     compare=versus[0] if versus else None)

    def view_key(self, spec: Frame, rect) -> tuple | None:
        """Everything the view's picture depends on (the renderer redraws it when this changes);
        None when linear passes draw (they keep their own state) or objects are dragged."""
        objects = ()
        if (self.renderer.linear_passes or self.objects.active()) and spec.compare is None:
            objects = None if self.renderer.linear_passes else self.objects.picture_key(spec, tuple(rect[2:]))
            if objects is None:
                return None
        fields = dataclasses.astuple
        doc = self.images.doc
        version = next((doc.texture_versions.get(k, 0) for k, t in doc.layer_textures.items()
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
