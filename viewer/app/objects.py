"""The App's inserted objects: the objects panel (``viewer.ui.objects_panel``) and its insertion
pass, which the App puts first among the renderer's overlay passes."""

from __future__ import annotations

from phyir.errors import PhyIRError
from viewer.app import cli_objects


class InsertedObjects:
    """Part of :class:`viewer.app.App`: wiring the inserted objects into the view."""

    def attach_objects(self) -> None:
        """Make the objects panel and put its pass before the other overlays (the probe markers)."""
        from viewer.ui.objects_panel import ObjectsPanel

        with self.surface.current():
            self.objects = ObjectsPanel(self)
        self._queued_objects = []
        self.objects_problem: str | None = None  # e.g. the camera inside an object (status bar)
        self.renderer.overlay_passes.insert(0, self.objects.hook)

    def detach_objects(self) -> None:
        """Take the objects' pass out of the renderer and free their GL resources (GL current)."""
        if self.objects.hook in self.renderer.overlay_passes:
            self.renderer.overlay_passes.remove(self.objects.hook)
        self.objects.release()

    def objects_active(self) -> bool:
        """Objects are drawn: the view's picture depends on them (no cached frames)."""
        return self.objects.active()

    def queue_objects(self, specs: list) -> None:
        """Objects to insert once the scene has depth and probes (``phyir-view --object ...`` with a
        window: the model may still be running); a one-line error banner if one can't be added."""
        self._queued_objects = list(specs)
        self.add_queued_objects()

    def add_queued_objects(self) -> None:
        if not self._queued_objects or not self.objects.sync():
            return
        specs, self._queued_objects = self._queued_objects, []
        try:
            cli_objects.add_objects(self, specs)
        except PhyIRError as e:
            self.note("error", str(e))

    def check_objects(self) -> None:
        """After an edit: warn once when the camera comes to be inside an object, which can't be
        drawn (``phyir.insert.placement.camera_inside``); the status keeps ``objects_problem``."""
        from phyir.insert.placement import camera_inside

        problem = camera_inside(self.objects.objects)
        if problem and not self.objects_problem:
            self.note("warning", problem)
        self.objects_problem = problem
