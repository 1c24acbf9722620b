"""The App's file I/O: opening a file or scene (read in the worker), ground truth to compare with,
cancelling, dropped files and screenshots."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.scene import PanoScene
from viewer.app.common import gl_current
from viewer.layers import auto_ranges, scene_arrays


@dataclass(frozen=True)
class _Opening:
    """A file being opened: what to show and compare with once it has loaded."""

    path: str | None
    name: str
    gt: PanoScene | None


class FileActions:
    """Part of :class:`viewer.app.App`: opening and saving."""

    def on_drop(self, paths: list[str]) -> None:
        """Files dropped on the window: added to the open images, the first shown."""
        for k, path in enumerate(paths):
            self.add_image(path) if k == 0 else self.queue_image(path)
        self.request_redraw()

    # -- opening ------------------------------------------------------------------------------
    @gl_current
    def open(self, source: str | os.PathLike | PanoScene, *, gt: PanoScene | None = None,
             name: str | None = None, compare: bool | None = None, model: bool | None = None) -> None:
        """Open a panorama/scene file or a PanoScene; cancels a running job.  The file is read in the
        worker; its layers appear when read, the model's when computed.  ``gt``: a ground-truth
        scene to compare with; ``compare``: treat the file's own layers as ground truth and predict
        all layers (default: only for complete synthetic scenes); ``model=False``: only read it
        (an image in the background, viewer.app.images)."""
        self.worker.cancel()
        self.error = None
        if isinstance(source, PanoScene):
            path, shown = None, name or source.meta.get("name", "scene")
        else:
            path = os.fspath(source)
            shown = name or Path(path).name
        if self.scene is None:  # nothing to keep: show the new name at once
            self.clear_shown()
            self.path, self.name = path, shown
        # the current scene stays until the new one has loaded (a file that fails to open keeps it)
        self._opening = _Opening(path, shown, None if gt is None else
                                 (gt if not gt.batched else gt[0]).detach().to("cpu", torch.float32))
        self.progress = (None, f"opening {shown}")
        self.busy = True
        self.job_max_frame, self.job_frames, self.job_max_parts = 0.0, 0, {}
        self.job_started = time.perf_counter()
        run_model = self.run_model if model is None else model and self.run_model
        self.worker.start(source, name=name, compare=compare, run_model=run_model)
        self.update_title()

    @property
    def opening(self) -> str | None:
        """The name of the file being opened (until it has loaded or failed), else None."""
        return self._opening.name if self._opening is not None else None

    def reload(self) -> None:
        """Open the current file again (File > Reload, Ctrl+R; automatic with ``watch``)."""
        if self.path is None:
            raise PhyIRError("nothing to reload: the scene did not come from a file")
        self.open(self.path)

    def file_stamp(self) -> tuple | None:
        try:
            st = os.stat(self.path) if self.path else None
        except OSError:
            return None
        return None if st is None else (st.st_mtime_ns, st.st_size)

    def check_file_changed(self, now: float | None = None) -> bool:
        """With ``watch`` on, at most once a second: reload the file when it changed on disk (a
        writer that is still writing is caught by the next check); True if a reload started."""
        now = time.monotonic() if now is None else now
        if not self.watch or self.busy or self.path is None or now - self._watch_last < 1.0:
            return False
        self._watch_last = now
        stamp = self.file_stamp()
        if stamp is None or stamp == self._watch_stamp:
            return False
        self.note("info", f"{self.name} changed on disk: reloading")
        self.reload()
        return True

    def begin_opened(self) -> None:
        """The file being opened has loaded: the previous scene goes, the given ground truth comes."""
        opening, self._opening = self._opening, None
        self.clear_shown()
        self._watch_stamp = None  # set from the file once its layers are in (_on_loaded)
        if opening is not None and opening.gt is not None:
            self.set_ground_truth(opening.gt)

    def open_failed(self) -> None:
        """The file being opened could not be read: keep showing the current scene."""
        opening, self._opening = self._opening, None
        if opening is not None and self.scene is not None:
            self.note("info", f"still showing {self.name}")

    def clear_shown(self) -> None:
        for tex in self.layer_textures.values():
            tex.release()
        self.layer_textures.clear()
        self.pending_uploads.clear()
        for pin in self.pins:
            self.release_pin(pin)
        self.pins.clear()
        self.scene, self.arrays, self.gt, self.gt_arrays = None, {}, None, {}
        self.show_gt = False
        self.hover = None
        self.timings = {}
        self._fit_pending = True

    def set_ground_truth(self, gt: PanoScene, arrays: dict[str, np.ndarray] | None = None) -> None:
        """Ground truth: a scene given to ``open`` (arrays made here) or the file's layers in compare
        mode (arrays made, and their ranges applied, when the file loaded)."""
        if arrays is None:
            arrays = scene_arrays(gt)
            self.gt = None  # so that its ranges apply
            self.apply_auto_ranges(auto_ranges(arrays))
        self.gt, self.gt_arrays = gt, dict(arrays)
        self.queue_upload("gt", self.gt_arrays)

    def cancel(self) -> None:
        """Stop the running job (keeps the layers that arrived)."""
        if self.busy:
            self.worker.cancel()
            self._opening = None
            self.busy = False
            self.progress = None
            self.note("info", "cancelled")

    def request_screenshot(self, path: str | os.PathLike | None = None) -> None:
        """Save a screenshot after the frame being built (F12, the menu): ``screenshot`` draws frames
        itself, which it cannot do from inside the UI's frame (imgui's frame is open)."""
        if path is None:
            stem = os.path.splitext(self.path or "phyir-view")[0]
            path = f"{stem}.{self.layer}.png"
        self._screenshot_request = os.fspath(path)
        self.request_redraw()

    def save_requested_screenshot(self) -> None:
        """After a frame: the screenshot asked for while it was built, with a note on the outcome."""
        out, self._screenshot_request = self._screenshot_request, None
        if out is None:
            return
        try:
            self.screenshot(out)
        except OSError as e:  # e.g. a read-only folder: report, keep running
            self.note("error", f"cannot save {out}: {e.strerror or e}")
            return
        self.note("info", f"saved {out}")

    def export_gltf(self, path: str | os.PathLike | None = None):
        """The room, its lights, the inserted objects and the perspective view's camera as
        glTF (``phyir.export``: PATH.glb + PATH_env.exr, default next to the file); a note says where."""
        from phyir.export.bundle import export_gltf

        sc = self.objects.scene()
        if sc is None or sc.depth is None:
            raise PhyIRError("nothing to export: the scene has no depth yet")
        if path is None:
            path = f"{os.path.splitext(self.path or self.name)[0]}.glb"
        cam = self.views["perspective"]
        w, h = self.view_size()
        report = export_gltf(sc, os.fspath(path), objects=[o for o in self.objects.objects if o.visible],
                             fov_deg=float(cam.fov), aspect=w / max(h, 1), camera_rotation=cam.rotation())
        self.note("info", f"exported {report.glb} and {report.exr} ({report.lights} lights, "
                          f"{report.objects} objects, {report.seconds:.1f} s)")
        return report

    @gl_current
    def screenshot(self, path: str | os.PathLike | None = None) -> np.ndarray:
        """Draw a frame of the current state and return it as uint8 RGB (rows from the top);
        written atomically as PNG to ``path`` if given."""
        self.frame(capture=True)
        while self.uploaded_last_frame or self.pending_uploads:  # the view lags uploads by a frame
            self.frame(capture=True)
        img = self.last_capture
        if path is not None:
            from PIL import Image

            from phyir.io import atomic_write

            with atomic_write(path) as tmp:
                Image.fromarray(img).save(tmp, format="PNG")
        return img
