"""A long scripted session of the real viewer.

The App (headless EGL, imgui interface drawn every frame) goes through 500 seeded random actions —
opening files (small generated scenes and panoramas, a real panorama when ``../shared/panos`` is
there, a synthetic ground-truth scene, a corrupt file and a non-panorama), switching layers, views
and ground truth, panning and zooming, display settings, pinning and unpinning probes, adding,
dragging, restyling and deleting objects and exporting composites — with a frame drawn after every
action.  It checks that

* no action raises anything but a one-line ``PhyIRError`` (refusals such as "no panorama is open"),
  the worker reports no failure, and only the two bad files raise the error banner, naming the file;
* memory stays bounded: resident memory (RSS) at the end exceeds that after a warm-up of
  :data:`WARMUP` actions by at most :data:`RSS_BOUND_MB`, and the moderngl objects alive (created
  and not released: textures, framebuffers, buffers, programs...) at the end exceed those alive
  after the warm-up by at most :data:`GL_BOUND` (what differs is the open file's layers, pins and
  objects; everything else is released);
* ``App.close`` ends the worker: every job thread joined, no thread left behind.
"""

from __future__ import annotations

import ctypes
import gc
import math
import random
import threading
import time
import traceback
from pathlib import Path

import numpy as np
import pytest
import torch

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.paths import PANOS  # noqa: E402
from support.scenes import box_room  # noqa: E402
from support.viewer import cheap_render  # noqa: E402

from phyir import io  # noqa: E402
from phyir.errors import PhyIRError  # noqa: E402
from phyir.scene import PanoScene  # noqa: E402

# ~40 s of CPU; the timeout leaves room for a machine where it gets a few percent of a core
pytestmark = [pytest.mark.gl, pytest.mark.slow, pytest.mark.timeout(1800)]

ACTIONS = 500
# actions before the memory baseline: every kind of action has run by then, and most shader variants
# (display x view x quality, the draft composite's too) are compiled: each costs llvmpipe megabytes
WARMUP = 250
RSS_BOUND_MB = 40.0  # growth of resident memory from the baseline to the end (measured +12)
GL_BOUND = 16  # growth of live moderngl objects, baseline to end (measured +8: new shader variants)
SIZE = (720, 440)
GL_FACTORIES = ("texture", "texture_array", "texture_cube", "texture3d", "depth_texture", "framebuffer",
                "renderbuffer", "depth_renderbuffer", "buffer", "vertex_array", "simple_vertex_array",
                "program", "sampler", "query", "scope", "compute_shader")


class QuickModel:
    """Stands in for ``phyir.predict``: the box room's layers at the image's size, after a few short
    steps that report progress and honour cancellation (so actions land while it runs)."""

    def __init__(self):
        self.calls = 0
        self._rooms: dict[tuple[int, int], PanoScene] = {}

    def __call__(self, scene, *, outputs, progress, cancel, **kw):
        self.calls += 1
        H, W = scene.size
        room = self._rooms.get((H, W))
        if room is None:
            room = self._rooms[(H, W)] = box_room(H, W, variant="viewer")
        for k in range(3):
            time.sleep(0.02)
            progress(k / 3, f"step {k + 1}/3")
            if cancel.is_set():
                raise RuntimeError("cancelled")
        return PanoScene(image=scene.image, **{n: getattr(room, n) for n in outputs})


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def settle_memory() -> float:
    gc.collect()
    try:  # hand freed heap pages back, so RSS shows what is held, not what malloc keeps around
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    return rss_mb()


