"""Several images open at once (as in tev): :class:`ImageList`, the list, the image shown, the
reference to compare with and which image the worker loads next.

Each image is an :class:`Entry` with its own :class:`~viewer.app.document.Document`; the one shown
is ``doc``.  All images share the view, display settings and inserted objects, so switching
compares like with like.

The worker runs one job at a time: the current image first, with the model; then the reference,
with the model, so its predicted layers can be compared too; then every other image, read only --
the model runs for an image when it is shown.  A job for an image that is neither current nor the
reference gives way when the current one needs the worker.  A job's events go to the image it was
started for, shown or not (``job_target``).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from phyir.errors import PhyIRError
from phyir.scene import PanoScene
from viewer.app.common import Messages, gl_current
from viewer.app.document import Document
from viewer.app.loader import Loader, Opening
from viewer.worker import Done, Failed, Loaded


@dataclass(eq=False)
class Entry:
    """One open image: where it comes from, how far the worker got with it, and its document."""

    source: str | PanoScene | None = None
    options: dict = field(default_factory=dict)  # open()'s gt / name / compare for this image
    loaded: bool = False    # its file was read
    modelled: bool = False  # a job with the model finished for it
    held: bool = False      # its job was cancelled or failed: not restarted until it is shown again
    doc: Document = field(default_factory=Document)


@dataclass(frozen=True)
class Job:
    """The worker's job: for which image, from what, and whether with the model."""

    entry: Entry
    source: str | PanoScene
    options: dict
    model: bool
    rerun: bool  # a model job for an image already read: keep its view and pins


