"""Inserted objects in ``phyir-view``: the object list, material editor, click-to-drop, dragging on
surfaces, the ImGuizmo gizmo and export (docs/insertion.md).

:class:`ObjectsPanel` owns the objects and an :class:`viewer.insertion.InsertionRenderer` whose
:class:`viewer.insertion_pass.InsertionPass` (``hook``) the app puts first among its renderer's overlay
passes.  Its methods
are what the UI calls (and what tests and scripts call): ``add``, ``drop_at``, ``duplicate``,
``delete``, ``set_material``, ``begin_drag``/``drag_to``/``end_drag``, ``export``.  While dragging the
pass draws at the cheaper quality; after the mouse is released (and after any other change) the
full-quality picture is built a slice per frame while the draft stays on screen (``refine``,
``viewer.refinement``), and screenshots finish it first.
"""

from __future__ import annotations

import copy
import functools
import math
import os

import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.insert import placement
from phyir.insert.objects import PRESETS, PRIMITIVES, ObjectMaterial, SceneObject, object_mesh
from phyir.insert.views import EquirectView, PerspectiveView, write_passes
from viewer.insertion import FUSIONS, InsertionRenderer
from viewer.insertion_pass import InsertionPass

DEFAULT_SIZE = 0.25  # metres: primitives are unit-size, added ones start at this scale