class GLCounter:
    """Records every object a moderngl context creates (``moderngl.Context``'s factories patched while
    ``monkeypatch`` lives); ``live()`` counts those not released: an object dropped without
    ``release()`` stays counted, as its GL object leaks."""

    def __init__(self, monkeypatch):
        import moderngl

        self.objects: list = []  # (object, creation number, where)
        self.count = self.mark = 0
        self._invalid = moderngl.InvalidObject
        for name in GL_FACTORIES:
            make = getattr(moderngl.Context, name, None)
            if make is not None:
                monkeypatch.setattr(moderngl.Context, name, self._wrap(make))

    def _wrap(self, make):
        def create(ctx, *args, **kw):
            obj = make(ctx, *args, **kw)
            site = next((f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in
                         reversed(traceback.extract_stack(limit=8)[:-1]) if "/viewer/" in f.filename), "?")
            self.objects.append((obj, self.count, site))
            self.count += 1
            return obj
        return create

    def live(self) -> int:
        self.objects = [o for o in self.objects if not isinstance(getattr(o[0], "mglo", None), self._invalid)]
        self.mark = self.count
        return len({id(o[0]) for o in self.objects})

    def since(self, mark: int) -> dict[str, int]:
        """Live objects created after ``mark``, by type and the viewer line that made them."""
        out: dict[str, int] = {}
        for obj, k, site in self.objects:
            if k >= mark:
                key = f"{type(obj).__name__} {site}"
                out[key] = out.get(key, 0) + 1
        return out