class ImageList:
    """The open images, a sequence of :class:`Entry`.  ``current`` indexes the one shown; ``reference``
    is the one compared with (None: none).  ``gl_context()`` makes the GL context current (freeing
    textures), ``retitle`` and ``redraw`` tell the window."""

    def __init__(self, loader: Loader, messages: Messages, *, gl_context: Callable,
                 retitle: Callable[[], None], redraw: Callable[[], None]):
        self.loader = loader
        self.messages = messages
        self.gl_context = gl_context
        self.retitle = retitle
        self.redraw = redraw
        self._entries: list[Entry] = [Entry()]
        self.current = 0
        self.reference: Entry | None = None
        self.on_no_reference: Callable[[], None] = lambda: None  # the comparison ends with it
        self._job: Job | None = None
        self.watch = False  # reload the file when it changes on disk (phyir-view --watch)
        self._watch_last = 0.0

    # -- the sequence ---------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._entries)

    def __getitem__(self, index: int) -> Entry:
        return self._entries[index]

    def __iter__(self) -> Iterator[Entry]:
        return iter(self._entries)

    def index(self, e: Entry) -> int:
        return self._entries.index(e)

    @property
    def entry(self) -> Entry:
        """The image shown."""
        return self._entries[self.current]

    @property
    def doc(self) -> Document:
        """The shown image's document."""
        return self.entry.doc

    @property
    def job(self) -> Job | None:
        """The worker's last job (None once its image closed)."""
        return self._job

    def label(self, e: Entry) -> str:
        """The image's name (its file's, before it is read)."""
        name, src = e.doc.name, e.source
        if not name and src is not None:
            name = src.meta.get("name", "scene") if isinstance(src, PanoScene) else Path(src).name
        return name or "(empty)"

    # -- switching ------------------------------------------------------------------------------
    def select(self, index: int) -> None:
        """Show image ``index`` (0-based); images of the same size keep the view."""
        if not 0 <= index < len(self._entries):
            raise PhyIRError(f"no image {index + 1} (there are {len(self._entries)})")
        if index != self.current:
            old_size = self.doc.size
            self.current = index
            self.doc.hover = None
            if self.doc.size is not None:  # another size: fitted, as panorama coordinates differ
                self.doc.fit_pending = self.doc.size != old_size
            self.retitle()
            self.redraw()
        self.entry.held = False
        self.schedule_jobs()

    def next(self, step: int = 1) -> None:
        """The next (``step`` 1) or previous (-1) image, wrapping around."""
        self.select((self.current + step) % len(self._entries))

    def set_reference(self, index: int | None) -> None:
        """Make image ``index`` (0-based) the reference; None: no reference (and no comparison)."""
        if index is None:
            self.reference = None
            self.on_no_reference()
        elif not 0 <= index < len(self._entries):
            raise PhyIRError(f"no image {index + 1} to use as the reference (there are {len(self._entries)})")
        else:
            self.reference = self._entries[index]
            self.reference.held = False
            self.schedule_jobs()  # its model's layers, to compare those too
        self.redraw()

    @property
    def reference_index(self) -> int | None:
        return None if self.reference is None else self._entries.index(self.reference)

    # -- adding and closing ---------------------------------------------------------------------
    def find(self, source: str | os.PathLike | PanoScene) -> Entry | None:
        """The open image read from ``source`` (the same file or the same scene object), if any."""
        for e in self._entries:
            if isinstance(source, PanoScene) or isinstance(e.source, PanoScene) or e.source is None:
                if e.source is source:
                    return e
            elif os.path.realpath(e.source) == os.path.realpath(os.fspath(source)):
                return e
        return None

    def queue(self, source: str | os.PathLike | PanoScene, **options) -> Entry:
        """Add an image to the list without showing it (read when the worker is free); an image
        already open is not added twice."""
        found = self.find(source)
        if found is not None:
            return found
        src = source if isinstance(source, PanoScene) else os.fspath(source)
        if self.entry.source is None and not self.loader.busy:  # the empty start: the first image takes it
            self.entry.source, self.entry.options = src, options
            e = self.entry
        else:
            e = Entry(src, options)
            self._entries.append(e)
        self.schedule_jobs()
        return e

    def add(self, source: str | os.PathLike | PanoScene, **options) -> Entry:
        """Add an image and show it (File > Open, a dropped file): read at once, with the model."""
        e = self.queue(source, **options)
        self.select(self._entries.index(e))
        return e

    @gl_current
    def close(self, index: int | None = None) -> None:
        """Close image ``index`` (default: the one shown), freeing its layers and textures."""
        e = self.entry if index is None else self._entries[index]
        if self._job is not None and self._job.entry is e and self.loader.busy:
            self.loader.stop()
            self._job = None
        if len(self._entries) == 1:
            e.doc.clear()
            e.doc.path, e.doc.name, e.doc.watch_stamp = None, "", None
            self._entries[0] = Entry(doc=e.doc)
        else:
            if e is self.entry:
                i = self._entries.index(e)
                self.select(i - 1 if i > 0 else 1)
            e.doc.clear()
            e.doc = Document()
            shown = self.entry
            self._entries.remove(e)
            self.current = self._entries.index(shown)
        if self.reference is e:
            self.set_reference(None)
        self.redraw()
        self.retitle()

    def release(self) -> None:
        """Free every image's GL resources (GL current; the app is closing)."""
        for e in self._entries:
            e.doc.clear()

    # -- the worker -----------------------------------------------------------------------------
    def open(self, source: str | os.PathLike | PanoScene, **kw) -> None:
        """Open a file or scene into the image shown (replacing it once read)."""
        e = self.entry
        options = {k: v for k, v in kw.items() if k in ("gt", "name", "compare")}
        if not e.loaded:
            e.source = source if isinstance(source, PanoScene) else os.fspath(source)
            e.options = options
        e.held = False
        self._job = Job(e, source, options, self.loader.run_model, rerun=False)
        self._start(e.doc, source, **kw)

    @gl_current
    def _start(self, doc: Document, source: str | os.PathLike | PanoScene, *, gt: PanoScene | None = None,
               name: str | None = None, compare: bool | None = None, model: bool | None = None) -> None:
        """Read ``source`` for ``doc`` in the worker; ``doc`` keeps its scene until the new one has
        loaded (a file that fails to open keeps it)."""
        if isinstance(source, PanoScene):
            path, shown = None, name or source.meta.get("name", "scene")
        else:
            path = os.fspath(source)
            shown = name or Path(path).name
        if doc.scene is None:  # nothing to keep: show the new name at once
            doc.clear()
            doc.path, doc.name = path, shown
        self.loader.start(source, Opening(path, shown, gt), name=name, compare=compare, model=model)
        self.retitle()

    def reload(self) -> None:
        """Open the current file again (File > Reload, Ctrl+R; automatic with ``watch``)."""
        if self.doc.path is None:
            raise PhyIRError("nothing to reload: the scene did not come from a file")
        self.open(self.doc.path)

    def check_file_changed(self, now: float | None = None) -> bool:
        """With ``watch`` on, at most once a second: reload the file when it changed on disk (a
        writer that is still writing is caught by the next check); True if a reload started."""
        now = time.monotonic() if now is None else now
        if not self.watch or self.loader.busy or self.doc.path is None or now - self._watch_last < 1.0:
            return False
        self._watch_last = now
        stamp = self.doc.file_stamp()
        if stamp is None or stamp == self.doc.watch_stamp:
            return False
        self.messages.note("info", f"{self.doc.name} changed on disk: reloading")
        self.reload()
        return True

    def cancel(self) -> None:
        """Stop the running job; its image waits until it is shown again."""
        if self.loader.busy and self._job is not None:
            self._job.entry.held = True
        self.loader.cancel()

    def schedule_jobs(self) -> None:
        """Start the next job the images need: the current one's, else the reference's, else the
        first unread image's.  A running job for another image gives way to the current one's."""
        wanted = [self.entry, self.reference]
        order = list(dict.fromkeys([e for e in wanted if e is not None] + self._entries))
        for e in order:
            if e.held or e.source is None:
                continue
            model = self.loader.run_model and e in wanted
            if e.loaded and (e.modelled or not model):
                continue
            if self.loader.busy:
                running = self._job.entry if self._job is not None else None
                if e is not self.entry or running in wanted:
                    return  # the worker is on an image that is looked at: wait for it
                self.loader.worker.cancel()
            self._job = Job(e, e.source, e.options, model and self.loader.run_model, e.loaded)
            self._start(e.doc, e.source, model=model, **e.options)
            return

    @contextlib.contextmanager
    def job_target(self, events: list, repin: Callable[[float, float, Document], object]):
        """Yield the document the worker's ``events`` are for, then note how far its job got; a
        rerun keeps the image's view and pins (``repin`` pins them again on the new layers)."""
        job = self._job
        if job is None or job.entry not in self._entries:
            yield self.doc
            return
        doc = job.entry.doc
        pins = [(p.u, p.v) for p in doc.pins] if job.rerun else []
        fit = doc.fit_pending
        yield doc
        if job.rerun and any(isinstance(ev, Loaded) for ev in events):
            doc.fit_pending = fit  # the same image again: keep its view and pins
            for u, v in pins:
                repin(u, v, doc)
        self.retitle()
        self._job_progress(job, events)

    def _job_progress(self, job: Job, events: list) -> None:
        e = job.entry
        for ev in events:
            if isinstance(ev, Loaded):
                e.loaded, e.source, e.options = True, job.source, job.options
            elif isinstance(ev, Done):
                e.modelled = e.modelled or job.model
            elif isinstance(ev, Failed):
                e.held = True  # not retried by itself: a second try would fail the same way
                if not e.loaded and len(self._entries) > 1:
                    self._job = None
                    self.close(self._entries.index(e))
        if not self.loader.busy:
            self.schedule_jobs()
