"""The App's pinned probes: pinning, their read-outs and their probe images."""

from __future__ import annotations

import moderngl
import numpy as np

from phyir.errors import PhyIRError
from phyir.insert.views import EquirectView
from viewer.app.common import BACKGROUND, gl_current
from viewer.probes import Pin, make_pin, pixel_values, update_pin
from viewer.renderer import Display, Frame


class Pins:
    """Part of :class:`viewer.app.App`: probes pinned at panorama positions."""

    # -- probes -------------------------------------------------------------------------------
    def pin_probe(self, u: float, v: float) -> Pin:
        """Pin the probe at panorama coordinates (u, v) (column, row; pixel centres at +0.5)."""
        if self.scene is None:
            raise PhyIRError("no panorama is open")
        pin = make_pin(u, v, len(self.pins), self.scene, self.arrays, self.gt, self.hdr.exposure)
        self.pins.append(pin)
        if self.gui is not None:
            self.gui.scroll_to_pin = len(self.pins) - 1
        return pin

    @gl_current
    def unpin(self, index: int = -1) -> None:
        if self.pins:
            self.release_pin(self.pins.pop(index))

    def set_pin_exposure(self, index: int, ev: float) -> None:
        self.pins[index].exposure = float(ev)
        self.pins[index].textures["stale"] = {"pred", "gt"}

    def pin_values(self, u: float, v: float, source: str = "pred") -> dict[str, np.ndarray]:
        """Every layer's value at (u, v) (what the read-out shows)."""
        arrays = self.gt_arrays if source == "gt" else self.arrays
        return pixel_values(arrays, u, v, self.size) if self.size else {}

    def refresh_pins(self) -> None:
        for pin in self.pins:
            update_pin(pin, self.scene, self.arrays, self.gt)
            pin.textures["stale"] = {"pred", "gt"}

    def dirty_pins(self) -> None:
        for pin in self.pins:
            pin.textures["stale"] = {"pred", "gt"}

    def release_pin(self, pin: Pin) -> None:
        for obj in pin.textures.values():
            if isinstance(obj, (moderngl.Texture, moderngl.Framebuffer)):
                obj.release()
        pin.textures.clear()

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
