"""Loading, inference and re-rendering off the GL thread.

One job at a time runs in a daemon thread: load the file -> run the model for the layers the file
lacks -> re-render.  Each step posts an event (a small frozen dataclass: :class:`Loaded`,
:class:`Progress`, :class:`GroundTruth`, :class:`LayersReady`, :class:`Rendered`, :class:`Note`,
:class:`Failed`, :class:`Done`) to a queue that the GL thread drains every
frame (``Worker.poll``); ``wake`` (e.g. ``glfw.post_empty_event``) is called after each post so an
idle window wakes up.  Starting a job cancels the running one: its ``cancel`` event is set (the model
polls it) and its later updates are dropped.  torch runs with few threads so the UI thread keeps a
core; the thread count is restored when the job ends.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os

# Idle OpenMP threads sleep instead of spinning (set before torch loads, as phyir.cli does): a
# spinning inference thread would take the UI thread's core on a small CPU.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import queue
import sys
import threading
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.inference import Cancelled
from phyir.scene import PanoScene
from viewer.layers import PREDICTED, auto_ranges, rendered_arrays, scene_arrays


@dataclass(frozen=True)
class Loaded:
    """The file is read: its scene and layer arrays."""

    scene: PanoScene
    arrays: dict[str, np.ndarray]
    name: str
    path: str | None
    notes: list[str]
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)  # scalar layers' default ranges


@dataclass(frozen=True)
class Progress:
    """How far the job is: a fraction (None: unknown) and/or a message (None: unchanged)."""

    fraction: float | None
    text: str | None


@dataclass(frozen=True)
class GroundTruth:
    """Compare mode: the file's scene and layers are the ground truth; the model predicts all layers."""

    scene: PanoScene
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class LayersReady:
    """The model's layers: the scene with them, their arrays, automatic ranges and the model's time."""

    scene: PanoScene
    arrays: dict[str, np.ndarray]
    ranges: dict[str, tuple[float, float]]
    seconds: float


@dataclass(frozen=True)
class Rendered:
    """Re-rendered layers (diffuse, specular, re-render, error) of the prediction or, with ``gt``,
    of the ground truth."""

    arrays: dict[str, np.ndarray]
    seconds: float
    gt: bool = False


@dataclass(frozen=True)
class Note:
    """Something to tell the user."""

    text: str


@dataclass(frozen=True)
class Failed:
    """The job stopped with an error at ``stage`` (loading, running the model, re-rendering)."""

    stage: str
    text: str


@dataclass(frozen=True)
class Done:
    """The job finished."""


Event = Loaded | Progress | GroundTruth | LayersReady | Rendered | Note | Failed | Done


# niceness of the worker thread: the UI thread, llvmpipe's threads and the X server come first (with
# 5 the longest frame while loading under Xvfb was 79-154 ms, with 15 46-77 ms; job time the same)
WORKER_NICE = 15
SYNTH_SOURCE = "phyir synth"  # meta["source"] of phyir.synth's scenes: their layers are ground truth


def default_threads() -> int:
    """torch threads for inference: all cores but one (the UI's), at least one."""
    return max(1, (os.cpu_count() or 2) - 1)


