"""The viewer's full-quality picture of the inserted objects, built a slice at a time.

While an object is dragged the view draws drafts (``viewer.gl.quality.DRAGGING``).  A still frame
needs the full quality, about a second of work on software GL (the objects' lighting on the CPU,
their impostors, shadow maps and the composite), which would stop the interface for as long.
:class:`Refinement` builds it on the side while the view goes on showing the draft:

1. the objects' lighting at full quality on the worker thread (``ObjectStates.lighting_ready``);
2. their impostors in strips of texel rows, the shadow maps one at a time
   (``ImpostorPasses.prepare_steps``), in atlases of its own: a fork of the draft's renderer, so
   draft frames and refinement don't draw over each other's tiles;
3. the composite into an off-screen texture in strips of rows.

Each :meth:`Refinement.advance` (once a frame) draws at most one slice, its size taken from what
the last slices of its kind cost, to about ``budget_s``; none in a frame whose input changed the
picture (while the view is panned, say, frames draw only the draft).  The picture is shown once complete and
until anything it depends on (its key) changes; a change starts it again (tiles of objects that did
not change are kept).  The pixels are those of the frame drawn in one piece: the same draws, in
scissored strips, at the same pixel positions.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Generator

import moderngl

from phyir.insert.objects import SceneObject
from phyir.insert.views import pixel_angle
from viewer.gl.quality import FULL

SLICE_BUDGET_S = 0.05  # GL time a slice aims at (a frame also draws the interface)
FIRST_ROWS = 16  # rows of a strip of a kind whose cost is not known yet
MIN_ROWS = 4
COST_WINDOW = 4  # a strip is sized for the dearest of the last few of its kind


class Refinement:
    """The full-quality picture of one set of objects in one view, a slice per :meth:`advance`.

    ``done``: the picture is complete (``rect``: the view region it covers, None when the objects
    change nothing in view); ``slices`` lists the kinds of the slices drawn since the last start
    ("lighting": a frame that waited for the worker, "impostor", "shadow", "composite")."""

    def __init__(self, insertion):
        self.insertion = insertion  # the draft frames' InsertionRenderer
        self.twin = None  # its fork: full-quality object states and atlases
        self.key: tuple | None = None
        self.done = False
        self.active = False  # the view shows the objects (else no frames are needed for this)
        self.rect: tuple[int, int, int, int] | None = None
        self.budget_s = SLICE_BUDGET_S
        self.finish: Callable[[], None] = insertion.ctx.finish  # waits for the GL (timing a slice)
        self.slices: list[str] = []
        self.starts = 0
        self._steps: Generator | None = None
        self._costs: dict[str, deque] = {}  # the last seconds per unit of work of each kind of strip
        self._canvas: tuple | None = None  # (framebuffer, texture) the composite is drawn into
        self._origin = (0, 0)  # the canvas texel of the region's bottom-left pixel
        self._whole = False

    @property
    def running(self) -> bool:
        """A picture is being built for the view shown: frames should go on."""
        return self.active and not self.done

    def shows(self, key: tuple) -> bool:
        """Whether the picture is complete for ``key``."""
        return self.done and key == self.key

    def advance(self, key: tuple, objects: list[SceneObject], frame, size: tuple[int, int], fusion: str,
                composite: Callable, final: bool = False) -> None:
        """One slice of the picture ``key`` names (started again if that changed): ``objects``
        in ``frame``'s view of ``size`` = (w, h) pixels; ``composite(frame, view_rect, fb_height)``
        gives the composite program with the frame's uniforms set.  With ``final`` all that is
        left, in one go (a screenshot: waits for the lighting)."""
        self.active = True
        if key != self.key:
            self._start(key, objects, frame, size, fusion, composite)
            if not final:
                return  # input goes on, maybe: this frame is the draft's, slices start with the next
        if self.done:
            return
        if final:
            self._whole = True
            try:
                while not self.done:
                    if self._next()[0] == "lighting":
                        self.twin.wait_lighting()
            finally:
                self._whole = False
            return
        self.finish()  # what earlier passes queued is not this slice's
        t = time.perf_counter()
        kind, strip = self._next()
        if strip is not None:
            self.finish()
            work = _work(kind, *strip)
            self._costs.setdefault(kind, deque(maxlen=COST_WINDOW)).append((time.perf_counter() - t) / work)

    def pause(self, objects: list[SceneObject]) -> None:
        """The view does not show the objects now (dragging, another layer): no frames for this.
        Deleted objects' states are freed, and everything once no object is left to show."""
        self.active = False
        if self.twin is not None and not any(o.visible for o in objects):
            self.release()  # made again when objects come back
        elif self.twin is not None:
            self.twin.forget(objects)

    def _start(self, key, objects, frame, size, fusion, composite) -> None:
        ins = self.insertion
        if self.twin is None or self.twin.scene is not ins.scene:
            if self.twin is not None:
                self.twin.release_fork()
            self.twin = ins.fork()
        self.twin.use_projection, self.twin.footprint_scale = ins.use_projection, ins.footprint_scale
        if self._steps is not None:
            self._steps.close()
        self.key, self.done, self.rect, self.slices = key, False, None, []
        self.starts += 1
        self._steps = self._build(list(objects), frame, size, fusion, composite)

    def _next(self) -> tuple[str, tuple | None]:
        """Run the build to its next slice: (kind, the strip drawn: (width, first row, rows) or None)."""
        try:
            kind, strip = next(self._steps)
        except StopIteration:
            self.done = True
            return "done", None
        except Exception:
            self.key = None  # (e.g. a lighting job's error) the next frame starts again
            raise
        self.slices.append(kind)
        return kind, strip

    def _rows(self, kind: str, width: int, start: int) -> int:
        """Rows of the next strip of ``kind`` (``width`` texels wide, from row ``start``): about
        ``budget_s`` of work at the dearest cost of the last few strips of its kind (a slow one, e.g.
        under load or compiling a shader, shrinks the next few)."""
        costs = self._costs.get(kind)
        if self._whole:
            return 1 << 30
        if not costs:
            return FIRST_ROWS
        budget, rows, work = self.budget_s / max(costs), 0, 0.0
        while work < budget and rows < 4096:
            work += _work(kind, width, start + rows, 1)
            rows += 1
        return max(MIN_ROWS, rows - (work > budget))

    def _build(self, objects, frame, size, fusion, composite) -> Generator[tuple[str, int], None, None]:
        twin = self.twin
        while not twin.lighting_ready(objects, FULL):
            yield "lighting", None
        H, W = twin.scene.size
        angle = pixel_angle(frame.view, size, (H, W))
        drawn = yield from twin.prepare_steps(objects, angle, FULL, fusion, self._rows)
        rect = twin.screen_rect(drawn, frame.view, size) if drawn else None
        if rect is None:
            return  # nothing of the objects in view
        fbo = self._target(rect, size)
        y, rows_left = 0, rect[3]
        while rows_left > 0:
            rows = min(rows_left, self._rows("composite", rect[2], y))
            self._composite_strip(fbo, drawn, frame, rect, size, y, rows, composite)
            y, rows_left = y + rows, rows_left - rows
            if rows_left == 0:
                self.rect, self.done = rect, True
            yield "composite", (rect[2], y - rows, rows)

    def _target(self, rect: tuple[int, int, int, int], size: tuple[int, int]) -> moderngl.Framebuffer:
        """The canvas for the region ``rect`` of a view of ``size``: one texel larger each way, so
        that the region lies on the pixels' parity of the view drawn at a framebuffer's origin (the
        view's cache; the same 2x2 quads)."""
        rx, ry, rw, rh = rect
        self._origin = (rx % 2, (size[1] - ry - rh) % 2)
        want = (rw + 1, rh + 1)
        if self._canvas is None or self._canvas[1].size != want:
            self._release_canvas()
            tex = self.insertion.ctx.texture(want, 4)  # RGBA8: the view's format, what it is shown in
            self._canvas = (self.insertion.ctx.framebuffer([tex]), tex)
        return self._canvas[0]

    def _composite_strip(self, fbo, drawn, frame, rect, size, y: int, rows: int, composite) -> None:
        """Rows ``y`` to ``y + rows`` (from the region's bottom) of the composite over ``rect``."""
        ctx, twin = self.insertion.ctx, self.twin
        ox, oy = self._origin
        rx, ry, rw, rh = rect
        fb_h = fbo.size[1]
        fbo.use()
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.viewport = (ox, oy, rw, rh)
        ctx.scissor = (ox, oy + y, rw, rows)
        # the view placed so that canvas texel (ox, oy) is the region's bottom-left pixel
        prog = composite(frame, (ox - rx, fb_h - oy - ry - rh, *size), fb_h)
        twin.bind_scene(prog)
        twin.composite_uniforms(prog, drawn)
        twin.draw_fullscreen(prog)
        ctx.scissor = None

    def show(self, renderer, frame, fb_h: int) -> None:
        """Copy the complete picture into the bound framebuffer over its region of ``frame``'s
        view (``fb_h``: the framebuffer's height)."""
        if self.rect is None:
            return
        ctx = self.insertion.ctx
        x, y, _, _ = frame.rect
        rx, ry, rw, rh = self.rect
        X, Y = x + rx, fb_h - y - ry - rh
        prog, vao = renderer.program("blit.frag")
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.viewport = (X, Y, rw, rh)
        self._canvas[1].use(0)
        prog["src"] = 0
        prog["origin"] = (float(X - self._origin[0]), float(Y - self._origin[1]))
        vao.render(moderngl.TRIANGLES, vertices=3)

    def _release_canvas(self) -> None:
        if self._canvas is not None:
            for r in self._canvas:
                r.release()
        self._canvas = None

    def release(self) -> None:
        """Free the canvas and the fork's states and atlases (before the renderer it forked)."""
        if self._steps is not None:
            self._steps.close()
            self._steps = None
        self._release_canvas()
        if self.twin is not None:
            self.twin.release_fork()
            self.twin = None
        self.key, self.done = None, False


def _work(kind: str, width: int, start: int, rows: int) -> float:
    """What a strip of ``kind`` costs, in units its time is measured per: texels for the composite
    (the same shading everywhere); for an impostor tile (``width`` texels square) mostly its texels
    inside the object's outline, a disc filling the tile, plus a tenth of the rest (clears, quads)."""
    if kind != "impostor":
        return float(width * rows)
    r = width / 2
    inside = sum(2 * math.sqrt(max(r * r - (y + 0.5 - r) ** 2, 0.0)) for y in range(start, start + rows))
    return 0.9 * inside + 0.1 * width * rows
