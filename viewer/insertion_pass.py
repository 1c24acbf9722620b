"""The inserted objects as an overlay pass of the viewer's renderer (:class:`InsertionPass`): draft
frames while an object is dragged (``viewer.gl.quality.DRAGGING``), the full-quality picture built a
slice per frame for still frames (``viewer.refinement``), drawn from an
:class:`viewer.insertion.InsertionRenderer` (docs/insertion.md, docs/viewer.md)."""

from __future__ import annotations

import math
from dataclasses import astuple, replace

import moderngl

from phyir.insert.objects import SceneObject
from phyir.insert.views import EquirectView, PerspectiveView, pixel_angle
from viewer.gl.object_state import state_key
from viewer.gl.programs import set_uniform, set_view
from viewer.gl.quality import DRAGGING, FULL, Quality
from viewer.insertion import InsertionRenderer, composite_defines
from viewer.refinement import Refinement
from viewer.renderer import KINDS, TONEMAPS, draw_around


class InsertionPass:
    """The objects of one scene as an overlay pass of :class:`viewer.renderer.Renderer`
    (its owner puts it first: ``renderer.overlay_passes.insert(0, InsertionPass(...))``).

    Overlay passes run right after the display pass, with its framebuffer and viewport bound; the
    region the objects change is drawn again from the layer (``layer.glsl``, the renderer's own
    look-up) composited and tonemapped (``display.glsl``), so a frame with objects costs the bare
    frame plus that region.  Draws while ``enabled`` and ``frame.extras.get("insert", True)``;
    ``dragging`` selects the cheaper :data:`DRAGGING` quality.  Still frames (``progressive``) show
    drafts too until the full-quality picture, built a slice per frame by :meth:`refine`
    (``viewer.refinement``), is complete, then that picture; without ``progressive`` they draw at
    full quality in one piece."""

    def __init__(self, insertion: InsertionRenderer, objects: list[SceneObject] | None = None):
        self.insertion = insertion
        self.objects: list[SceneObject] = objects if objects is not None else []
        self.enabled = True
        self.dragging = False
        self.progressive = True
        self.refinement = Refinement(insertion)
        self.background_lighting = True  # while dragging: a moved object's lighting on a worker thread
        self.impostor_every = 2  # while dragging: a moved object's impostor drawn every other frame
        self.receivers_every = 2  # and the draft's receivers on the frames it is not (_receivers_due)
        self.receivers_drawn = 0  # draft receiver passes drawn so far
        self._receivers_key: tuple | None = None
        self._receivers_kept = False
        self.fusion = "three-image"
        self.last_rect: tuple[int, int, int, int] | None = None
        self._plan: tuple | None = None  # (frame, what _plan_frame returned) from overwrites()

    # -- the full-quality picture, a slice per frame ---------------------------------------------
    def still_key(self, frame, size: tuple[int, int]) -> tuple | None:
        """Everything the full-quality picture of the objects in ``frame``'s view of ``size`` =
        (w, h) depends on; None when it is not wanted (no objects drawn, dragging, not progressive)."""
        ins = self.insertion
        if self.dragging or not self.progressive or not self._drawing(frame):
            return None
        objects = tuple((id(o), state_key(o, FULL), astuple(o.material)) for o in self.objects if o.visible)
        return (objects, id(ins.scene), self.fusion, ins.use_projection, ins.footprint_scale,
                type(frame.view).__name__, astuple(frame.view), tuple(size), astuple(frame.display),
                frame.nearest, frame.background, id(frame.texture), frame.extras.get("layer_version"),
                frame.pano_size)

    def picture_key(self, frame, size: tuple[int, int]) -> tuple | None:
        """For the renderer's view cache: what the view's picture takes from the objects (() when it
        shows none), None while every frame differs (dragging, or not ``progressive``).  Draft
        frames while the picture is built are drawn once and copied."""
        if self.dragging or not self.progressive:
            return None
        key = self.still_key(frame, size)
        if key is None:
            return ()
        return ("final" if self.refinement.shows(key) else "draft", key)

    def refine(self, renderer, frame, size: tuple[int, int], final: bool = False) -> None:
        """One slice of the full-quality picture of the view ``frame`` of ``size`` = (w, h), or all
        that is left with ``final`` (a screenshot); the App calls it once a frame, before drawing
        the view.  Nothing while it is not wanted (:meth:`still_key`)."""
        key = self.still_key(frame, size)
        if key is None:
            self.refinement.pause(self.objects)
            return
        self.refinement.advance(key, self.objects, frame, size, self.fusion,
                                lambda f, rect, fb_h: self.composite_program(renderer, f, rect, fb_h), final)

    def refining(self) -> bool:
        """The full-quality picture is being built: frames should go on."""
        return self.refinement.running

    def release(self) -> None:
        self.refinement.release()

    # -- drawing ---------------------------------------------------------------------------------
    def _drawing(self, frame) -> bool:
        ins = self.insertion
        return self.enabled and frame.extras.get("insert", True) and ins.scene is not None \
            and any(o.visible for o in self.objects)

    def overwrites(self, renderer, frame) -> tuple[int, int, int, int] | None:
        """Called by the renderer before the display pass: prepares the objects and returns the view
        region (x, y, w, h) a draft frame will draw whole, which the display pass then skips (it
        would be overwritten); None for full-quality frames (drawn over the display pass as before)."""
        plan = self._plan_frame(frame)
        self._plan = (frame, plan)
        if plan is None or plan[0] != "draft":
            return None
        return plan[1][1]

    def _plan_frame(self, frame) -> tuple | None:
        """("final",) when the refinement's picture is complete for this frame, else ("draft" or
        "full", what _prepare returned); None when nothing is drawn."""
        key = self.still_key(frame, frame.rect[2:])
        if key is not None and self.refinement.shows(key):
            self.insertion.forget(self.objects)
            return ("final",)
        plan = self._prepare(frame, draft=self.dragging or key is not None)
        if plan is None:
            return None
        return ("draft" if plan[2].composite_scale < 1 else "full", plan)

    def _prepare(self, frame, draft: bool) -> tuple[list, tuple[int, int, int, int], Quality] | None:
        """The objects drawn into the atlases, the view region they change and the frame's quality
        (``draft``: the dragging one); None when nothing is drawn.  Leaves other framebuffers bound."""
        ins = self.insertion
        ins.forget(self.objects)  # deleted objects' lighting, unused meshes
        if not self._drawing(frame):
            return None
        _, _, w, h = frame.rect
        quality = replace(DRAGGING, background_lighting=self.background_lighting,
                          impostor_every=self.impostor_every) if draft else FULL
        H, W = ins.scene.size
        drawn = ins.prepare(self.objects, pixel_angle(frame.view, (w, h), (H, W)), quality, self.fusion)
        rect = ins.screen_rect(drawn, frame.view, (w, h)) if drawn else None
        return None if rect is None else (drawn, rect, quality)

    def __call__(self, renderer, frame) -> None:
        ctx = self.insertion.ctx
        self.last_rect = None
        target = ctx.fbo
        vx, vy, vw, vh = ctx.viewport  # the display pass's: (x, fb_h - y - h, w, h)
        planned, self._plan = self._plan, None
        plan = planned[1] if planned is not None and planned[0] is frame else self._plan_frame(frame)
        target.use()
        ctx.viewport = (vx, vy, vw, vh)
        if plan is None:
            return
        x, y, w, h = frame.rect
        fb_h = vy + y + h
        if plan[0] == "final":
            self.refinement.show(renderer, frame, fb_h)
            rect = self.refinement.rect
        else:
            drawn, rect, quality = plan[1]
            if plan[0] == "draft":
                self._draft(renderer, frame, drawn, rect, fb_h, quality)
            else:
                self._full(renderer, frame, drawn, rect, fb_h)
        ctx.viewport = (vx, vy, vw, vh)
        self.last_rect = rect

    def _frame_program(self, prog, renderer, frame, rect, fb_h: float) -> None:
        """The view, layer and display uniforms ``prog`` shares with the display pass."""
        set_view(prog, frame.view, rect, fb_h)
        frame.texture.use(12)
        set_uniform(prog, "layer", 12)
        set_uniform(prog, "pano_size", (float(frame.pano_size[1]), float(frame.pano_size[0])))
        renderer.set_display(prog, frame)  # exposure, tone map and colour map as the display pass

    def _defines(self, frame, quality: Quality, **more: int) -> dict[str, int]:
        d = frame.display
        return dict(VIEWER=1, **composite_defines(quality), NEAREST=int(frame.nearest), KIND=KINDS[d.kind],
                    VIEW_KIND=int(isinstance(frame.view, PerspectiveView)),
                    TONEMAP=TONEMAPS.index(d.tonemap) if d.kind == "hdr" else 0, **more)

    def composite_program(self, renderer, frame, rect, fb_h: float) -> moderngl.Program:
        """The full-quality composite for ``frame`` (display colours) with its view placed at
        ``rect`` (x, y, w, h; y from the top) of a framebuffer ``fb_h`` high, the frame's uniforms set."""
        prog = self.insertion.program("fullscreen.vert", "composite.frag", **self._defines(frame, FULL))
        self._frame_program(prog, renderer, frame, rect, fb_h)
        return prog

    def _full(self, renderer, frame, drawn, rect, fb_h: float) -> None:
        """The composite over the region ``rect`` of the view, at its resolution, in one piece."""
        ins, ctx = self.insertion, self.insertion.ctx
        x, y, w, h = frame.rect
        rx, ry, rw, rh = rect
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.viewport = (x + rx, fb_h - y - ry - rh, rw, rh)
        prog = self.composite_program(renderer, frame, (x, y, w, h), fb_h)
        ins.bind_scene(prog)
        ins.composite_uniforms(prog, drawn)
        ins.draw_fullscreen(prog)

    def _draft_programs(self, frame, quality: Quality) -> tuple[moderngl.Program, moderngl.Program]:
        """The draft composite (linear outputs: one variant per view kind, whatever the layer's
        display; each variant costs llvmpipe megabytes) and the pass putting it over the layer."""
        ins = self.insertion
        kind = int(isinstance(frame.view, PerspectiveView))
        prog = ins.program("fullscreen.vert", "composite.frag", VIEWER=1, DRAFT=1, VIEW_KIND=kind,
                           **composite_defines(quality))
        return prog, ins.program("fullscreen.vert", "composite_up.frag", **self._defines(frame, quality))

    def _receivers_due(self, key: tuple) -> bool:
        """Whether this draft frame draws the receivers again: with ``receivers_every`` = 2, a frame
        that drew an impostor keeps the last frame's receivers when they were drawn for the same
        region and view (the costs alternate: one frame the impostor, the next the receivers; the
        shadows lag the object by at most a frame)."""
        keep = self.receivers_every > 1 and self.insertion.drawn_faces["impostor"] > 0 \
            and self._receivers_key == key and not self._receivers_kept
        self._receivers_kept = keep
        self._receivers_key = key
        self.receivers_drawn += not keep
        return not keep

    def _draft(self, renderer, frame, drawn, rect, fb_h: float, quality: Quality) -> None:
        """The receivers (the objects' shadows) at ``quality.composite_scale`` of the region's
        resolution, then put over the layer with the objects at full resolution (the panorama and
        the objects' edges stay sharp while they move)."""
        ins, ctx = self.insertion, self.insertion.ctx
        target = ctx.fbo
        x, y, w, h = frame.rect
        rx, ry, rw, rh = rect
        s = quality.composite_scale
        cw, ch = max(1, math.ceil(rw * s)), max(1, math.ceil(rh * s))
        fbo, keep_tex = ins.draft_targets(cw, ch)
        prog, up = self._draft_programs(frame, quality)
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        fbo.use()
        ctx.viewport = (0, 0, cw, ch)
        ins.bind_scene(prog)
        view = frame.view if isinstance(frame.view, PerspectiveView) else \
            EquirectView(center=frame.view.center, zoom=frame.view.zoom * s)
        self._frame_program(prog, renderer, replace(frame, view=view), (-rx * s, -ry * s, w * s, h * s), ch)
        key = (cw, ch, rect, astuple(view), id(frame.texture))
        if self._receivers_due(key):
            ins.composite_uniforms(prog, drawn)
            ins.draw_fullscreen(prog)
        target.use()
        region = (x + rx, fb_h - y - ry - rh, rw, rh)
        ctx.viewport = region
        self._frame_program(up, renderer, frame, (x, y, w, h), fb_h)
        ins.impostor_uniforms(up, drawn)
        keep_tex.use(14)
        set_uniform(up, "draft_keep", 14)
        set_uniform(up, "draft_rect", tuple(float(r) for r in region))
        set_uniform(up, "draft_uv_scale", (rw * s / cw, rh * s / ch))
        # the objects' look-ups only where they can be (they cost as much as the rest of the pass),
        # each pixel drawn once: the region around their outline without them, the outline with them
        outline = ins.screen_rect(drawn, frame.view, (w, h), reach=False)
        hole = None
        if outline is not None:
            ox0, oy0 = max(outline[0], rx), max(outline[1], ry)
            ox1, oy1 = min(outline[0] + outline[2], rx + rw), min(outline[1] + outline[3], ry + rh)
            hole = (x + ox0, fb_h - y - oy1, ox1 - ox0, oy1 - oy0) if ox1 > ox0 and oy1 > oy0 else None
        set_uniform(up, "n_objects", 0)
        draw_around(ctx, region, hole, lambda: ins.draw_fullscreen(up))
        if hole is not None:
            ctx.viewport = hole
            set_uniform(up, "n_objects", len(drawn))
            ins.draw_fullscreen(up)
