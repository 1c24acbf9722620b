"""The bridge to the worker (:class:`Loader`): starting and cancelling its one job, what the job is
doing (``busy``, ``progress``) and how the UI's frames fared while it ran."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import torch

from phyir.scene import PanoScene
from viewer.app.common import Messages
from viewer.worker import Worker


@dataclass(frozen=True)
class Opening:
    """A file being opened: what to show and compare with once it has loaded."""

    path: str | None
    name: str
    gt: PanoScene | None


class Loader:
    """Owns the job's state; ``run_model=False`` never runs the model (only reads files)."""

    def __init__(self, worker: Worker, messages: Messages, run_model: bool = True):
        self.worker = worker
        self.messages = messages
        self.run_model = run_model
        self.busy = False
        self.progress: tuple[float | None, str] | None = None
        self.job_started = 0.0
        self._opening: Opening | None = None
        self.job_max_frame = 0.0  # longest frame while the current job ran (s)
        self.job_max_parts: dict[str, tuple[float, float]] = {}  # that frame's parts: (wall, CPU) s
        self.job_frames = 0

    def start(self, source: str | os.PathLike | PanoScene, opening: Opening, *, name: str | None = None,
              compare: bool | None = None, model: bool | None = None) -> None:
        """Read ``source`` in the worker (cancelling its job), with the model unless ``model=False``."""
        self.worker.cancel()
        self.messages.error = None
        gt = opening.gt
        if gt is not None:
            gt = (gt if not gt.batched else gt[0]).detach().to("cpu", torch.float32)
        self._opening = Opening(opening.path, opening.name, gt)
        self.progress = (None, f"opening {opening.name}")
        self.busy = True
        self.job_max_frame, self.job_frames, self.job_max_parts = 0.0, 0, {}
        self.job_started = time.perf_counter()
        run_model = self.run_model if model is None else model and self.run_model
        self.worker.start(source, name=name, compare=compare, run_model=run_model)

    @property
    def opening(self) -> str | None:
        """The name of the file being opened (until it has loaded or failed), else None."""
        return self._opening.name if self._opening is not None else None

    def take_opening(self) -> Opening | None:
        """The file being opened, which has loaded or failed: no longer being opened."""
        opening, self._opening = self._opening, None
        return opening

    def stop(self) -> None:
        """End the job without a word (its image was closed)."""
        self.worker.cancel()
        self.busy, self.progress, self._opening = False, None, None

    def cancel(self) -> bool:
        """Stop the running job (keeps the layers that arrived); True if one ran."""
        if not self.busy:
            return False
        self.stop()
        self.messages.note("info", "cancelled")
        return True

    def finished(self) -> float:
        """The job ended (done or failed); returns how long it took (s)."""
        self.busy, self.progress = False, None
        return time.perf_counter() - self.job_started

    def record_frame(self, seconds: float, parts: dict[str, tuple[float, float]]) -> None:
        """A frame drawn while the job runs: the longest one and its parts are kept."""
        if not self.busy:
            return
        if seconds > self.job_max_frame:
            self.job_max_parts = dict(parts)
        self.job_max_frame = max(self.job_max_frame, seconds)
        self.job_frames += 1