def make_files(tmp, panos: list) -> dict[str, object]:
    """The session's files: (path, what opening it must give)."""
    files = {}
    sc = box_room(32, 64, variant="viewer")
    io.save_scene(sc, tmp / "scene.exr")
    files["scene.exr"] = "ok"
    synth = box_room(32, 64, variant="viewer").replace(meta={"source": "phyir synth", "name": "synthetic"})
    io.save_scene(synth, tmp / "synth.exr")  # ground truth: predicted and compared (G)
    files["synth.exr"] = "ok"
    io.save_panorama(box_room(32, 64, variant="viewer").image, tmp / "room.hdr")
    files["room.hdr"] = "ok"
    io.save_panorama(box_room(24, 48, variant="viewer").image * 0.5, tmp / "room.png")
    files["room.png"] = "ok"
    for p in panos[:1]:  # a real indoor panorama, reduced to 64 x 128
        from phyir.pano import resize_area

        io.save_panorama(resize_area(io.load_panorama(p)[None], 64, 128)[0], tmp / "real.exr")
        files["real.exr"] = "ok"
    data = (tmp / "scene.exr").read_bytes()
    (tmp / "corrupt.exr").write_bytes(data[: len(data) // 2])
    files["corrupt.exr"] = "error"
    io.save_panorama(torch.rand(3, 20, 30), tmp / "not-a-pano.png")
    files["not-a-pano.png"] = "error"
    (tmp / "tetra.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    return files


def test_random_session_of_500_actions(egl, tmp_path, monkeypatch):
    from phyir.insert.objects import PRESETS, PRIMITIVES
    from viewer.app import App
    from viewer.insertion import FUSIONS
    from viewer.layers import LAYERS
    from viewer.recent import RecentFiles
    from viewer.renderer import COLORMAPS, TONEMAPS

    files = make_files(tmp_path, sorted(PANOS.glob("*.hdr")) if PANOS.is_dir() else [])
    threads_before = set(threading.enumerate())
    model = QuickModel()
    gl = GLCounter(monkeypatch)
    app = App(SIZE, headless=True, predict=model, render=cheap_render, threads=1,
              recent=RecentFiles(tmp_path / "recent.json"))
    errors: list[tuple[str, str]] = []  # (file open, error text) of every error note
    note = app.messages.note

    def recording_note(level, text):
        if level == "error":
            # a failed open keeps the scene (and name)
            errors.append((app.loader.opening or app.doc.name, text))
        note(level, text)

    app.messages.note = recording_note
    rng = random.Random(9)
    counts: dict[str, int] = {}
    cpu: dict[str, float] = {}  # CPU seconds (all threads) per kind of action, its frame included
    refusals: list[str] = []
    exports: list[str] = []
    state = {"file": None}

    def size():
        if app.doc.size is None:  # still loading, or the last file was refused
            raise PhyIRError("no panorama is open")
        return app.doc.size

    def uv():
        H, W = size()
        return rng.uniform(0, W), rng.uniform(0, H)

    def xy():
        w, h = app.view_size()
        return rng.uniform(0, w), rng.uniform(0, h)

    def do_open():
        name = rng.choice(list(files))
        state["file"] = name
        app.open(tmp_path / name)
        if rng.random() < 0.6:  # else the next actions land while it loads and the model runs
            assert app.wait_idle(60), app.loader.progress
            want = files[name]
            if want == "error":
                error = app.messages.error
                assert error and name in error and "\n" not in error, error
            else:
                assert app.messages.error is None, app.messages.error

    def do_pin():
        if rng.random() < 0.5:
            app.camera.click(*xy())
        else:
            app.pins.pin_probe(*uv())

    def do_add():
        spec = rng.choice((*PRIMITIVES, str(tmp_path / "tetra.obj")))
        app.objects.add(spec, PRESETS[rng.choice(list(PRESETS))], rng.uniform(0.1, 0.4), at=uv())

    def pick_object():
        if not app.objects.objects:
            raise PhyIRError("no objects")
        return rng.randrange(len(app.objects.objects))

    def do_drag_object():
        panel = app.objects
        i = pick_object()
        obj = panel.objects[i]
        c = obj.bounding_sphere()[0]
        from phyir import pano

        H, W = size()
        u, v, _ = pano.points_to_uv(torch.as_tensor(c), H, W)
        x, y, front = app.camera.view.uv_to_screen(np.array(float(u)), np.array(float(v)), app.view_size(),
                                                   app.doc.size)
        if not (front and panel.begin_drag(float(x), float(y))):
            raise PhyIRError("the object is not under the mouse")
        for _ in range(rng.randint(1, 4)):
            panel.drag_to(float(x) + rng.uniform(-30, 30), float(y) + rng.uniform(-15, 15))
            app.frame()
        panel.end_drag()

    def do_export():
        path = tmp_path / f"export{len(exports) % 3}.{rng.choice(('exr', 'png'))}"
        exports.extend(app.objects.export(str(path)))

    def canonical():
        """The same state at the baseline and at the end: the scene open, no pins, no objects."""
        app.open(tmp_path / "scene.exr")
        assert app.wait_idle(60) and app.messages.error is None
        while app.objects.objects:
            app.objects.delete(0)
        while app.pins:
            app.pins.unpin()
        app.display.set_layer("image")
        app.camera.set_view("equirect")
        app.frame()

    actions = {
        "open": (4, do_open),
        "layer": (12, lambda: app.display.set_layer(rng.choice(LAYERS))),
        "truth": (2, lambda: app.display.set_source(rng.random() < 0.5)),
        "pan": (8, lambda: app.camera.drag(rng.uniform(-80, 80), rng.uniform(-40, 40))),
        "zoom": (6, lambda: app.camera.scroll(rng.uniform(-4, 4), *xy())),
        "fit": (2, lambda: app.camera.fit() if rng.random() < 0.5 else app.camera.one_to_one()),
        "view": (5, lambda: app.camera.set_view(rng.choice(("equirect", "perspective")))),
        "look": (3, lambda: app.camera.set_view("perspective", yaw=rng.uniform(-math.pi, math.pi),
                                         pitch=rng.uniform(-1.2, 1.2), fov=rng.uniform(40, 110))),
        "exposure": (3, lambda: app.display.set_exposure(rng.uniform(-4, 4))),
        "tonemap": (2, lambda: app.display.set_tonemap(rng.choice(TONEMAPS))),
        "colormap": (2, lambda: app.display.set_colormap(rng.choice(COLORMAPS),
                                                         rng.choice(list(app.display.scalar)))),
        "range": (2, lambda: app.display.set_range(None) if rng.random() < 0.5
                  else app.display.set_range(rng.uniform(0, 1), rng.uniform(1, 5))),
        "hover": (5, lambda: app.camera.hover_at(*xy())),
        "pin": (7, do_pin),
        "pin exposure": (2, lambda: app.pins.set_pin_exposure(rng.randrange(len(app.pins)) if app.pins else
                                                         _refuse("no pins"), rng.uniform(-3, 3))),
        "unpin": (5, lambda: app.pins.unpin(rng.randrange(len(app.pins)) if app.pins else -1)),
        "add object": (6, do_add),
        "drop object": (2, lambda: app.objects.drop_at(*uv(), pick_object())),
        "drag object": (4, do_drag_object),
        "material": (2, lambda: app.objects.set_material(pick_object(), rng.choice(list(PRESETS)))),
        "scale": (2, lambda: app.objects.set_scale(pick_object(), rng.uniform(0.05, 0.5))),
        "visible": (1, lambda: app.objects.set_visible(pick_object(), rng.random() < 0.7)),
        "duplicate": (1, lambda: app.objects.duplicate(pick_object())),
        "delete object": (5, lambda: app.objects.delete(pick_object())),
        "fusion": (1, lambda: setattr(app.objects.hook, "fusion", rng.choice(FUSIONS))),
        "export": (2, do_export),
        "cancel": (1, app.images.cancel),
    }
    names = list(actions)
    weights = [actions[n][0] for n in names]
    base_rss = base_gl = None
    t0, c_start = time.perf_counter(), time.process_time()
    for step in range(ACTIONS):
        if step == 0:
            kind = "open"
        else:
            kind = rng.choices(names, weights)[0]
        counts[kind] = counts.get(kind, 0) + 1
        c0 = time.process_time()
        try:
            actions[kind][1]()
        except PhyIRError as e:  # a refusal the interface shows as a message: one line
            assert "\n" not in str(e), str(e)
            refusals.append(f"{kind}: {e}")
        app.frame()
        cpu[kind] = cpu.get(kind, 0.0) + time.process_time() - c0
        if len(app.objects.objects) > 6:  # keep the scene's object count realistic
            app.objects.delete(0)
        if step % 50 == 0:
            print(f"step {step}: {time.perf_counter() - t0:.1f} s, CPU {time.process_time() - c_start:.1f} s,"
                  f" {app.doc.name}, RSS {rss_mb():.0f} MB", flush=True)
        if step == WARMUP - 1:
            canonical()
            base_gl, base_rss = gl.live(), settle_memory()
            base_mark = gl.mark
    canonical()
    end_gl, end_rss = gl.live(), settle_memory()
    elapsed = time.perf_counter() - t0
    app.close()
    # the worker is gone: every job thread joined, nothing left behind
    assert not any(t.is_alive() for t in app.worker._threads)
    left = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    assert not left, left

    print(f"\n{ACTIONS} actions in {elapsed:.1f} s; model calls {model.calls}; refusals {len(refusals)}; "
          f"exports {len(exports)};\nRSS {base_rss:.1f} -> {end_rss:.1f} MB; live moderngl objects "
          f"{base_gl} -> {end_gl}; CPU {time.process_time() - c_start:.1f} s\n"
          f"live objects made after the baseline: {gl.since(base_mark)}\n"
          + "\n".join(f"  {k}: {counts[k]} x, {cpu[k]:.1f} s CPU" for k in sorted(cpu, key=cpu.get)[::-1]))
    unexpected = [(f, e) for f, e in errors if files.get(f) != "error"]
    assert not unexpected, unexpected
    assert all(f in e for f, e in errors), errors  # each banner names its file
    # every kind of action ran, and the object and probe actions mostly did something
    assert set(counts) == set(actions), set(actions) - set(counts)
    assert len(refusals) < ACTIONS // 4, refusals[:20]
    assert exports and all(p.endswith((".exr", ".png")) for p in exports)
    assert end_rss - base_rss <= RSS_BOUND_MB, (base_rss, end_rss)
    assert end_gl - base_gl <= GL_BOUND, (base_gl, end_gl)


def _refuse(text: str):
    raise PhyIRError(text)
