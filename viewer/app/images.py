"""Several images open at once (as in tev): the list, switching between them and which one the
worker loads next.

The shown image's state (``PER_IMAGE``: its scene, layers, textures, pins, ...) lives in the App's
own attributes, so every other part of the App reads it as it always did; switching stores those
attributes in the image's :class:`Entry` and restores the other's.  All images share the view,
display settings and inserted objects, so switching compares like with like.

The worker runs one job at a time, through the App's ``open`` (the one load path): the current
image first, with the model; then the reference (``viewer.app.comparison``), with the model, so its
predicted layers can be compared too; then every other image, read only -- the model runs for an
image when it is shown.  A job for an image that is neither current nor the reference gives way
when the current one needs the worker.  A job's events go to the image it was started for, shown
or not (``job_shown``).
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from pathlib import Path

from phyir.errors import PhyIRError
from phyir.scene import PanoScene
from viewer.app.common import gl_current
from viewer.worker import Done, Failed, Loaded

PER_IMAGE = ("path", "name", "scene", "confidence", "arrays", "gt", "gt_arrays", "show_gt", "pins",
             "timings", "layer_textures", "texture_versions", "pending_uploads", "_fit_pending",
             "_watch_stamp")


def fresh_state() -> dict:
    """The PER_IMAGE attributes of an image not read yet."""
    return {"path": None, "name": "", "scene": None, "confidence": None, "arrays": {}, "gt": None,
            "gt_arrays": {}, "show_gt": False, "pins": [], "timings": {}, "layer_textures": {},
            "texture_versions": {}, "pending_uploads": [], "_fit_pending": True, "_watch_stamp": None}


@dataclass(eq=False)
class Entry:
    """One open image: where it comes from, how far the worker got with it, and (while it is not the
    one shown) its PER_IMAGE state."""

    source: str | PanoScene | None = None
    options: dict = field(default_factory=dict)  # open()'s gt / name / compare for this image
    loaded: bool = False    # its file was read
    modelled: bool = False  # a job with the model finished for it
    held: bool = False      # its job was cancelled or failed: not restarted until it is shown again
    state: dict = field(default_factory=fresh_state)


@dataclass(frozen=True)
class _Job:
    entry: Entry
    source: str | PanoScene
    options: dict
    model: bool
    rerun: bool  # a model job for an image already read: keep its view and pins


class ImageList:
    """Part of :class:`viewer.app.App`: the open images."""

    def init_images(self) -> None:
        self.images: list[Entry] = [Entry()]
        self.current = 0
        self._job: _Job | None = None

    @property
    def entry(self) -> Entry:
        """The image shown."""
        return self.images[self.current]

    def image_state(self, e: Entry, key: str):
        """A PER_IMAGE attribute of image ``e`` (the App's own for the one shown)."""
        return getattr(self, key) if e is self.entry else e.state[key]

    def image_label(self, e: Entry) -> str:
        """The image's name (its file's, before it is read)."""
        name, src = self.image_state(e, "name"), e.source
        if not name and src is not None:
            name = src.meta.get("name", "scene") if isinstance(src, PanoScene) else Path(src).name
        return name or "(empty)"

    # -- switching ------------------------------------------------------------------------------
    def _stash(self) -> None:
        for k in PER_IMAGE:
            self.entry.state[k] = getattr(self, k)

    def _restore(self, e: Entry) -> None:
        for k in PER_IMAGE:
            setattr(self, k, e.state[k])

    def select_image(self, index: int) -> None:
        """Show image ``index`` (0-based); images of the same size keep the view."""
        if not 0 <= index < len(self.images):
            raise PhyIRError(f"no image {index + 1} (there are {len(self.images)})")
        if index != self.current:
            old_size = self.size
            self._stash()
            self.current = index
            self._restore(self.entry)
            self.hover = None
            if self.size is not None:  # another size: fitted, as panorama coordinates differ
                self._fit_pending = self.size != old_size
            self.update_title()
            self.request_redraw()
        self.entry.held = False
        self.schedule_jobs()

    def next_image(self, step: int = 1) -> None:
        """The next (``step`` 1) or previous (-1) image, wrapping around."""
        self.select_image((self.current + step) % len(self.images))

    @contextlib.contextmanager
    def _shown(self, e: Entry):
        """Make image ``e`` the App's state for the block (no-op when it is shown)."""
        if e is self.entry:
            yield
            return
        current = self.current
        self._stash()
        self.current = self.images.index(e)
        self._restore(e)
        try:
            yield
        finally:
            self._stash()
            self.current = current
            self._restore(self.entry)
            self.update_title()

    # -- adding and closing ---------------------------------------------------------------------
    def find_image(self, source: str | os.PathLike | PanoScene) -> Entry | None:
        """The open image read from ``source`` (the same file or the same scene object), if any."""
        for e in self.images:
            if isinstance(source, PanoScene) or isinstance(e.source, PanoScene) or e.source is None:
                if e.source is source:
                    return e
            elif os.path.realpath(e.source) == os.path.realpath(os.fspath(source)):
                return e
        return None

    def queue_image(self, source: str | os.PathLike | PanoScene, **options) -> Entry:
        """Add an image to the list without showing it (read when the worker is free); an image
        already open is not added twice."""
        found = self.find_image(source)
        if found is not None:
            return found
        src = source if isinstance(source, PanoScene) else os.fspath(source)
        if self.entry.source is None and not self.busy:  # the empty start: the first image takes it
            self.entry.source, self.entry.options = src, options
            e = self.entry
        else:
            e = Entry(src, options)
            self.images.append(e)
        self.schedule_jobs()
        return e

    def add_image(self, source: str | os.PathLike | PanoScene, **options) -> Entry:
        """Add an image and show it (File > Open, a dropped file): read at once, with the model."""
        e = self.queue_image(source, **options)
        self.select_image(self.images.index(e))
        return e

    @gl_current
    def close_image(self, index: int | None = None) -> None:
        """Close image ``index`` (default: the one shown), freeing its layers and textures."""
        e = self.entry if index is None else self.images[index]
        if self._job is not None and self._job.entry is e and self.busy:
            self.worker.cancel()
            self.busy, self.progress, self._opening, self._job = False, None, None, None
        if len(self.images) == 1:
            self.clear_shown()
            self.path, self.name, self._watch_stamp = None, "", None
            self.images[0] = Entry()
        else:
            if e is self.entry:
                i = self.images.index(e)
                self.select_image(i - 1 if i > 0 else 1)
            self._free(e)
            shown = self.entry
            self.images.remove(e)
            self.current = self.images.index(shown)
        self.forget_image(e)
        self.request_redraw()
        self.update_title()

    def _free(self, e: Entry) -> None:
        """Release the GL resources of image ``e`` (not the one shown)."""
        for tex in e.state["layer_textures"].values():
            tex.release()
        e.state["layer_textures"].clear()
        for pin in e.state["pins"]:
            self.release_pin(pin)
        e.state = fresh_state()

    def close_other_images(self) -> None:
        """Free every image but the one shown (App.close frees that one)."""
        for e in self.images:
            if e is not self.entry:
                self._free(e)

    # -- the worker -----------------------------------------------------------------------------
    def open(self, source: str | os.PathLike | PanoScene, **kw) -> None:
        """Open a file or scene into the image shown (replacing it once read), as before."""
        e = self.entry
        options = {k: v for k, v in kw.items() if k in ("gt", "name", "compare")}
        if not e.loaded:
            e.source = source if isinstance(source, PanoScene) else os.fspath(source)
            e.options = options
        e.held = False
        self._job = _Job(e, source, options, self.run_model, rerun=False)
        super().open(source, **kw)

    def _start_job(self, e: Entry, model: bool) -> None:
        rerun = e.loaded
        with self._shown(e):
            self._job = _Job(e, e.source, e.options, model and self.run_model, rerun)
            super().open(e.source, model=model, **e.options)

    def cancel(self) -> None:
        """Stop the running job; its image waits until it is shown again."""
        if self.busy and self._job is not None:
            self._job.entry.held = True
        super().cancel()

    def schedule_jobs(self) -> None:
        """Start the next job the images need: the current one's, else the reference's, else the
        first unread image's.  A running job for another image gives way to the current one's."""
        wanted = [self.entry, getattr(self, "reference", None)]
        order = list(dict.fromkeys([e for e in wanted if e is not None] + self.images))
        for e in order:
            if e.held or e.source is None:
                continue
            model = self.run_model and e in wanted
            if e.loaded and (e.modelled or not model):
                continue
            if self.busy:
                running = self._job.entry if self._job is not None else None
                if e is not self.entry or running in wanted:
                    return  # the worker is on an image that is looked at: wait for it
                self.worker.cancel()
            self._start_job(e, model)
            return

    @contextlib.contextmanager
    def job_shown(self, events: list):
        """Apply worker events to the image the job is for, then note how far it got."""
        job = self._job
        if job is None or job.entry not in self.images:
            yield
            return
        with self._shown(job.entry):
            pins = [(p.u, p.v) for p in self.pins] if job.rerun else []
            fit = self._fit_pending
            yield
            if job.rerun and any(isinstance(ev, Loaded) for ev in events):
                self._fit_pending = fit  # the same image again: keep its view and pins
                for u, v in pins:
                    self.pin_probe(u, v)
        self._job_progress(job, events)

    def _job_progress(self, job: _Job, events: list) -> None:
        e = job.entry
        for ev in events:
            if isinstance(ev, Loaded):
                e.loaded, e.source, e.options = True, job.source, job.options
            elif isinstance(ev, Done):
                e.modelled = e.modelled or job.model
            elif isinstance(ev, Failed):
                e.held = True  # not retried by itself: a second try would fail the same way
                if not e.loaded and len(self.images) > 1:
                    self._job = None
                    self.close_image(self.images.index(e))
        if not self.busy:
            self.schedule_jobs()
