"""The App's inserted objects: the objects panel (``viewer.ui.objects_panel``) and its insertion
pass, which the App puts first among the renderer's overlay passes."""

from __future__ import annotations


class InsertedObjects:
    """Part of :class:`viewer.app.App`: wiring the inserted objects into the view."""

    def _attach_objects(self) -> None:
        """Make the objects panel and put its pass before the other overlays (the probe markers)."""
        from viewer.ui.objects_panel import ObjectsPanel

        with self.surface.current():
            self.objects = ObjectsPanel(self)
        self.renderer.overlay_passes.insert(0, self.objects.hook)

    def _detach_objects(self) -> None:
        """Take the objects' pass out of the renderer and free their GL resources (GL current)."""
        if self.objects.hook in self.renderer.overlay_passes:
            self.renderer.overlay_passes.remove(self.objects.hook)
        self.objects.release()

    def objects_active(self) -> bool:
        """Objects are drawn: the view's picture depends on them (no cached frames)."""
        return self.objects.active()