class Worker:
    def __init__(self, wake: Callable[[], None] | None = None, predict: Callable | None = None,
                 render: Callable | None = None, threads: int | None = None,
                 predict_kwargs: dict | None = None):
        self._wake = wake or _no_wake
        self._predict = predict
        self.predict_kwargs = dict(predict_kwargs or {})  # e.g. weights=..., device=...
        self._render = render
        self.threads = threads or default_threads()
        self._queue: queue.Queue[tuple[int, Event]] = queue.Queue()
        self._job = 0
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self._threads: list[threading.Thread] = []  # cancelled jobs may still finish a torch op
        self._lock = threading.Lock()

    # -- GL-thread side ------------------------------------------------------------------------
    def start(self, source: str | os.PathLike | PanoScene, *, name: str | None = None,
              compare: bool | None = None, run_model: bool = True) -> int:
        """Start a job (cancelling the current one); returns its id.

        ``source``: a file path or a PanoScene.  The model fills only the layers the source lacks;
        with ``compare`` it predicts every layer and the source's own layers become ground truth
        (``None``: only for complete synthetic scenes, ``meta["source"] == SYNTH_SOURCE``).
        """
        with self._lock:
            self._cancel.set()
            self._job += 1
            self._cancel = threading.Event()
            job, cancel = self._job, self._cancel
        t = threading.Thread(target=self._run, args=(job, cancel, source, name, compare, run_model),
                             name=f"phyir-view job {job}", daemon=True)
        self._thread = t
        self._threads = [th for th in self._threads if th.is_alive()] + [t]
        t.start()
        return job

    def cancel(self) -> None:
        with self._lock:
            self._cancel.set()
            self._job += 1

    @property
    def job(self) -> int:
        return self._job

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and not self._cancel.is_set()

    def set_wake(self, wake: Callable[[], None] | None) -> None:
        """What the worker calls after each post (None: nothing, e.g. once the window is closing)."""
        self._wake = wake or _no_wake

    def poll(self) -> list[Event]:
        """Events of the current job posted since the last poll (stale jobs' events dropped)."""
        out = []
        while True:
            try:
                job, event = self._queue.get_nowait()
            except queue.Empty:
                return out
            if job == self._job:
                out.append(event)

    def join(self, timeout: float | None = None) -> None:
        """Wait for every job thread (cancelled ones included) up to ``timeout`` seconds in all."""
        end = None if timeout is None else time.monotonic() + timeout
        for t in self._threads:
            t.join(None if end is None else max(0.0, end - time.monotonic()))

    def _weights_available(self) -> bool:
        """An injected model, explicit weights, or the shipped default weights: a complete scene is
        only re-predicted for comparison when a model can actually run."""
        if self._predict is not None or self.predict_kwargs.get("weights"):
            return True
        from phyir.learn.weights import default_weights_path

        return default_weights_path().exists()

    # -- worker-thread side --------------------------------------------------------------------
    def _post(self, job: int, event: Event) -> None:
        self._queue.put((job, event))
        self._wake()

    def _run(self, job: int, cancel: threading.Event, source, name, compare: bool | None,
             run_model: bool) -> None:
        old_threads = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        _lower_priority()
        post = functools.partial(self._post, job)
        stage = ["loading"]
        try:
            loaded = load(source, name)
            post(loaded)
            self._check(cancel)
            scene = loaded.scene
            predict = (self._predict or _library_predict) if run_model else None
            missing = [n for n in PREDICTED if getattr(scene, n) is None]
            if compare is None:  # synthetic ground truth: predict everything and compare
                compare = (predict is not None and not missing and self._weights_available()
                           and scene.meta.get("source") == SYNTH_SOURCE)
            if compare:
                gt, missing = scene, list(PREDICTED)
                scene = PanoScene(image=scene.image, meta=dict(scene.meta))
                post(GroundTruth(gt, loaded.arrays))
                self._rerender(post, cancel, stage, scene=gt, gt=True)
            if missing and run_model:
                stage[0] = "running the model"
                post(Progress(0.0, f"running the model for {', '.join(missing)}"))
                t0 = time.perf_counter()
                pred = predict(scene, outputs=tuple(missing), progress=_progress(post, cancel),
                               cancel=cancel, **self.predict_kwargs)
                self._check(cancel)
                pred = pred[0] if pred.batched else pred
                scene = scene.replace(**{n: getattr(pred, n).detach().cpu().float() for n in missing
                                         if getattr(pred, n) is not None})
                arrays = scene_arrays(scene, missing)
                post(LayersReady(scene, arrays, auto_ranges(arrays), time.perf_counter() - t0))
            self._rerender(post, cancel, stage, scene=scene, gt=False)
            post(Done())
        except Cancelled:
            pass
        except PhyIRError as e:  # user-facing: the message names the file and the problem
            if not cancel.is_set():
                post(Failed(stage[0], str(e)))
        except Exception as e:  # noqa: BLE001 - a failing model must not take the viewer down
            if not cancel.is_set():
                traceback.print_exc()
                post(Failed(stage[0], f"{type(e).__name__}: {e}"))
        finally:
            torch.set_num_threads(old_threads)

    def _rerender(self, post, cancel: threading.Event, stage: list[str], *, scene: PanoScene,
                  gt: bool) -> None:
        """Post the re-rendered diffuse/specular/image and the error map, when the scene allows."""
        render = self._render or _library_render
        if not scene.has(*PREDICTED):
            return
        stage[0] = "re-rendering"
        post(Progress(None, "re-rendering diffuse and specular"))
        t0 = time.perf_counter()
        passes = render(scene)
        self._check(cancel)
        arrays = rendered_arrays(scene_arrays(scene, ("image",))["image"], passes)
        post(Rendered(arrays, time.perf_counter() - t0, gt))

    @staticmethod
    def _check(cancel: threading.Event) -> None:
        if cancel.is_set():
            raise Cancelled("job superseded")


