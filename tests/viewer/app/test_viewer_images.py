"""Several images open at once (tev-style): switching keeps each image's layers, the model runs for the
image shown (and the reference), and the comparison with a reference drawn by the App matches
viewer.compare's numpy formulas."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from support.scenes import box_room
from support.viewer import FakeModel, cheap_render, press

from phyir.errors import PhyIRError
from phyir.scene import PanoScene

pytestmark = pytest.mark.gl

H, W = 32, 64


def images() -> tuple[PanoScene, list[PanoScene]]:
    """The box room and three panoramas of it, each with its own brightness and a gradient."""
    truth = box_room(H, W, variant="viewer")
    ramp = (0.5 + np.linspace(0, 1, W, dtype=np.float32))[None, None]
    return truth, [PanoScene(image=truth.image * k * torch.from_numpy(ramp ** p), meta={"name": f"pano{k}"})
                   for k, p in ((1.0, 0), (2.0, 1), (0.5, 2))]


@pytest.fixture(scope="module")
def model():
    return FakeModel(images()[0], steps=1)


@pytest.fixture()
def app(egl, model):
    from viewer.app import App

    model.calls.clear()
    a = App((W, H), headless=True, ui=False, recent=False, predict=model, render=cheap_render)
    yield a
    a.close()


def released(tex) -> bool:
    try:
        return tex.glo in (0, -1) or type(tex.mglo).__name__ == "InvalidObject"
    except Exception:  # noqa: BLE001 - moderngl versions differ in what a released object says
        return True


def view(app) -> np.ndarray:
    return app.screenshot().astype(np.float64)


def test_images_switch_keep_their_layers_and_the_model_runs_for_the_one_shown(app, model):
    _, (a, b, c) = images()
    app.open(a)
    app.images.queue(b)
    app.images.queue(c)
    assert app.wait_idle(60)
    assert [app.images.label(e) for e in app.images] == ["pano1.0", "pano2.0", "pano0.5"]
    assert app.images.current == 0 and all(e.loaded for e in app.images)
    assert len(model.calls) == 1 and "depth" in app.doc.arrays  # only the image shown was modelled
    shot_a = view(app)
    app.images.next()
    doc = app.doc
    assert doc.name == "pano2.0" and torch.equal(doc.scene.image, b.image) and "depth" not in doc.arrays
    assert app.wait_idle(60) and len(model.calls) == 2 and "depth" in app.doc.arrays  # modelled once shown
    shot_b = view(app)
    app.images.next(-1)
    assert app.doc.name == "pano1.0" and np.array_equal(view(app), shot_a)  # its layers were kept
    app.images.select(2)
    assert app.wait_idle(60) and len(model.calls) == 3
    app.images.select(0)
    assert app.wait_idle(60) and len(model.calls) == 3  # nothing is computed twice
    # b = a * 2 * ramp (ramp 0.5 .. 1.5 over the columns): the view shows b's own pixels
    from phyir.color import srgb_to_linear

    lin_a, lin_b = srgb_to_linear(shot_a / 255), srgb_to_linear(shot_b / 255)
    ok = (lin_a > 0.02) & (lin_b < 0.98) & (lin_b > 0.02)
    want = np.broadcast_to(2 * (0.5 + np.linspace(0, 1, W))[None, :, None], ok.shape)
    assert ok.mean() > 0.3 and np.median(np.abs(lin_b[ok] / lin_a[ok] / want[ok] - 1)) < 0.03
    with pytest.raises(PhyIRError, match="no image 4"):
        app.images.select(3)


def test_the_view_is_kept_across_images_of_one_size_and_closing_frees_them(app):
    _, (a, b, _) = images()
    app.open(a)
    app.images.add(b)
    assert app.wait_idle(60) and app.images.current == 1
    app.frame()
    app.camera.views["equirect"].zoom_about(2.0, app.view_size())
    zoom = app.camera.view.zoom
    app.images.select(0)
    app.frame()
    assert app.camera.view.zoom == zoom
    assert app.images.add(a) is app.images[0] and len(app.images) == 2  # already open: shown, not added
    closed = app.images[1]
    tex = list(closed.doc.layer_textures.values())
    assert tex and all(t.glo > 0 for t in tex)
    app.images.close(1)
    assert len(app.images) == 1 and app.images.current == 0 and app.doc.name == "pano1.0"
    assert closed.doc.layer_textures == {} and all(released(t) for t in tex)


def test_a_file_that_fails_to_open_is_dropped_and_the_shown_image_stays(app, tmp_path):
    _, (a, _, _) = images()
    app.open(a)
    assert app.wait_idle(60)
    bad = tmp_path / "broken.hdr"
    bad.write_bytes(b"not an image")
    app.images.add(bad)
    assert app.wait_idle(60)
    assert len(app.images) == 1 and app.doc.name == "pano1.0" and "broken.hdr" in app.messages.error


def lut_colours(name: str, t: np.ndarray) -> np.ndarray:
    from viewer.renderer import colormap_lut

    lut = colormap_lut(name)
    x = np.clip(t, 0, 1) * 255
    return np.stack([np.interp(x, np.arange(256), lut[:, k]) for k in range(3)], -1) * 255


@pytest.mark.parametrize("mode", ["diff", "reldiff", "sqerr"])
def test_comparison_with_the_reference_matches_numpy(app, mode):
    from viewer import compare

    _, (a, b, _) = images()
    app.open(a)
    app.images.queue(b)
    assert app.wait_idle(60)
    app.images.set_reference(1)
    assert app.wait_idle(60)
    for layer, channel in (("image", "rgb"), ("image", "luminance"), ("depth", "rgb"), ("normal", "rgb")):
        app.display.set_layer(layer)
        app.display.set_channel(channel)
        app.comparison.set_mode(mode)
        got = view(app)
        values = compare.compare_values(app.doc.arrays[layer], app.comparison.reference_arrays()[layer], mode,
                                        app.display.display().kind, channel)
        lo, hi = compare.colour_range(mode, compare.auto_extent(values))
        assert app.composer.frame_spec().compare.range == pytest.approx((lo, hi))
        want = lut_colours(compare.COLORMAP[mode], (values - lo) / (hi - lo))
        assert np.abs(got - want).max() <= 1.5, (layer, channel)
        assert values.std() > 0 or layer in ("depth", "normal")  # the images differ
    app.display.set_channel("rgb")
    app.comparison.set_extent(0.25)
    app.display.set_layer("image")
    values = compare.compare_values(app.doc.arrays["image"], app.comparison.reference_arrays()["image"], mode)
    lo, hi = compare.colour_range(mode, 0.25)
    assert np.abs(view(app) - lut_colours(compare.COLORMAP[mode], (values - lo) / (hi - lo))).max() <= 1.5


def test_split_view_shows_the_reference_right_of_the_divide(app):
    _, (a, b, _) = images()
    app.open(a)
    app.images.queue(b)
    assert app.wait_idle(60)
    alone_a = view(app)
    app.images.select(1)
    assert app.wait_idle(60)
    alone_b = view(app)
    app.images.select(0)
    with pytest.raises(PhyIRError, match="no reference"):
        app.comparison.set_mode("split")
    app.images.set_reference(1)
    app.comparison.set_mode("split")
    app.comparison.set_split(0.25)
    got = view(app)
    col = W // 4
    assert np.array_equal(got[:, :col], alone_a[:, :col])
    assert np.array_equal(got[:, col + 1 :], alone_b[:, col + 1 :])
    assert np.abs(alone_a - alone_b)[:, col + 1 :].mean() > 5  # the halves differ: the test could fail
    app.images.close(1)
    assert app.images.reference is None and app.comparison.mode is None and np.array_equal(view(app), alone_a)


@pytest.fixture()
def ui_app(egl, model):
    from viewer.app import App

    a = App((900, 500), headless=True, recent=False, predict=model, render=cheap_render)
    yield a
    a.close()


def test_keys_switch_images_choose_the_reference_and_the_mode_and_the_divide_drags(ui_app):
    from imgui_bundle import imgui

    app, K = ui_app, imgui.Key
    _, (a, b, c) = images()
    app.open(a)
    app.images.queue(b)
    app.images.queue(c)
    assert app.wait_idle(60)
    press(app, K.right_bracket)
    assert app.images.current == 1
    press(app, K.page_down)
    assert app.images.current == 2
    press(app, K.right_bracket)
    assert app.images.current == 0  # wraps around
    press(app, K.left_bracket)
    assert app.images.current == 2
    press(app, K.d)
    # (the worker may post its own message meanwhile: the model ran for the image now shown)
    assert app.comparison.mode is None and any("no reference" in m.text for m in list(app.messages)[-3:])
    press(app, K.r, shift=True)
    assert app.images.reference is app.images[2] and app.display.hdr.exposure == 0.0
    press(app, K.page_up)
    assert app.images.current == 1
    app.display.set_exposure(1.0)
    for mode in ("diff", "reldiff", "sqerr", "split"):
        press(app, K.d)
        assert app.comparison.mode == mode
    assert app.display.hdr.exposure == 1.0  # Shift+R did not reset it; R still does
    press(app, K.r)
    assert app.display.hdr.exposure == 0.0
    # drag the split view's divide from the middle to a quarter of the view
    x, y, w, h = app.view_rect()
    io = app.gui.io
    io.add_mouse_pos_event(x + 0.5 * w, y + h / 2)
    app.frame()
    io.add_mouse_button_event(0, True)
    app.frame()
    for f in (0.45, 0.35, 0.25):
        io.add_mouse_pos_event(x + f * w, y + h / 2)
        app.frame()
    io.add_mouse_button_event(0, False)
    app.frame()
    assert app.comparison.split == pytest.approx(0.25, abs=2 / w) and not app.pins  # the drag pinned no probe
    press(app, K.d, shift=True)
    assert app.comparison.mode == "sqerr"
    press(app, K.d)
    press(app, K.d)
    assert app.comparison.mode is None


def test_the_image_shown_gets_the_worker_first_and_keeps_its_probes(egl):
    from viewer.app import App

    truth, (a, b, c) = images()
    slow = FakeModel(truth, steps=25)  # 0.5 s: still running when the next image is shown
    app = App((W, H), headless=True, ui=False, recent=False, predict=slow, render=cheap_render)
    try:
        app.open(a)
        app.images.queue(b)
        assert slow.started.wait(30)
        app.images.add(c)  # a's model gives way: a is neither shown nor the reference
        assert app.images.job.entry is app.images[2] and app.images.job.model
        assert app.wait_idle(60)
        assert [(e.loaded, e.modelled) for e in app.images] == [(True, False), (True, False), (True, True)]
        app.images.select(1)  # b was read only: its model runs now; a probe pinned meanwhile stays
        app.pins.pin_probe(10.5, 20.5)
        assert app.wait_idle(60) and app.images[1].modelled and "depth" in app.doc.arrays
        assert [(p.u, p.v) for p in app.pins] == [(10.5, 20.5)] and app.pins[0].point is not None
        app.images.select(0)
        assert app.wait_idle(60) and app.images[0].modelled
        assert len(slow.calls) == 4  # a (given way), c, b, a again
    finally:
        app.close()