class ObjectsPanel:
    def __init__(self, app):
        self.app = app
        self.insertion = InsertionRenderer(app.ctx)
        self.hook = InsertionPass(self.insertion)
        self.hook.refinement.finish = app.surface.finish  # drops the GIL while it waits (EGL)
        self.selected: int | None = None
        self.drop_mode = False  # clicks in the view drop the selected object (or a new sphere)
        self.new_kind = "sphere"
        self.mesh_path = ""
        self.gizmo_op = "translate"
        self.snap = True
        self._scene_id: int | None = None
        self._drag: placement.Drag | None = None
        self._normals: torch.Tensor | None = None

    # -- state --------------------------------------------------------------------------------
    @property
    def objects(self) -> list[SceneObject]:
        return self.hook.objects

    def active(self) -> bool:
        """Objects are drawn (the view's picture depends on them: no cached frames)."""
        return self.hook.enabled and any(o.visible for o in self.objects) and self.insertion.scene is not None

    def refining(self) -> bool:
        """Frames should go on: while dragging, an object's lighting is being computed in the
        background; else the full-quality picture is being built (``InsertionPass.refine``)."""
        return self.insertion.lighting_pending() if self.dragging else self.hook.refining()

    def refine(self, frame, size: tuple[int, int], final: bool = False) -> None:
        """A slice of the view's full-quality picture (all of it with ``final``): once a frame,
        before the view is drawn (``frame`` None: the view shows nothing)."""
        if frame is None:
            self.hook.refinement.pause(self.objects)
        else:
            self.hook.refine(self.app.renderer, frame, size, final)

    def picture_key(self, frame, size: tuple[int, int]) -> tuple | None:
        """What the view's picture takes from the objects (the view cache's key), None: uncachable."""
        return self.hook.picture_key(frame, size)

    def scene(self):
        app = self.app
        return app.gt if app.show_gt and app.gt is not None else app.scene

    def sync(self) -> bool:
        """Follow the app's scene: upload it once it has depth and probes.  True if usable."""
        sc = self.scene()
        if sc is None or sc.depth is None or sc.probes is None:
            return False
        if id(sc) != self._scene_id:
            self.insertion.set_scene(sc)
            self._scene_id = id(sc)
            self._normals = placement.scene_normals(sc)
        return True

    def _changed(self) -> None:
        self.app.request_redraw()
        self.app.check_objects()

    # -- editing (what the panel's buttons call) ------------------------------------------------
    def add(self, spec: str = "sphere", material: ObjectMaterial | None = None, scale: float | None = None,
            at: tuple[float, float] | None = None) -> SceneObject:
        """Add a primitive or mesh file; at panorama (u, v) if given, else in front of the camera."""
        if not self.sync():
            raise PhyIRError("objects need the scene's depth and probes (open a scene or wait for the model)")
        mesh = object_mesh(spec)
        size = scale if scale is not None else (DEFAULT_SIZE if spec in PRIMITIVES else 1.0)
        obj = SceneObject(mesh, copy.deepcopy(material or PRESETS["diffuse"]), scale=size)
        self.objects.append(obj)
        self.selected = len(self.objects) - 1
        sc = self.scene()
        H, W = sc.size
        self.drop_at(*(at or (W / 2, H * 0.75)))
        return obj

    def drop_at(self, u: float, v: float, index: int | None = None) -> None:
        """Stand the selected object on the surface seen at panorama (u, v)."""
        i = self.selected if index is None else index
        if i is None or not self.sync():
            return
        obj = self.objects[i]
        pl = placement.drop(self.scene(), u, v, obj.base_offset(), placement.yaw_of(obj.rotation),
                            normal=self._normals)
        obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
        self._changed()

    def duplicate(self, index: int) -> SceneObject:
        obj = self.objects[index].duplicate()
        self.objects.append(obj)
        self.selected = len(self.objects) - 1
        self._changed()
        return obj

    def delete(self, index: int) -> None:
        del self.objects[index]
        if self.selected is not None:
            self.selected = None if not self.objects else min(self.selected, len(self.objects) - 1)
        self._changed()

    def set_visible(self, index: int, visible: bool) -> None:
        self.objects[index].visible = bool(visible)
        self._changed()

    def set_material(self, index: int, material: ObjectMaterial | str) -> None:
        m = copy.deepcopy(PRESETS[material]) if isinstance(material, str) else material
        self.objects[index].material = m
        self._changed()

    def set_scale(self, index: int, scale: float) -> None:
        """Resize keeping the object on its surface."""
        obj = self.objects[index]
        up = obj.rotation @ np.array([0.0, 1.0, 0.0])
        base = obj.position - obj.base_offset() * up
        obj.scale = float(max(scale, 1e-3))
        obj.position = base + obj.base_offset() * up
        self._changed()

    # -- mouse ----------------------------------------------------------------------------------
    def pick(self, x: float, y: float) -> int | None:
        """The nearest visible object whose bounding sphere the view ray under (x, y) meets."""
        uv = self.app.screen_to_uv(x, y)
        sc = self.scene()
        if uv is None or sc is None:
            return None
        from phyir import pano

        H, W = sc.size
        d = pano.uv_to_dir(torch.tensor(uv[0], dtype=torch.float64), torch.tensor(uv[1], dtype=torch.float64),
                           H, W).numpy()
        best, best_t = None, math.inf
        for i, obj in enumerate(self.objects):
            if not obj.visible:
                continue
            c, r = obj.bounding_sphere()
            b = float(d @ c)
            disc = b * b - float(c @ c) + r * r
            if disc >= 0 and 0 < b - math.sqrt(disc) < best_t:
                best, best_t = i, b - math.sqrt(disc)
        return best

    def begin_drag(self, x: float, y: float) -> bool:
        """Grab the object under (x, y); True if there was one (the view then doesn't pan)."""
        i = self.pick(x, y)
        if i is None or not self.sync():
            return False
        self.selected = i
        obj = self.objects[i]
        contact = obj.support[0] if obj.support is not None else obj.bounding_sphere()[0]
        self._drag = placement.Drag(self.scene(), contact, self.app.screen_to_uv(x, y), obj.base_offset(),
                                    placement.yaw_of(obj.rotation))
        self.hook.dragging = True
        return True

    def drag_to(self, x: float, y: float) -> None:
        uv = self.app.screen_to_uv(x, y)
        if self._drag is None or uv is None or self.selected is None:
            return
        try:
            pl = self._drag.move(uv)
        except PhyIRError:  # no surface there (sky through a window): stay
            return
        obj = self.objects[self.selected]
        obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
        self._changed()

    def end_drag(self) -> None:
        self._drag = None
        self.hook.dragging = False
        self._changed()  # the full-quality frame

    @property
    def dragging(self) -> bool:
        return self._drag is not None

    # -- export ---------------------------------------------------------------------------------
    def export(self, path: str) -> list[str]:
        """The equirect composite at the panorama's resolution: EXR passes + PNG
        (:func:`phyir.insert.views.write_passes`)."""
        if not self.sync():
            raise PhyIRError("nothing to export: the scene has no depth and probes yet")
        H, W = self.scene().size
        out = self.insertion.render_view(self.objects, EquirectView(center=(W / 2, H / 2), zoom=1.0), (W, H),
                                         fusion=self.hook.fusion)
        files = write_passes(out, path, None, {"objects": str(len(self.objects)), "fusion": self.hook.fusion})
        self._changed()
        return files

    def release(self) -> None:
        """Free the insertion renderer's GL resources (the app has taken ``hook`` out of its passes)."""
        self.hook.release()
        self.insertion.release()

    # -- imgui ----------------------------------------------------------------------------------
    def view_mouse(self, hovered: bool, activated: bool, active: bool, deactivated: bool, moved: bool,
                   mx: float, my: float) -> bool:
        """Route the view's mouse to the objects first; True when they took it (no pan, no pin)."""
        if activated and hovered:
            if self.drop_mode and self.selected is not None:
                uv = self.app.screen_to_uv(mx, my)
                if uv is not None:
                    self.drop_at(*uv)
                return True
            if self.begin_drag(mx, my):
                return True
        if self._drag is not None:
            if active and moved:
                self.drag_to(mx, my)
            if deactivated:
                self.end_drag()
            return True
        return self.drop_mode and (active or deactivated)

    def build_ui(self) -> None:
        from imgui_bundle import imgui

        usable = self.sync()
        if not usable:
            imgui.text_disabled("needs depth and probes (a scene file or the model)")
            return
        imgui.text("Add")
        for kind in PRIMITIVES:
            imgui.same_line()
            if imgui.small_button(kind):
                self._try(lambda k=kind: self.add(k))
        _, self.mesh_path = imgui.input_text("##mesh", self.mesh_path)
        imgui.same_line()
        if imgui.small_button("Add mesh") and self.mesh_path:
            self._try(lambda: self.add(os.path.expanduser(self.mesh_path)))
        _, self.drop_mode = imgui.checkbox("Click to drop", self.drop_mode)
        imgui.same_line()
        _, self.hook.enabled = imgui.checkbox("Show", self.hook.enabled)
        fi = FUSIONS.index(self.hook.fusion)
        changed, fi = imgui.combo("Fusion", fi, list(FUSIONS))
        if changed:
            self.hook.fusion = FUSIONS[fi]
            self._changed()
        for i, obj in enumerate(list(self.objects)):
            imgui.push_id(i)
            changed, vis = imgui.checkbox("##vis", obj.visible)
            if changed:
                self.set_visible(i, vis)
            imgui.same_line()
            if imgui.selectable(f"{obj.name}##sel", self.selected == i, size=imgui.ImVec2(120, 0))[0]:
                self.selected = i
            imgui.same_line()
            if imgui.small_button("dup"):
                self.duplicate(i)
            imgui.same_line()
            if imgui.small_button("del"):
                self.delete(i)
                imgui.pop_id()
                break
            imgui.pop_id()
        if self.selected is not None and self.selected < len(self.objects):
            self._material_editor(self.selected)
        if imgui.button("Export composite (EXR + PNG)"):
            name = os.path.splitext(self.app.name or "scene")[0]
            self._try(lambda: self.app.note("info", "wrote " + ", ".join(self.export(f"{name}_insert.exr"))))

    def _material_editor(self, i: int) -> None:
        from imgui_bundle import imgui

        obj = self.objects[i]
        m = obj.material
        presets = list(PRESETS)
        current = next((k for k, p in PRESETS.items() if p == m), "custom")
        if imgui.begin_combo("Material", current):
            for name in presets:
                if imgui.selectable(name, name == current)[0]:
                    self.set_material(i, name)
            imgui.end_combo()
        ch, col = imgui.color_edit3("Base colour", list(m.base_color))
        ch2, rough = imgui.slider_float("Roughness", m.roughness, 0.0, 1.0)
        ch3, metal = imgui.slider_float("Metalness", m.metallic, 0.0, 1.0)
        if ch or ch2 or ch3:
            self.set_material(i, ObjectMaterial(tuple(float(c) for c in col), float(rough), float(metal)))
        ch, size = imgui.slider_float("Scale", obj.scale, 0.01, 5.0, "%.3f", imgui.SliderFlags_.logarithmic)
        if ch:
            self.set_scale(i, size)
        ops = ("translate", "rotate", "scale")
        ch, k = imgui.combo("Gizmo", ops.index(self.gizmo_op), list(ops))
        if ch:
            self.gizmo_op = ops[k]
        imgui.same_line()
        _, self.snap = imgui.checkbox("Snap", self.snap)

    def gizmo(self, rect_logical: tuple[float, float, float, float], view_size: tuple[int, int]) -> bool:
        """ImGuizmo on the selected object in the perspective view (the equirect view has no linear
        projection); call inside the view window, once per frame.  True while the mouse is on it."""
        from imgui_bundle import imgui, imguizmo

        g = imguizmo.im_guizmo
        g.begin_frame()
        view = self.app.view
        sel = self.selected
        if sel is None or sel >= len(self.objects) or not isinstance(view, PerspectiveView):
            return False
        g.set_drawlist(imgui.get_window_draw_list())
        g.set_rect(*rect_logical)
        obj = self.objects[self.selected]
        colmajor = functools.partial(_column_major, g)
        model = colmajor(obj.model_matrix())
        op = {"translate": g.OPERATION.translate, "rotate": g.OPERATION.rotate, "scale": g.OPERATION.scale}
        snap = {"translate": 0.05, "rotate": 15.0, "scale": 0.1}[self.gizmo_op]
        changed = g.manipulate(colmajor(view.view_matrix()), colmajor(view.projection_matrix(view_size)),
                               op[self.gizmo_op], g.MODE.local, model,
                               None, g.Matrix3([snap] * 3) if self.snap else None)
        if changed:
            m = np.asarray(model.values, np.float64).reshape(4, 4).T
            s = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
            obj.scale = max(s, 1e-3)
            u, _, vt = np.linalg.svd(m[:3, :3] / obj.scale)
            obj.rotation = u @ vt
            obj.position = m[:3, 3].copy()
            obj.support = None if self.gizmo_op != "scale" else obj.support
            self._changed()
        return bool(g.is_using() or g.is_over())

    def _try(self, fn) -> None:
        try:
            fn()
        except PhyIRError as e:
            self.app.note("error", str(e))


def _column_major(guizmo, m: np.ndarray):
    """A 4x4 matrix as ImGuizmo's column-major ``Matrix16``."""
    return guizmo.Matrix16(list(np.asarray(m, np.float64).T.reshape(-1)))
