"""The worker's events applied to the open images (:class:`WorkerEvents`, on the GL thread, from
``App.poll``): each event type (``viewer.worker``'s dataclasses) has its handler, found by the
event's type, and changes the document of the image the job is for."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from phyir.scene import PanoScene
from viewer.app.common import Messages
from viewer.app.display import DisplaySettings
from viewer.app.document import Document
from viewer.app.images import ImageList
from viewer.app.loader import Loader
from viewer.app.objects import InsertedObjects
from viewer.app.pins import Pins
from viewer.layers import auto_ranges, scene_arrays
from viewer.recent import RecentFiles
from viewer.worker import Done, Failed, GroundTruth, LayersReady, Loaded, Note, Progress, Rendered


class WorkerEvents:
    """What each worker event changes: the job's document (``images``), the job's state
    (``loader``), automatic ranges (``display``), pins, queued objects, messages and the recent files."""

    def __init__(self, loader: Loader, images: ImageList, display: DisplaySettings, pins: Pins,
                 objects: InsertedObjects, messages: Messages, recent: RecentFiles | None,
                 retitle: Callable[[], None]):
        self.loader, self.images, self.display, self.pins = loader, images, display, pins
        self.objects, self.messages, self.recent, self.retitle = objects, messages, recent, retitle

    def poll(self) -> bool:
        """Apply the worker's events; True if any arrived."""
        events = self.loader.worker.poll()
        if events:
            with self.images.job_target(events, self.pins.pin_probe) as doc:
                for event in events:
                    self._handlers[type(event)](self, doc, event)
        return bool(events)

    def set_ground_truth(self, doc: Document, gt: PanoScene,
                         arrays: dict[str, np.ndarray] | None = None) -> None:
        """Ground truth: a scene given to ``open`` (arrays made here) or the file's layers in compare
        mode (arrays made, and their ranges applied, when the file loaded)."""
        if arrays is None:
            arrays = scene_arrays(gt)
            doc.gt = None  # so that its ranges apply
            self.display.apply_auto_ranges(auto_ranges(arrays), doc)
        doc.gt, doc.gt_arrays = gt, dict(arrays)
        doc.queue_upload("gt", doc.gt_arrays)

    def _on_loaded(self, doc: Document, loaded: Loaded) -> None:
        # the previous scene goes, the ground truth given to open comes
        opening = self.loader.take_opening()
        doc.clear()
        doc.watch_stamp = None
        if opening is not None and opening.gt is not None:
            self.set_ground_truth(doc, opening.gt)
        doc.scene = loaded.scene
        doc.path, doc.name = loaded.path, loaded.name
        doc.watch_stamp = doc.file_stamp()
        doc.arrays = dict(loaded.arrays)
        doc.queue_upload("pred", loaded.arrays)
        self.display.apply_auto_ranges(loaded.ranges, doc)
        for text in loaded.notes:
            self.messages.note("warning", text)
        H, W = doc.scene.size
        self.messages.note("info", f"opened {loaded.name} ({W}x{H}; layers: {', '.join(loaded.arrays)})")
        self._geometry_confidence(doc)
        doc.timings["load"] = time.perf_counter() - self.loader.job_started
        if self.recent is not None and loaded.path is not None:
            self.recent.add(loaded.path)
        self.pins.refresh(doc)
        self.retitle()

    def _on_progress(self, doc: Document, event: Progress) -> None:
        old = self.loader.progress or (None, "")
        fraction = event.fraction if event.fraction is not None else old[0]
        self.loader.progress = (fraction, event.text or old[1])

    def _on_layers(self, doc: Document, event: LayersReady) -> None:
        arrays, seconds = event.arrays, event.seconds
        doc.scene = event.scene
        doc.arrays.update(arrays)
        doc.queue_upload("pred", arrays)
        self.display.apply_auto_ranges(event.ranges, doc)
        doc.timings["model"] = seconds
        extra = " (G: prediction / ground truth)" if doc.gt is not None else ""
        self.messages.note("info", f"model: {', '.join(arrays)} in {seconds:.1f} s{extra}")
        self._geometry_confidence(doc)
        self.pins.refresh(doc)

    def _geometry_confidence(self, doc: Document) -> None:
        """How far to trust the scene's geometry (phyir.evaluation.real.scene_confidence), for the status
        bar; a warning when it is flagged."""
        from phyir.commands.info import format_confidence
        from phyir.evaluation.real import flag_reason, scene_confidence

        sc = doc.scene
        doc.confidence = None
        if sc is None or sc.depth is None or sc.normal is None:
            return
        c = scene_confidence(sc)
        doc.confidence = float(c["confidence"])
        if c["flagged"]:
            self.messages.note("warning", f"geometry confidence {format_confidence(doc.confidence)} "
                                          f"({flag_reason(c)}): the floor below the camera is "
                                          f"{100 * float(c['nadir_up']):.0f}% floor-like, normals and "
                                          f"depth disagree by {float(c['consistency_deg']):.0f}°, the room "
                                          f"reaches {float(c['far_m']):.0f} m; insertions may be off")

    def _on_gt(self, doc: Document, event: GroundTruth) -> None:
        gt = event.scene
        # the file's layers are the ground truth now; the prediction starts from the image only
        for name in list(doc.arrays):
            if name != "image":
                del doc.arrays[name]
                doc.drop_texture(("pred", name))
        doc.scene = PanoScene(image=gt.image, meta=dict(gt.meta))
        self.set_ground_truth(doc, gt, event.arrays)
        doc.show_gt = True  # the file's layers, at once; G switches to the prediction when it is in
        self.messages.note("info", "the file's layers are ground truth: predicting all layers to compare "
                                   "(G switches)")
        self.pins.refresh(doc)

    def _on_rendered(self, doc: Document, event: Rendered) -> None:
        if event.gt:
            doc.timings["render_gt"] = event.seconds
            doc.gt_arrays.update(event.arrays)
            doc.queue_upload("gt", event.arrays)
        else:
            doc.timings["render"] = event.seconds
            doc.arrays.update(event.arrays)
            doc.queue_upload("pred", event.arrays)

    def _on_note(self, doc: Document, event: Note) -> None:
        self.messages.note("info", event.text)

    def _on_failed(self, doc: Document, event: Failed) -> None:
        loading = event.stage == "loading"
        self.messages.note("error", event.text if loading else f"{event.stage} failed: {event.text}")
        if loading:  # the file being opened could not be read: keep showing the current scene
            opening = self.loader.take_opening()
            if opening is not None and doc.scene is not None:
                self.messages.note("info", f"still showing {doc.name}")
        doc.timings["job"] = self.loader.finished()

    def _on_done(self, doc: Document, _event: Done) -> None:
        doc.timings["job"] = self.loader.finished()
        self.pins.refresh(doc)
        self.objects.add_queued()

    # each event type's handler (functions of this class body, called with the handler and the document)
    _handlers = {Loaded: _on_loaded, Progress: _on_progress, LayersReady: _on_layers, GroundTruth: _on_gt,
                 Rendered: _on_rendered, Note: _on_note, Failed: _on_failed, Done: _on_done}

