"""The side panel's Objects section (:class:`ObjectsPanel`, docs/insertion.md): the object list,
material editor, click-to-drop, the ImGuizmo gizmo and export.  What its buttons change lives in
:class:`viewer.app.objects.InsertedObjects` (``inserted``), which scripts and tests call too."""

from __future__ import annotations

import functools
import os

import numpy as np

from phyir.errors import PhyIRError
from phyir.insert.objects import PRESETS, PRIMITIVES, ObjectMaterial
from phyir.insert.views import PerspectiveView
from viewer.insertion import FUSIONS
from viewer.ui.widgets import imgui


class ObjectsPanel:
    """A side-panel section (``title``, ``default_open``, ``draw``) over the inserted objects; owns
    the interface's own state: click-to-drop, the gizmo's operation and snapping, the mesh path."""

    default_open = False

    def __init__(self, inserted, camera, messages):
        self.inserted = inserted
        self.camera = camera
        self.messages = messages
        self.drop_mode = False  # clicks in the view drop the selected object (or a new sphere)
        self.mesh_path = ""
        self.gizmo_op = "translate"
        self.snap = True

    @property
    def title(self) -> str:
        return f"Objects ({len(self.inserted.objects)})###objects"

    def view_mouse(self, hovered: bool, activated: bool, active: bool, deactivated: bool, moved: bool,
                   mx: float, my: float) -> bool:
        """Route the view's mouse to the objects first; True when they took it (no pan, no pin)."""
        ins = self.inserted
        if activated and hovered:
            if self.drop_mode and ins.selected is not None:
                uv = self.camera.screen_to_uv(mx, my)
                if uv is not None:
                    ins.drop_at(*uv)
                return True
            if ins.begin_drag(mx, my):
                return True
        if ins.dragging:
            if active and moved:
                ins.drag_to(mx, my)
            if deactivated:
                ins.end_drag()
            return True
        return self.drop_mode and (active or deactivated)

    def draw(self) -> None:
        ins = self.inserted
        if not ins.sync():
            imgui.text_disabled("needs depth and probes (a scene file or the model)")
            return
        imgui.text("Add")
        for kind in PRIMITIVES:
            imgui.same_line()
            if imgui.small_button(kind):
                self._try(lambda k=kind: ins.add(k))
        _, self.mesh_path = imgui.input_text("##mesh", self.mesh_path)
        imgui.same_line()
        if imgui.small_button("Add mesh") and self.mesh_path:
            self._try(lambda: ins.add(os.path.expanduser(self.mesh_path)))
        _, self.drop_mode = imgui.checkbox("Click to drop", self.drop_mode)
        imgui.same_line()
        _, ins.hook.enabled = imgui.checkbox("Show", ins.hook.enabled)
        fi = FUSIONS.index(ins.hook.fusion)
        changed, fi = imgui.combo("Fusion", fi, list(FUSIONS))
        if changed:
            ins.hook.fusion = FUSIONS[fi]
            ins.changed()
        self._object_list()
        if ins.selected is not None and ins.selected < len(ins.objects):
            self._material_editor(ins.selected)
        if imgui.button("Export composite (EXR + PNG)"):
            self._try(self._export_composite)

    def _export_composite(self) -> None:
        name = os.path.splitext(self.inserted.scene_name or "scene")[0]
        files = self.inserted.export(f"{name}_insert.exr")
        self.messages.note("info", "wrote " + ", ".join(files))

    def _object_list(self) -> None:
        ins = self.inserted
        for i, obj in enumerate(list(ins.objects)):
            imgui.push_id(i)
            changed, vis = imgui.checkbox("##vis", obj.visible)
            if changed:
                ins.set_visible(i, vis)
            imgui.same_line()
            if imgui.selectable(f"{obj.name}##sel", ins.selected == i, size=imgui.ImVec2(120, 0))[0]:
                ins.selected = i
            imgui.same_line()
            if imgui.small_button("dup"):
                ins.duplicate(i)
            imgui.same_line()
            if imgui.small_button("del"):
                ins.delete(i)
                imgui.pop_id()
                break
            imgui.pop_id()

    def _material_editor(self, i: int) -> None:
        ins = self.inserted
        obj = ins.objects[i]
        m = obj.material
        current = next((k for k, p in PRESETS.items() if p == m), "custom")
        if imgui.begin_combo("Material", current):
            for name in PRESETS:
                if imgui.selectable(name, name == current)[0]:
                    ins.set_material(i, name)
            imgui.end_combo()
        ch, col = imgui.color_edit3("Base colour", list(m.base_color))
        ch2, rough = imgui.slider_float("Roughness", m.roughness, 0.0, 1.0)
        ch3, metal = imgui.slider_float("Metalness", m.metallic, 0.0, 1.0)
        if ch or ch2 or ch3:
            ins.set_material(i, ObjectMaterial(tuple(float(c) for c in col), float(rough), float(metal)))
        ch, size = imgui.slider_float("Scale", obj.scale, 0.01, 5.0, "%.3f", imgui.SliderFlags_.logarithmic)
        if ch:
            ins.set_scale(i, size)
        ops = ("translate", "rotate", "scale")
        ch, k = imgui.combo("Gizmo", ops.index(self.gizmo_op), list(ops))
        if ch:
            self.gizmo_op = ops[k]
        imgui.same_line()
        _, self.snap = imgui.checkbox("Snap", self.snap)

    def gizmo(self, rect_logical: tuple[float, float, float, float], view_size: tuple[int, int]) -> bool:
        """ImGuizmo on the selected object in the perspective view (the equirect view has no linear
        projection); call inside the view window, once per frame.  True while the mouse is on it."""
        from imgui_bundle import imguizmo

        g = imguizmo.im_guizmo
        g.begin_frame()
        ins, view = self.inserted, self.camera.view
        sel = ins.selected
        if sel is None or sel >= len(ins.objects) or not isinstance(view, PerspectiveView):
            return False
        g.set_drawlist(imgui.get_window_draw_list())
        g.set_rect(*rect_logical)
        obj = ins.objects[sel]
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
            ins.changed()
        return bool(g.is_using() or g.is_over())

    def _try(self, fn) -> None:
        try:
            fn()
        except PhyIRError as e:
            self.messages.note("error", str(e))


def _column_major(guizmo, m: np.ndarray):
    """A 4x4 matrix as ImGuizmo's column-major ``Matrix16``."""
    return guizmo.Matrix16(list(np.asarray(m, np.float64).T.reshape(-1)))
