"""The worker's events applied to the App's state (on the GL thread, from ``App.poll``): each
event type (``viewer.worker``'s dataclasses) has its handler, found by the event's type."""

from __future__ import annotations

import time

from phyir.scene import PanoScene
from viewer.worker import Done, Failed, GroundTruth, LayersReady, Loaded, Note, Progress, Rendered


class WorkerEvents:
    """Part of :class:`viewer.app.App`: what each worker event changes."""

    def poll(self) -> bool:
        """Apply the worker's events; True if anything changed."""
        self.check_file_changed()
        events = self.worker.poll()
        if events:
            with self.job_shown(events):  # viewer.app.images: the image the job is for
                for event in events:
                    self._handlers[type(event)](self, event)
        return bool(events)

    def _on_loaded(self, loaded: Loaded) -> None:
        self.begin_opened()
        self.scene = loaded.scene
        self.path, self.name = loaded.path, loaded.name
        self._watch_stamp = self.file_stamp()
        self.arrays = dict(loaded.arrays)
        self.queue_upload("pred", loaded.arrays)
        self.apply_auto_ranges(loaded.ranges)
        for text in loaded.notes:
            self.note("warning", text)
        H, W = self.scene.size
        self.note("info", f"opened {loaded.name} ({W}x{H}; layers: {', '.join(loaded.arrays)})")
        self._geometry_confidence()
        self.timings["load"] = time.perf_counter() - self.job_started
        if self.recent is not None and loaded.path is not None:
            self.recent.add(loaded.path)
        self.refresh_pins()
        self.update_title()

    def _on_progress(self, event: Progress) -> None:
        old = self.progress or (None, "")
        self.progress = (event.fraction if event.fraction is not None else old[0], event.text or old[1])

    def _on_layers(self, event: LayersReady) -> None:
        arrays, seconds = event.arrays, event.seconds
        self.scene = event.scene
        self.arrays.update(arrays)
        self.queue_upload("pred", arrays)
        self.apply_auto_ranges(event.ranges)
        self.timings["model"] = seconds
        extra = " (G: prediction / ground truth)" if self.gt is not None else ""
        self.note("info", f"model: {', '.join(arrays)} in {seconds:.1f} s{extra}")
        self._geometry_confidence()
        self.refresh_pins()

    def _geometry_confidence(self) -> None:
        """How far to trust the scene's geometry (phyir.evaluation.real.scene_confidence), for the status
        bar; a warning when it is flagged."""
        from phyir.commands.info import format_confidence
        from phyir.evaluation.real import scene_confidence

        sc = self.scene
        self.confidence = None
        if sc is None or sc.depth is None or sc.normal is None:
            return
        c = scene_confidence(sc)
        self.confidence = float(c["confidence"])
        if c["flagged"]:
            self.note("warning", f"geometry confidence {format_confidence(self.confidence)}: the floor "
                                 f"below the camera is {100 * float(c['nadir_up']):.0f}% floor-like and "
                                 f"normals and depth disagree by {float(c['consistency_deg']):.0f}°; "
                                 "insertions may be off")

    def _on_gt(self, event: GroundTruth) -> None:
        gt = event.scene
        # the file's layers are the ground truth now; the prediction starts from the image only
        for name in list(self.arrays):
            if name != "image":
                del self.arrays[name]
                tex = self.layer_textures.pop(("pred", name), None)
                if tex is not None:
                    tex.release()
        self.scene = PanoScene(image=gt.image, meta=dict(gt.meta))
        self.set_ground_truth(gt, event.arrays)
        self.show_gt = True  # the file's layers, at once; G switches to the prediction when it is in
        self.note("info", "the file's layers are ground truth: predicting all layers to compare (G switches)")
        self.refresh_pins()

    def _on_rendered(self, event: Rendered) -> None:
        if event.gt:
            self.timings["render_gt"] = event.seconds
            self.gt_arrays.update(event.arrays)
            self.queue_upload("gt", event.arrays)
        else:
            self.timings["render"] = event.seconds
            self.arrays.update(event.arrays)
            self.queue_upload("pred", event.arrays)

    def _on_note(self, event: Note) -> None:
        self.note("info", event.text)

    def _on_failed(self, event: Failed) -> None:
        self.note("error", event.text if event.stage == "loading" else f"{event.stage} failed: {event.text}")
        if event.stage == "loading":
            self.open_failed()
        self.busy, self.progress = False, None
        self.timings["job"] = time.perf_counter() - self.job_started

    def _on_done(self, _event: Done) -> None:
        self.busy, self.progress = False, None
        self.timings["job"] = time.perf_counter() - self.job_started
        self.refresh_pins()
        self.add_queued_objects()

    # each event type's handler (functions of this class body, called with the App)
    _handlers = {Loaded: _on_loaded, Progress: _on_progress, LayersReady: _on_layers, GroundTruth: _on_gt,
                 Rendered: _on_rendered, Note: _on_note, Failed: _on_failed, Done: _on_done}