# Modules a job imports on first use (phyir.io's readers, phyir.predict's model and weights, the
# re-render; numpy.ma, which np.percentile in layers.auto_range imports at its first call).
JOB_MODULES = ("numpy.ma", "phyir.io", "phyir.io.exr", "phyir.io.ldr", "phyir.io.rgbe", "phyir.inference",
               "phyir.learn.weights", "phyir.nets.model", "phyir.learn.datasets", "safetensors",
               "safetensors.torch", "phyir.io.files", "torch.utils._device",  # (weights: meta device)
               "phyir.shading.render",
               "phyir.lighting.fusion")  # the default lighting method's (phyir.lighting.methods.fused)


def preload() -> None:
    """Import :data:`JOB_MODULES` on the calling (UI) thread before any job runs.  An import holds
    the GIL for its whole unmarshal-and-execute (numpy.ma: ~40 ms alone, 160-200 ms inside a job on
    the loaded 2-core machine, the worker's lower priority stretching it), and the UI thread retakes
    the GIL after every GL call: a job importing them froze the UI that long
    (tests/viewer/app/test_viewer_warmup.py)."""
    for name in JOB_MODULES:
        if importlib.util.find_spec(name.partition(".")[0]) is not None:  # optional packages
            importlib.import_module(name)


def _lower_priority() -> None:
    """Nice this thread (Linux: per thread) so the UI thread wins the CPU when both want it."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WORKER_NICE)


def load(source: str | os.PathLike | PanoScene, name: str | None = None) -> Loaded:
    """Read a panorama or scene file (or take a PanoScene) and make its layer arrays."""
    notes: list[str] = []
    if isinstance(source, PanoScene):
        scene, path = source, None
        name = name or source.meta.get("name", "scene")
    else:
        from phyir import io

        path = os.fspath(source)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", io.InputWarning)
            scene = io.load_scene(path)
        notes = [str(w.message) for w in caught if issubclass(w.category, io.InputWarning)]
        name = name or Path(path).name
    if scene.batched:
        scene = scene[0]
    scene = scene.detach().to("cpu", torch.float32)
    arrays = scene_arrays(scene)
    return Loaded(scene, arrays, name, path, notes, auto_ranges(arrays))


def _progress(post, cancel: threading.Event) -> Callable:
    """A progress callback accepting (fraction[, message]) in any order; raises when cancelled."""
    def cb(*args, **kw):
        frac = next((float(a) for a in (*args, *kw.values()) if isinstance(a, (int, float))), None)
        text = next((a for a in (*args, *kw.values()) if isinstance(a, str)), None)
        post(Progress(frac, text))
        if cancel.is_set():
            raise Cancelled("job superseded")
    return cb


def _no_wake() -> None:
    """The default ``wake``: nothing to wake."""


def _library_predict(scene: PanoScene, **kwargs) -> PanoScene:
    """The model: :func:`phyir.predict`."""
    from phyir import predict

    return predict(scene, **kwargs)


def _library_render(scene: PanoScene) -> dict:
    """The re-render: split-sum shading, fast and close to the Monte Carlo render (docs/rendering.md)."""
    from phyir.shading.render import render_scene

    return render_scene(scene, method="prefiltered")
