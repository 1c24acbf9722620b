"""Nothing that stalls the UI thread happens while a panorama loads: every shader variant the job
draws was drawn at start-up (software GL compiles a variant at its first draw), the worker imports
no module and a garbage collection scans no start-up objects (both hold the GIL, which the UI thread
retakes after every GL call)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.paths import REPO  # noqa: E402
from support.scenes import box_room  # noqa: E402
from support.viewer import FakeModel, cheap_render  # noqa: E402

from phyir.scene import PanoScene  # noqa: E402

pytestmark = pytest.mark.gl



@pytest.fixture(scope="module")
def app(egl):
    from viewer.app import App

    a = App((700, 420), headless=True, recent=False, render=cheap_render)
    yield a
    a.close()


def _run_job(app, truth: PanoScene) -> list[tuple]:
    """Open the image of ``truth`` with a model returning its layers; the shader variants drawn for
    the first time while the job ran."""
    start = len(app.renderer.first_draws)
    app.worker._predict = FakeModel(truth, steps=8)
    try:
        app.open(PanoScene(image=truth.image))
        assert app.wait_idle(60)
    finally:
        app.worker._predict = None
    assert app.messages.error is None and "rerender" in app.doc.arrays and app.loader.job_frames >= 2
    return app.renderer.first_draws[start:]


@pytest.mark.parametrize("size", [(64, 128), (48, 96), (64, 96)], ids=["pot", "npot", "npot-width"])
def test_a_loading_panorama_draws_no_new_shader_variant(app, size):
    app.display.set_layer("image")
    app.camera.set_view("equirect")
    assert _run_job(app, box_room(*size, variant="viewer")) == []
    # the job drew: the image in the view's cache, copied to the canvas
    drawn = {key[0][0] for key in app.renderer.variants}
    assert {"view.frag", "blit.frag"} <= drawn


def test_every_layer_view_tone_map_and_a_probe_were_drawn_at_start_up(app):
    """After the job: switching layers, views, tone maps and pinning a probe compile nothing either
    (a panorama with power-of-two sides, like the 1024x512 ones)."""
    from viewer.layers import LAYERS
    from viewer.renderer import TONEMAPS

    _run_job(app, box_room(64, 128, variant="viewer"))
    start = len(app.renderer.first_draws)
    app.pins.pin_probe(40.5, 30.5)  # a marker on the view, the probe image in the panel
    for view in ("equirect", "perspective"):
        app.camera.set_view(view)
        for name in app.doc.available():
            app.display.set_layer(name)
            app.frame()
        app.display.set_layer("image")
        for tm in TONEMAPS:
            app.display.set_tonemap(tm)
            app.frame()
        app.display.set_tonemap("srgb")
    app.camera.set_view("equirect", zoom=4.0)  # nearest-neighbour texels
    app.frame()
    assert set(app.doc.available()) == set(LAYERS)
    assert app.renderer.first_draws[start:] == []
    app.pins.unpin()


def test_variant_classes_are_what_llvmpipe_compiles_for(egl):
    """The renderer's record tells variants apart as Mesa's llvmpipe does: a texture whose sides
    change power-of-two-ness (or channel count) costs a compile at its first draw; one in the same
    class does not.  In a fresh process with Mesa's shader disk cache off, CPU time of first draws."""
    script = textwrap.dedent("""
        import json, time
        import moderngl, numpy as np
        from viewer.renderer import Display, Frame, Renderer
        from phyir.insert.views import EquirectView
        ctx = moderngl.create_standalone_context(backend="egl")
        r = Renderer(ctx)
        fbo = ctx.framebuffer([ctx.texture((8, 8), 4)])
        def draw(w, h, c):
            tex = r.texture(np.ones((h, w, c), np.float32))
            frame = Frame(tex, (h, w), EquirectView(), Display(kind="scalar" if c == 1 else "hdr"))
            ctx.finish()
            t = time.thread_time()
            r.render(fbo, (0, 0, 8, 8), frame)
            ctx.finish()
            return time.thread_time() - t, len(r.first_draws)
        out = {"renderer": ctx.info["GL_RENDERER"]}
        for name, size in [("first", (4, 2, 3)), ("same class", (16, 8, 3)), ("npot width", (6, 8, 3)),
                           ("npot width again", (12, 4, 3)), ("npot height", (8, 6, 3))]:
            out[name] = draw(*size)
        print(json.dumps(out))
    """)
    env = {**os.environ, "MESA_SHADER_CACHE_DISABLE": "true", "PYOPENGL_PLATFORM": "egl"}
    res = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    if "llvmpipe" not in out.pop("renderer"):
        pytest.skip("not Mesa llvmpipe")
    cpu = {k: v[0] for k, v in out.items()}
    recorded = [v[1] for v in out.values()]
    assert recorded == [1, 1, 2, 2, 3]  # new variants recorded exactly where the class changes
    for new in ("npot width", "npot height"):
        assert cpu[new] > 0.015 and cpu[new] > 5 * max(cpu["same class"], cpu["npot width again"]), cpu


def test_a_real_job_imports_nothing_in_the_worker(egl, tmp_path):
    """A fresh ``phyir-view`` process loads a panorama, runs the shipped model and the re-render:
    the worker thread imports no module (viewer.worker.preload did at start-up), and the heap the
    start-up built is out of the cyclic collector's reach (``gc.freeze``)."""
    from phyir.learn.weights import default_weights_path

    if not default_weights_path().exists():
        pytest.skip("no shipped weights")
    import torch

    from phyir import io

    path = tmp_path / "room.hdr"
    io.save_panorama(box_room(64, 128, variant="viewer").image.float().clamp(min=0), path)
    del torch
    script = textwrap.dedent(f"""
        import gc, json, sys, threading
        imports = []
        def hook(event, args):
            if event == "import" and threading.current_thread().name.startswith("phyir-view job"):
                imports.append(args[0])
        from viewer.app import App
        app = App((320, 200), headless=True, recent=False, threads=1)
        heap = {{"frozen": gc.get_freeze_count(), "collected": len(gc.get_objects(generation=2))}}
        sys.addaudithook(hook)
        app.open({str(path)!r})
        ok = app.wait_idle(120)
        print(json.dumps({{"ok": ok, "error": app.messages.error, "layers": sorted(app.doc.arrays),
                          "imports": imports, **heap}}))
        app.close()
    """)
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "OMP_WAIT_POLICY": "PASSIVE"}
    res = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=180)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["ok"] and out["error"] is None, out
    assert {"depth", "probes", "rerender"} <= set(out["layers"])
    assert out["imports"] == []
    # the start-up heap (torch, imgui, the warm-up) is frozen: a full collection the worker's
    # allocations trigger (it holds the GIL throughout) has only the job's objects to scan
    assert out["frozen"] > 50_000 and out["collected"] < out["frozen"] / 100, out
