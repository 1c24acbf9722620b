"""The scene renderer: a short chain of GL passes drawing one layer of a panorama into a view.

1. layer pass   -> ``hdr``: the layer's linear values resampled into view pixels (RGBA32F, alpha =
   panorama coverage, with a depth buffer);
2. linear passes (``Renderer.linear_passes``): hooks drawing onto ``hdr`` in linear values with the
   same camera;
3. display pass -> target: exposure/offset and tone map, or colour map for scalar layers;
4. overlay passes (``Renderer.overlay_passes``): probe markers and the like, in display colours.

Everything runs on the thread that owns the GL context.  The renderer knows nothing of imgui or
GLFW, so it runs on a standalone EGL context as well as in the window.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import moderngl
import numpy as np

from phyir.insert.views import EquirectView, PerspectiveView, View
from viewer.compare import MODES
from viewer.gl.programs import ProgramCache, set_uniform, set_view

KINDS = {"hdr": 0, "colour": 1, "normal": 2, "scalar": 3}
TONEMAPS = ("srgb", "aces", "false")
CHANNELS = ("rgb", "r", "g", "b", "luminance")  # what colour layers show (display.glsl's `channel`)
COLORMAPS = ("viridis", "magma", "inferno", "turbo", "gray")
FALSE_COLOUR_MAP = "turbo"
MAX_MARKERS = 32  # shaders/markers.frag


@dataclass
class Display:
    """How linear values become display colours."""

    kind: str = "hdr"                       # one of KINDS
    tonemap: str = "srgb"                   # hdr: one of TONEMAPS
    exposure: float = 0.0                   # EV
    offset: float = 0.0                     # added after exposure (hdr)
    colormap: str = "viridis"               # scalar layers
    range: tuple[float, float] = (0.0, 1.0)  # scalar: values mapped to [0, 1] of the colour map
    false_range: tuple[float, float] = (-8.0, 8.0)  # false colour: log2 luminance range
    channel: str = "rgb"                    # hdr and colour layers: one of CHANNELS (as grey)


@dataclass
class Compare:
    """The view against the same layer of a reference image (``shaders/compare.glsl``)."""

    mode: str                               # one of viewer.compare.MODES
    texture: moderngl.Texture               # the reference's layer
    split: float = 0.5                      # split: where the reference starts, fraction of the view width
    range: tuple[float, float] = (-1.0, 1.0)  # metrics: values mapped onto the colour map
    colormap: str = "coolwarm"              # metrics: the colour map


@dataclass
class Marker:
    x: float  # framebuffer pixels from the view's top-left corner
    y: float
    colour: tuple[float, float, float]
    label: str = ""


@dataclass
class Frame:
    """One view of one layer: everything a pass needs to draw."""

    texture: moderngl.Texture
    pano_size: tuple[int, int]              # (H, W) the layer is laid over
    view: View
    display: Display
    nearest: bool = False
    markers: Sequence[Marker] = ()
    background: tuple[float, float, float] = (0.12, 0.12, 0.13)
    # filled in by Renderer.render
    rect: tuple[int, int, int, int] = (0, 0, 0, 0)  # view rect in the target, px from top-left
    # for linear/overlay passes: "layers" (name -> texture of the shown scene), "scene" (PanoScene),
    # "marker_radius"; passes may add their own keys
    extras: dict = field(default_factory=dict)
    compare: Compare | None = None          # drawn against a reference (one-pass path only)


Pass = Callable[["Renderer", Frame], None]


def colormap_lut(name: str, n: int = 256) -> np.ndarray:
    """``n`` x 3 float32 RGB entries of a matplotlib colour map ("gray" is the identity ramp)."""
    from matplotlib import colormaps

    return colormaps[name].resampled(n)(np.linspace(0, 1, n))[:, :3].astype(np.float32)


class Renderer:
    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.programs = ProgramCache(ctx)
        self._cache: moderngl.Framebuffer | None = None  # the last view drawn with a cache key
        self._cache_key: tuple | None = None
        self.cache_misses = 0
        self.display_pixels = 0  # the display pass's, last frame (overlay passes may overwrite some)
        self._luts: dict[str, moderngl.Texture] = {}
        self._hdr: moderngl.Framebuffer | None = None
        self.linear_passes: list[Pass] = []
        self.overlay_passes: list[Pass] = [draw_markers]
        # the shader variants drawn so far, as software GL tells them apart (program, sampled
        # textures' classes, target's class): a new one costs a compile at its first draw
        self.variants: set[tuple] = set()
        self.first_draws: list[tuple] = []

    # -- resources ---------------------------------------------------------------------------
    def texture(self, array: np.ndarray, old: moderngl.Texture | None = None) -> moderngl.Texture:
        """An equirect float texture from an H x W x C array (C = 1 or 3); reuses ``old`` when the
        shape matches.  Wraps in longitude, clamps at the poles, bilinear."""
        a = np.ascontiguousarray(array, dtype=np.float32)
        if a.ndim == 2:
            a = a[..., None]
        h, w, c = a.shape
        if old is not None and old.size == (w, h) and old.components == c:
            old.write(a)
            return old
        if old is not None:
            old.release()
        tex = self.ctx.texture((w, h), c, a, dtype="f4")
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        tex.repeat_x, tex.repeat_y = True, False
        return tex

    def program(self, frag: str, **defines: int) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """A full-screen program of ``frag`` compiled with ``defines`` (cached), and its VAO."""
        prog = self.programs.program("fullscreen.vert", frag, **defines)
        return prog, self.programs.fullscreen(prog)

    def warm_up(self, target: moderngl.Framebuffer | None = None) -> None:
        """Load the colour maps (imports matplotlib) and draw every shader variant a file can need
        once now, so no frame of a loading file stalls on a compile.  Software GL (llvmpipe)
        compiles a variant at its first draw for each combination of the sampled textures' formats
        and power-of-two-ness of their sides and of the target's format (see ``variants``): each
        display variant is drawn with a layer of its real format (one channel for scalar layers),
        the default display of a panorama and the copy of the cached view for every power-of-two
        class, into the cache's format and into ``target``, the framebuffer frames go to (a corner
        of it is drawn over).  29 variants: 3.7 s of CPU without Mesa's shader disk cache (the first
        run on a machine), 0.1 s from it."""
        for name in (*COLORMAPS, FALSE_COLOUR_MAP):
            self.lut(name)
        made: list = []
        textures: dict[tuple[int, int, int], moderngl.Texture] = {}

        def layer(w: int, h: int, c: int) -> moderngl.Texture:
            if (w, h, c) not in textures:
                textures[w, h, c] = self.texture(np.ones((h, w, c), np.float32))
                made.append(textures[w, h, c])
            return textures[w, h, c]

        cache_tex = self.ctx.texture((4, 4), 4)  # the format of the cached view and the probe images
        cache = self.ctx.framebuffer([cache_tex])
        made += [cache, cache_tex]
        target = target or cache
        marker = [Marker(1.0, 1.0, (1.0, 1.0, 1.0))]
        displays = [Display(kind="hdr", tonemap=t) for t in TONEMAPS] + \
                   [Display(kind=k) for k in ("colour", "normal", "scalar")]
        for view, nearest in ((EquirectView(), False), (EquirectView(), True), (PerspectiveView(), False)):
            for d in displays:  # (the app draws the perspective view bilinear only)
                tex = layer(4, 2, 1 if d.kind == "scalar" else 3)
                self.render(cache, (0, 0, 4, 4), Frame(tex, (2, 4), view, d, nearest, marker))
        for w, h in POT_CLASSES:
            for nearest in (False, True):
                frame = Frame(layer(w, h, 3), (h, w), EquirectView(), Display(), nearest, marker)
                self.render(cache, (0, 0, 4, 4), frame)
                self.render(target, (0, 0, 4, 4), frame, fb_size=(4, 4))  # drawn directly (objects shown)
            self._release_cache()
            self.render(target, (0, 0, w, h), frame, fb_size=(4, 4), cache_key=("warm-up",))
        self.ctx.finish()
        self._release_cache()
        for obj in made:
            obj.release()

    def note_variant(self, shader: str, defines: dict[str, int], textures: Sequence[moderngl.Texture],
                     target: moderngl.Framebuffer) -> None:
        """Record the shader variant a draw uses (``variants``; ``first_draws`` in order); passes
        call it for their own draws."""
        key = ((shader, *sorted(defines.items())), tuple(map(texture_class, textures)),
               framebuffer_class(target))
        if key not in self.variants:
            self.variants.add(key)
            self.first_draws.append(key)

    def lut(self, name: str) -> moderngl.Texture:
        if name not in self._luts:
            tex = self.ctx.texture((256, 1), 3, colormap_lut(name), dtype="f4")
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
            self._luts[name] = tex
        return self._luts[name]

    def hdr_target(self, w: int, h: int) -> moderngl.Framebuffer:
        """The linear-value framebuffer of pass 1 (RGBA32F + depth), resized on demand."""
        if self._hdr is None or self._hdr.size != (w, h):
            if self._hdr is not None:
                for a in (*self._hdr.color_attachments, self._hdr.depth_attachment):
                    a.release()
                self._hdr.release()
            colour = self.ctx.texture((w, h), 4, dtype="f4")
            colour.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._hdr = self.ctx.framebuffer([colour], self.ctx.depth_renderbuffer((w, h)))
        return self._hdr

    # -- drawing -----------------------------------------------------------------------------
    def render(self, target: moderngl.Framebuffer, rect: tuple[int, int, int, int], frame: Frame,
               fb_size: tuple[int, int] | None = None, cache_key: tuple | None = None,
               stale_ok: bool = False) -> None:
        """Draw ``frame`` into ``rect`` = (x, y, w, h) of ``target`` (pixels, y from the top);
        ``fb_size``: the target's size when ``target.size`` can't be trusted (a window's default
        framebuffer after a resize).

        Without linear passes the layer look-up and the display transform run as one pass (half
        the fill cost on software GL); with them, through the linear ``hdr`` framebuffer.
        With a ``cache_key`` (anything hashable describing everything the picture depends on) the
        view is drawn once into a cache and copied while the key stays the same: frames where only
        the interface changes (hover, progress) then cost a copy instead of the passes.  With
        ``stale_ok`` a cached picture of the right size is copied even if the key changed, or
        nothing is drawn when there is none (the next call redraws): spreads an expensive frame
        over two.
        """
        x, y, w, h = (int(round(r)) for r in rect)
        if w <= 0 or h <= 0:
            return
        if cache_key is None:
            self._draw(target, (x, y, w, h), frame, (fb_size or target.size)[1])
            return
        cache = self._cache
        if stale_ok and (cache is None or cache.size != (w, h)):
            return  # nothing to show yet: the view appears with the next call
        if not stale_ok and (cache is None or cache.size != (w, h) or self._cache_key != cache_key):
            if cache is None or cache.size != (w, h):
                self._release_cache()
                cache = self._cache = self.ctx.framebuffer([self.ctx.texture((w, h), 4)])
            self._draw(cache, (0, 0, w, h), frame, h)
            self._cache_key = cache_key
            self.cache_misses += 1
        fb_h = (fb_size or target.size)[1]
        frame.rect = (x, y, w, h)
        prog, vao = self.program("blit.frag")
        self.note_variant("blit.frag", {}, (cache.color_attachments[0],), target)
        target.use()
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        self.ctx.viewport = (x, fb_h - y - h, w, h)
        cache.color_attachments[0].use(0)
        prog["src"] = 0
        prog["origin"] = (float(x), float(fb_h - y - h))
        vao.render(moderngl.TRIANGLES, vertices=3)

    def _release_cache(self) -> None:
        if self._cache is not None:
            self._cache.color_attachments[0].release()
            self._cache.release()
        self._cache, self._cache_key = None, None

    def _draw(self, target: moderngl.Framebuffer, rect: tuple[int, int, int, int], frame: Frame,
              fb_h: int) -> None:
        x, y, w, h = rect
        ctx = self.ctx
        frame.rect = (x, y, w, h)
        hole = self._overwritten(frame)  # first: the passes' preparations bind their own framebuffers
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        view_defs = {"VIEW_KIND": int(isinstance(frame.view, PerspectiveView)), "NEAREST": int(frame.nearest)}
        d = frame.display
        disp_defs = {"KIND": KINDS[d.kind], "TONEMAP": TONEMAPS.index(d.tonemap) if d.kind == "hdr" else 0}
        if self.linear_passes and frame.compare is None:
            hdr = self.hdr_target(w, h)
            hdr.use()
            hdr.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            prog, vao = self.program("layer.frag", **view_defs)
            self.note_variant("layer.frag", view_defs, (frame.texture,), hdr)
            self._set_layer(prog, frame, (0, 0, w, h), h)
            vao.render(moderngl.TRIANGLES, vertices=3)
            for p in self.linear_passes:
                p(self, frame)
            ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            prog, vao = self.program("display.frag", **disp_defs)
            self.note_variant("display.frag", disp_defs, (hdr.color_attachments[0], self._cmap(d)), target)
            target.use()
            ctx.viewport = (x, fb_h - y - h, w, h)
            hdr.color_attachments[0].use(0)
            set_uniform(prog, "hdr", 0)
            set_uniform(prog, "hdr_origin", (float(x), float(fb_h - y - h)))
        else:
            if frame.compare is not None:
                disp_defs["COMPARE"] = MODES.index(frame.compare.mode) + 1
            prog, vao = self.program("view.frag", **view_defs, **disp_defs)
            self.note_variant("view.frag", {**view_defs, **disp_defs}, (frame.texture, self._cmap(d)), target)
            target.use()
            ctx.viewport = (x, fb_h - y - h, w, h)
            self._set_layer(prog, frame, (x, y, w, h), fb_h)
        self.set_display(prog, frame)
        if frame.compare is not None:
            self._set_compare(prog, frame.compare, w)
        self._render_around(vao, (x, fb_h - y - h, w, h), hole)
        for p in self.overlay_passes:
            p(self, frame)

    def _overwritten(self, frame: Frame) -> tuple[int, int, int, int] | None:
        """The view region (x, y, w, h from the view's top left) an overlay pass will draw whole this
        frame (its optional ``overwrites(renderer, frame)``), or None."""
        for p in self.overlay_passes:
            hook = getattr(p, "overwrites", None)
            hole = hook(self, frame) if hook is not None else None
            if hole is not None:
                return hole
        return None

    def _render_around(self, vao: moderngl.VertexArray, viewport: tuple[int, int, int, int],
                       hole: tuple[int, int, int, int] | None) -> None:
        """The display pass over ``viewport`` (framebuffer pixels) except the view region ``hole``
        (an overlay pass overwrites it): scissored strips, so each pixel drawn is the same as
        without a hole.  ``display_pixels``: how many it drew."""
        x, y, w, h = viewport
        if hole is not None:
            hx, hy, hw, hh = hole
            hole = (x + hx, y + h - hy - hh, hw, hh)  # from the bottom, in framebuffer pixels
        self.display_pixels = draw_around(self.ctx, viewport, hole,
                                          lambda: vao.render(moderngl.TRIANGLES, vertices=3))

    def _set_layer(self, prog: moderngl.Program, frame: Frame, rect, fb_height: int) -> None:
        set_view(prog, frame.view, rect, fb_height)
        frame.texture.use(0)
        set_uniform(prog, "layer", 0)
        H, W = frame.pano_size
        set_uniform(prog, "pano_size", (float(W), float(H)))

    def set_display(self, prog: moderngl.Program, frame: Frame) -> None:
        """The uniforms of ``shaders/display.glsl``: exposure, offset and range of ``frame.display``,
        its colour map on unit 1 and the background (passes that redo the display transform use it)."""
        d = frame.display
        set_uniform(prog, "exposure", float(d.exposure))
        set_uniform(prog, "offset", float(d.offset))
        false = d.kind == "hdr" and d.tonemap == "false"
        lo, hi = d.false_range if false else d.range
        set_uniform(prog, "range", (float(lo), float(hi) if hi != lo else float(lo) + 1e-6))
        self._cmap(d).use(1)
        set_uniform(prog, "cmap", 1)
        set_uniform(prog, "background", tuple(float(c) for c in frame.background))
        set_uniform(prog, "channel", CHANNELS.index(d.channel))

    def _set_compare(self, prog: moderngl.Program, c: Compare, view_w: int) -> None:
        """The uniforms of ``shaders/compare.glsl``: the reference on unit 2, its colour map on 3."""
        c.texture.use(2)
        set_uniform(prog, "reference", 2)
        self.lut(c.colormap).use(3)
        set_uniform(prog, "compare_cmap", 3)
        lo, hi = c.range
        set_uniform(prog, "compare_range", (float(lo), float(hi) if hi != lo else float(lo) + 1e-6))
        set_uniform(prog, "split_x", float(np.clip(c.split, 0.0, 1.0) * view_w))

    def _cmap(self, d: Display) -> moderngl.Texture:
        """The colour map a display samples (the false-colour one for false-colour HDR)."""
        return self.lut(FALSE_COLOUR_MAP if d.kind == "hdr" and d.tonemap == "false" else d.colormap)

    def read(self, target: moderngl.Framebuffer, rect: tuple[int, int, int, int] | None = None,
             components: int = 3) -> np.ndarray:
        """uint8 pixels (rows from the top) of ``rect`` (x, y, w, h; y from the top) of ``target``."""
        W, H = target.size
        x, y, w, h = rect or (0, 0, W, H)
        data = target.read(viewport=(x, H - y - h, w, h), components=components)
        return np.frombuffer(data, np.uint8).reshape(h, w, components)[::-1].copy()

    def read_linear(self) -> np.ndarray:
        """The last frame's pass-1 values (h x w x 4 float32, rows from the top)."""
        assert self._hdr is not None
        w, h = self._hdr.size
        data = self._hdr.read(components=4, dtype="f4")
        return np.frombuffer(data, np.float32).reshape(h, w, 4)[::-1].copy()

    def release(self) -> None:
        self._release_cache()
        for t in self._luts.values():
            t.release()
        self._luts.clear()
        self.programs.release()


POT_CLASSES = ((4, 2), (3, 2), (4, 3), (3, 3))  # (w, h) sizes: each side a power of two or not


def strips_around(rect: tuple[int, int, int, int], hole: tuple[int, int, int, int]
                  ) -> list[tuple[int, int, int, int]]:
    """Up to four (x, y, w, h) rectangles covering ``rect`` except ``hole`` (inside it; same axes)."""
    x, y, w, h = rect
    hx, hy, hw, hh = hole
    strips = [(x, y, w, hy - y), (x, hy + hh, w, y + h - hy - hh),
              (x, hy, hx - x, hh), (hx + hw, hy, x + w - hx - hw, hh)]
    return [s for s in strips if s[2] > 0 and s[3] > 0]


def draw_around(ctx: moderngl.Context, rect: tuple[int, int, int, int],
                hole: tuple[int, int, int, int] | None, draw: Callable[[], None]) -> int:
    """``draw()`` over the framebuffer rectangle ``rect`` except ``hole`` (inside it, None: nowhere),
    in scissored strips; returns the pixels covered."""
    if hole is None:
        draw()
        return rect[2] * rect[3]
    strips = strips_around(rect, hole)
    for s in strips:
        ctx.scissor = s
        draw()
    ctx.scissor = None
    return sum(s[2] * s[3] for s in strips)


def _pot(n: int) -> bool:
    return n > 0 and n & (n - 1) == 0


def texture_class(tex: moderngl.Texture) -> tuple:
    """What software GL compiles a shader variant for, of a texture it samples: its format and
    whether each side is a power of two (llvmpipe's static texture state)."""
    w, h = tex.size
    return tex.components, tex.dtype, _pot(w), _pot(h)


def framebuffer_class(fb: moderngl.Framebuffer) -> tuple:
    """What software GL compiles a shader variant for, of the framebuffer it draws into: the
    colour formats and whether there is a depth buffer (a window's own framebuffer: "default")."""
    colours = tuple((a.components, a.dtype) for a in fb.color_attachments or ()) or ("default",)
    return colours, fb.depth_attachment is not None


def draw_markers(r: Renderer, frame: Frame) -> None:
    """Rings around the pinned probes (overlay pass): one instanced quad per marker."""
    ms = list(frame.markers)[:MAX_MARKERS]
    if not ms:
        return
    prog = r.programs.program("markers.vert", "markers.frag")
    vao = r.programs.fullscreen(prog)
    r.note_variant("markers", {}, (), r.ctx.fbo)
    pos = np.zeros((MAX_MARKERS, 2), np.float32)
    col = np.zeros((MAX_MARKERS, 3), np.float32)
    for k, m in enumerate(ms):
        pos[k] = (m.x, m.y)
        col[k] = m.colour
    prog["marker_pos"].write(pos.tobytes())
    prog["marker_colour"].write(col.tobytes())
    prog["radius"] = float(frame.extras.get("marker_radius", 9.0))
    prog["view_size"] = (float(frame.rect[2]), float(frame.rect[3]))
    r.ctx.enable(moderngl.BLEND)
    r.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
    vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=len(ms))
    r.ctx.disable(moderngl.BLEND)
