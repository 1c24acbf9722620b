"""Pinned probes (:class:`Pins`): pinning, their read-outs and their probe images."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import moderngl

from phyir.errors import PhyIRError
from phyir.insert.views import EquirectView
from viewer.app.common import BACKGROUND, gl_current
from viewer.app.document import Document, release_pin
from viewer.app.images import ImageList
from viewer.probes import Pin, make_pin, update_pin
from viewer.renderer import Display, Frame


class Pins:
    """The shown image's pinned probes, as a sequence of :class:`~viewer.probes.Pin` (each image keeps
    its own: ``Document.pins``).  Probe images are drawn with ``renderer`` and the ``hdr`` display
    settings; ``on_pinned(index)`` hears of each new pin (the side panel scrolls to it)."""

    def __init__(self, images: ImageList, renderer, ctx: moderngl.Context, hdr: Display,
                 gl_context: Callable):
        self.images = images
        self.renderer = renderer
        self.ctx = ctx
        self.hdr = hdr
        self.gl_context = gl_context
        self.on_pinned: Callable[[int], None] = lambda index: None

    def __len__(self) -> int:
        return len(self.images.doc.pins)

    def __getitem__(self, index: int) -> Pin:
        return self.images.doc.pins[index]

    def __iter__(self) -> Iterator[Pin]:
        return iter(self.images.doc.pins)

    def pin_probe(self, u: float, v: float, doc: Document | None = None) -> Pin:
        """Pin the probe at panorama coordinates (u, v) (column, row; pixel centres at +0.5) of the
        shown image (or of ``doc``)."""
        doc = doc or self.images.doc
        if doc.scene is None:
            raise PhyIRError("no panorama is open")
        pin = make_pin(u, v, len(doc.pins), doc.scene, doc.arrays, doc.gt, self.hdr.exposure)
        doc.pins.append(pin)
        self.on_pinned(len(doc.pins) - 1)
        return pin

    @gl_current
    def unpin(self, index: int = -1) -> None:
        pins = self.images.doc.pins
        if pins:
            release_pin(pins.pop(index))

    def set_pin_exposure(self, index: int, ev: float) -> None:
        pin = self.images.doc.pins[index]
        pin.exposure = float(ev)
        pin.textures["stale"] = {"pred", "gt"}

    def refresh(self, doc: Document) -> None:
        """``doc``'s layers changed: its pins read them again."""
        for pin in doc.pins:
            update_pin(pin, doc.scene, doc.arrays, doc.gt)
            pin.textures["stale"] = {"pred", "gt"}

    def dirty(self) -> None:
        """The display changed: probe images are drawn again."""
        for pin in self.images.doc.pins:
            pin.textures["stale"] = {"pred", "gt"}

    def probe_image(self, pin: Pin, which: str, size: tuple[int, int]) -> moderngl.Texture | None:
        """The pin's probe ("pred" or "gt") drawn into an RGBA8 texture of ``size`` (w, h) with the
        pin's exposure and the HDR tone map, nearest-neighbour (its texels stay visible)."""
        probe = pin.probe if which == "pred" else pin.probe_gt
        if probe is None:
            return None
        t = pin.textures
        key = f"img-{which}"
        stale = t.setdefault("stale", {"pred", "gt"})
        if which in stale or t.get(key + "-size") != size or key not in t:
            src = self.renderer.texture(probe.transpose(1, 2, 0), t.get(f"src-{which}"))
            t[f"src-{which}"] = src
            if t.get(key + "-size") != size:
                for k in (key, key + "-fbo"):
                    if k in t:
                        t.pop(k).release()
                t[key] = self.ctx.texture(size, 4)
                t[key + "-fbo"] = self.ctx.framebuffer([t[key]])
                t[key + "-size"] = size
            h, w = probe.shape[1:]
            view = EquirectView()
            view.fit(size, (h, w))
            d = Display(kind="hdr", tonemap=self.hdr.tonemap, exposure=pin.exposure, offset=self.hdr.offset,
                        false_range=self.hdr.false_range)
            self.renderer.render(t[key + "-fbo"], (0, 0, *size),
                                 Frame(texture=src, pano_size=(h, w), view=view, display=d, nearest=True,
                                       background=BACKGROUND))
            stale.discard(which)
        return t[key]
