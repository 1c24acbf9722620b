"""Stand-ins for the viewer tests: a fake model (``phyir.predict``) and a cheap re-render
(``phyir.shading.render.render_scene``), both driven through the app's worker."""

from __future__ import annotations

import threading
import time

import torch

from phyir.scene import PanoScene


def box_room_app(size: tuple[int, int] = (900, 520)):
    """A headless viewer App (cheap re-render) with the 64x128 test box room open and idle; closed
    again if opening fails.  Call viewer.gl.window.prefer_egl() before (at the test module's top)."""
    from support.scenes import box_room
    from viewer.app import App

    app = App(size, headless=True, recent=False, render=cheap_render)
    try:
        app.open(box_room(64, 128))
        assert app.wait_idle(60) and app.messages.error is None
    except BaseException:
        app.close()
        raise
    return app


def cheap_render(scene: PanoScene) -> dict[str, torch.Tensor]:
    """Stands in for phyir.shading.render.render_scene where its cost (seconds on 2 cores) buys nothing."""
    diffuse = scene.albedo * scene.image.mean(0, keepdim=True)
    specular = 0.1 * scene.roughness.expand(3, -1, -1) * scene.image
    return {"diffuse": diffuse, "specular": specular, "image": diffuse + specular}


class FakeModel:
    """Stands in for phyir.predict: returns the box room's layers after ``steps`` steps (each
    ``busy`` seconds of real torch convolutions, else a short sleep), reporting progress and
    honouring cancel; records what it was asked for."""

    def __init__(self, truth: PanoScene, steps: int = 4, busy: float = 0.0, fail: bool = False):
        self.truth, self.steps, self.busy, self.fail = truth, steps, busy, fail
        self.calls: list[tuple[str, ...]] = []
        self.started = threading.Event()
        self.steps_done = 0

    def __call__(self, scene, *, outputs, progress, cancel, **kw):
        self.calls.append(tuple(outputs))
        self.started.set()
        x = torch.randn(1, 16, 128, 256)
        conv = torch.nn.Conv2d(16, 16, 3, padding=1)
        for k in range(self.steps):
            end = time.perf_counter() + self.busy
            while time.perf_counter() < end:
                with torch.no_grad():
                    x = torch.tanh(conv(x))
            if not self.busy:
                time.sleep(0.02)
            self.steps_done += 1
            progress(k / self.steps, f"step {k + 1}/{self.steps}")
            if cancel.is_set():
                raise RuntimeError("cancelled")
        if self.fail:
            raise RuntimeError("the network exploded")
        out = {n: getattr(self.truth, n) * (1.1 if n == "probes" else 1.0) for n in outputs}
        return PanoScene(image=scene.image, **out)


def press(app, key, shift: bool = False) -> None:
    """A key press (and release) through imgui's input queue, a frame each, as a window would."""
    from imgui_bundle import imgui

    io = app.gui.io
    if shift:
        io.add_key_event(imgui.Key.mod_shift, True)
    io.add_key_event(key, True)
    app.frame()
    io.add_key_event(key, False)
    if shift:
        io.add_key_event(imgui.Key.mod_shift, False)
    app.frame()
