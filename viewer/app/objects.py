"""Inserted objects (:class:`InsertedObjects`, docs/insertion.md): the objects, adding, dropping and
dragging them on surfaces, and their :class:`viewer.insertion.InsertionRenderer`, whose
:class:`viewer.insertion_pass.InsertionPass` (``hook``) goes first among the view renderer's overlay
passes.  While dragging the pass draws at the cheaper quality; after the mouse is released (and after
any other change) the full-quality picture is built a slice per frame while the draft stays on screen
(``refine``, ``viewer.refinement``), and screenshots finish it first.  The side panel's section is
``viewer.ui.objects_panel``."""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Callable

import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.insert import placement
from phyir.insert.objects import PRESETS, PRIMITIVES, ObjectMaterial, SceneObject, object_mesh
from phyir.insert.views import EquirectView, write_passes
from viewer.app import cli_objects
from viewer.app.camera import Camera
from viewer.app.common import Messages
from viewer.app.images import ImageList
from viewer.insertion import InsertionRenderer
from viewer.insertion_pass import InsertionPass

DEFAULT_SIZE = 0.25  # metres: primitives are unit-size, added ones start at this scale


class InsertedObjects:
    """Owns the objects (``objects``, the ``selected`` one), the drag and the insertion renderer;
    places them in the shown image's scene (``images``) through the view (``camera``)."""

    def __init__(self, renderer, ctx, finish: Callable[[], None], images: ImageList, camera: Camera,
                 messages: Messages, redraw: Callable[[], None]):
        self.renderer = renderer
        self.images = images
        self.camera = camera
        self.messages = messages
        self.redraw = redraw
        self.insertion = InsertionRenderer(ctx)
        self.hook = InsertionPass(self.insertion)
        self.hook.refinement.finish = finish  # drops the GIL while it waits (EGL)
        renderer.overlay_passes.insert(0, self.hook)  # before the other overlays (the probe markers)
        self.selected: int | None = None
        self.problem: str | None = None  # e.g. the camera inside an object (status bar)
        self._queued: list = []
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
            self.hook.refine(self.renderer, frame, size, final)

    def picture_key(self, frame, size: tuple[int, int]) -> tuple | None:
        """What the view's picture takes from the objects (the view cache's key), None: uncachable."""
        return self.hook.picture_key(frame, size)

    @property
    def scene_name(self) -> str:
        """The shown image's name (for messages)."""
        return self.images.doc.name

    def note(self, level: str, text: str) -> None:
        self.messages.note(level, text)

    def scene(self):
        doc = self.images.doc
        return doc.gt if doc.show_gt and doc.gt is not None else doc.scene

    def sync(self) -> bool:
        """Follow the shown scene: upload it once it has depth and probes.  True if usable."""
        sc = self.scene()
        if sc is None or sc.depth is None or sc.probes is None:
            return False
        if id(sc) != self._scene_id:
            self.insertion.set_scene(sc)
            self._scene_id = id(sc)
            self._normals = placement.scene_normals(sc)
        return True

    def changed(self) -> None:
        """An object changed: redraw, and warn if the camera came to be inside one."""
        self.redraw()
        self.check()

    def check(self) -> None:
        """After an edit: warn once when the camera comes to be inside an object, which can't be
        drawn (``phyir.insert.placement.camera_inside``); the status keeps ``problem``."""
        problem = placement.camera_inside(self.objects)
        if problem and not self.problem:
            self.messages.note("warning", problem)
        self.problem = problem

    # -- editing ----------------------------------------------------------------------------------
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
        H, W = self.scene().size
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
        self.changed()

    def duplicate(self, index: int) -> SceneObject:
        obj = self.objects[index].duplicate()
        self.objects.append(obj)
        self.selected = len(self.objects) - 1
        self.changed()
        return obj

    def delete(self, index: int) -> None:
        del self.objects[index]
        if self.selected is not None:
            self.selected = None if not self.objects else min(self.selected, len(self.objects) - 1)
        self.changed()

    def set_visible(self, index: int, visible: bool) -> None:
        self.objects[index].visible = bool(visible)
        self.changed()

    def set_material(self, index: int, material: ObjectMaterial | str) -> None:
        m = copy.deepcopy(PRESETS[material]) if isinstance(material, str) else material
        self.objects[index].material = m
        self.changed()

    def set_scale(self, index: int, scale: float) -> None:
        """Resize keeping the object on its surface."""
        obj = self.objects[index]
        up = obj.rotation @ np.array([0.0, 1.0, 0.0])
        base = obj.position - obj.base_offset() * up
        obj.scale = float(max(scale, 1e-3))
        obj.position = base + obj.base_offset() * up
        self.changed()

    def queue(self, specs: list) -> None:
        """Objects to insert once the scene has depth and probes (``phyir-view --object ...`` with a
        window: the model may still be running); a one-line error banner if one can't be added."""
        self._queued = list(specs)
        self.add_queued()

    def add_queued(self) -> None:
        if not self._queued or not self.sync():
            return
        specs, self._queued = self._queued, []
        try:
            cli_objects.add_objects(self, specs)
        except PhyIRError as e:
            self.messages.note("error", str(e))

    # -- mouse ----------------------------------------------------------------------------------
    def pick(self, x: float, y: float) -> int | None:
        """The nearest visible object whose bounding sphere the view ray under (x, y) meets."""
        uv = self.camera.screen_to_uv(x, y)
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
        self._drag = placement.Drag(self.scene(), contact, self.camera.screen_to_uv(x, y), obj.base_offset(),
                                    placement.yaw_of(obj.rotation))
        self.hook.dragging = True
        return True

    def drag_to(self, x: float, y: float) -> None:
        uv = self.camera.screen_to_uv(x, y)
        if self._drag is None or uv is None or self.selected is None:
            return
        try:
            pl = self._drag.move(uv)
        except PhyIRError:  # no surface there (sky through a window): stay
            return
        obj = self.objects[self.selected]
        obj.position, obj.rotation, obj.support = pl.position, pl.rotation, (pl.contact, pl.normal)
        self.changed()

    def end_drag(self) -> None:
        self._drag = None
        self.hook.dragging = False
        self.changed()  # the full-quality frame

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
        self.changed()
        return files

    def export_gltf(self, path: str | os.PathLike | None = None):
        """The room, its lights, the objects and the perspective view's camera as glTF
        (``phyir.export``: PATH.glb + PATH_env.exr, default next to the file); a note says where."""
        from phyir.export.bundle import export_gltf

        sc = self.scene()
        if sc is None or sc.depth is None:
            raise PhyIRError("nothing to export: the scene has no depth yet")
        if path is None:
            doc = self.images.doc
            path = f"{os.path.splitext(doc.path or doc.name)[0]}.glb"
        cam = self.camera.views["perspective"]
        w, h = self.camera.view_size()
        report = export_gltf(sc, os.fspath(path), objects=[o for o in self.objects if o.visible],
                             fov_deg=float(cam.fov), aspect=w / max(h, 1), camera_rotation=cam.rotation())
        self.messages.note("info", f"exported {report.glb} and {report.exr} ({report.lights} lights, "
                                   f"{report.objects} objects, {report.seconds:.1f} s)")
        return report

    def release(self) -> None:
        """Take the pass out of the renderer and free the GL resources (GL current)."""
        if self.hook in self.renderer.overlay_passes:
            self.renderer.overlay_passes.remove(self.hook)
        self.hook.release()
        self.insertion.release()
