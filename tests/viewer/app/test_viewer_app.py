"""The viewer app driven headlessly (EGL, imgui drawn into the canvas) through the same methods the
interface calls; screenshots are checked pixel-wise."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.scenes import box_room  # noqa: E402
from support.viewer import FakeModel, cheap_render  # noqa: E402

from phyir.color import linear_to_srgb  # noqa: E402
from phyir.errors import PhyIRError  # noqa: E402
from phyir.scene import PanoScene  # noqa: E402

pytestmark = pytest.mark.gl

SIZE = (1000, 600)


@pytest.fixture(scope="module")
def app(egl):
    from viewer.app import App

    a = App(SIZE, headless=True, recent=False, render=cheap_render)
    yield a
    a.close()


def test_open_scene_switch_every_layer_and_check_depth_colours(app):
    from viewer.layers import LAYERS
    from viewer.renderer import colormap_lut

    sc = box_room(64, 128, variant="viewer")
    app.worker._render = None  # the real re-rendering (phyir.shading.render, split-sum) this once
    try:
        app.open(sc)
        assert app.wait_idle(120), app.loader.progress
    finally:
        app.worker._render = cheap_render
    assert app.messages.error is None
    assert app.doc.available() == list(LAYERS)
    shots = {}
    for name in app.doc.available():
        app.display.set_layer(name)
        app.frame()
        shots[name] = app.screenshot()
    # layers look different from each other
    x, y, w, h = app.view_rect()
    views = {k: s[y : y + h, x : x + w].astype(np.int32) for k, s in shots.items()}
    names = list(views)
    for a_ in range(len(names)):
        for b_ in range(a_ + 1, len(names)):
            assert np.abs(views[names[a_]] - views[names[b_]]).mean() > 2, (names[a_], names[b_])
    # depth: the colour at chosen pixels decodes (nearest viridis entry) to the depth there
    app.display.set_layer("depth")
    app.display.set_range(1.0, 5.0)
    app.frame()
    img = app.screenshot()
    lut = colormap_lut("viridis") * 255
    H, W = sc.size
    assert app.composer.frame_spec().nearest  # zoomed in: each texel is a flat square
    rng = np.random.default_rng(0)
    ij = rng.integers([2, 2], [H - 2, W - 2], size=(16, 2))
    px, py, _ = app.camera.view.uv_to_screen(ij[:, 1] + 0.5, ij[:, 0] + 0.5, (w, h))
    colours = img[(y + py).astype(int), (x + px).astype(int)].astype(float)
    decoded = np.argmin(((lut[None] - colours[:, None]) ** 2).sum(-1), 1) / 255
    depth = sc.depth[0].numpy()[ij[:, 0], ij[:, 1]]
    want = np.clip((depth - 1.0) / 4.0, 0, 1)
    assert np.abs(decoded - want).max() < 0.01
    order = np.argsort(depth)
    assert np.all(np.diff(decoded[order]) >= -1e-9)  # colour order follows depth order


def test_pinned_probe_panel_shows_the_probe(app):
    sc = box_room(128, 256, variant="viewer")
    app.open(sc)
    assert app.wait_idle(60)
    app.display.set_layer("image")
    pin = app.pins.pin_probe(100.0, 40.0)
    app.pins.set_pin_exposure(0, -2.0)
    app.frame()
    app.frame()
    img = app.screenshot()
    # the probe grid is 4x8 over 128x256: (100, 40) lies between cells; bilinear weights by hand
    gx, gy = 100 * 8 / 256 - 0.5, 40 * 4 / 128 - 0.5
    b0, a0 = int(np.floor(gx)), int(np.floor(gy))
    fx, fy = gx - b0, gy - a0
    P = sc.probes.numpy()
    want = ((1 - fx) * (1 - fy) * P[a0, b0] + fx * (1 - fy) * P[a0, b0 + 1] + (1 - fx) * fy * P[a0 + 1, b0]
            + fx * fy * P[a0 + 1, b0 + 1])
    assert np.allclose(pin.probe, want, rtol=1e-5)
    assert pin.block == (1, 3)
    # its 3D position: on the wall, 5 cm along the normal
    n = sc.normal[:, 40, 100].numpy()
    r = float(sc.depth[0, 40, 100])
    assert np.allclose(pin.point / np.linalg.norm(pin.point), pin.direction)
    assert abs(np.dot(pin.position - pin.point, n) - 0.05) < 0.01 * 0.05 + abs(r) * 1e-3
    x0, y0, x1, y1 = app.gui.side_panel.probe_rects[(0, "pred")]
    h, w = want.shape[1:]
    s = app.surface.scale
    exp_rgb = linear_to_srgb(want * 2.0**-2) * 255
    errs = []
    for i in range(h):
        for j in range(w):
            py = int(y0 * s + (i + 0.5) * (y1 - y0) * s / h)
            px = int(x0 * s + (j + 0.5) * (x1 - x0) * s / w)
            errs.append(np.abs(img[py, px].astype(float) - exp_rgb[:, i, j]).max())
    assert max(errs) <= 2.0, max(errs)
    # the marker ring is drawn around the pin in the view
    vx, vy, vw, vh = app.view_rect()
    mx, my, _ = app.camera.view.uv_to_screen(np.array(100.0), np.array(40.0), (vw, vh))
    ring = img[int(vy + my), int(vx + mx + 9 * app.ui_scale)].astype(float)
    assert np.abs(ring - np.array(pin.colour) * 255).max() < 60
    app.pins.unpin()
    assert not app.pins


def test_ground_truth_probes_side_by_side(app):
    truth = box_room(128, 256, variant="viewer")
    model = FakeModel(truth)
    app.worker._predict = model
    try:
        app.open(truth, compare=True)
        assert app.wait_idle(60)
    finally:
        app.worker._predict = None
    assert model.calls == [("depth", "normal", "albedo", "roughness", "metallic", "probes")]
    assert app.doc.gt is not None and "probes" in app.doc.gt_arrays and "probes" in app.doc.arrays
    pin = app.pins.pin_probe(60.0, 100.0)
    app.frame()
    app.frame()
    assert np.allclose(pin.probe, 1.1 * pin.probe_gt, rtol=1e-5)
    img = app.screenshot().astype(float)
    s = app.surface.scale
    means = {}
    for which in ("pred", "gt"):
        x0, y0, x1, y1 = app.gui.side_panel.probe_rects[(0, which)]
        means[which] = img[int(y0 * s) + 2 : int(y1 * s) - 2, int(x0 * s) + 2 : int(x1 * s) - 2].mean()
    assert means["pred"] > means["gt"] + 0.5  # the prediction is 10% brighter
    app.display.set_source(True)
    assert app.doc.available("gt")[0] == "image"
    app.display.set_source(False)


def test_view_is_redrawn_only_when_its_state_changes(app):
    app.open(box_room(64, 128, variant="viewer"))
    assert app.wait_idle(60)
    app.display.set_layer("image")
    app.frame()
    misses = app.renderer.cache_misses
    first = app.screenshot()
    for _ in range(3):
        app.camera.hover_at(10.0, 10.0)  # the read-out changes, the view doesn't
        app.frame()
    assert app.renderer.cache_misses == misses
    app.display.set_exposure(2.0)
    brighter = app.screenshot()
    assert app.renderer.cache_misses == misses + 1
    x, y, w, h = app.view_rect()
    assert brighter[y : y + h, x : x + w].mean() > first[y : y + h, x : x + w].mean() + 10
    app.display.set_exposure(0.0)


def test_views_and_zoomed_pixel_values(app):
    sc = box_room(64, 128, variant="viewer")
    app.open(sc)
    assert app.wait_idle(60)
    app.display.set_layer("roughness")
    app.camera.set_view("perspective", yaw=0.3, pitch=0.1, fov=80.0)
    app.frame()
    persp = app.screenshot()
    app.camera.set_view("equirect")
    app.camera.fit()
    app.frame()
    eq = app.screenshot()
    x, y, w, h = app.view_rect()
    assert np.abs(persp[y : y + h, x : x + w].astype(int) - eq[y : y + h, x : x + w]).mean() > 5
    # zoom in on one pixel: nearest filtering, and its value printed over it
    app.camera.set_view("equirect", center=(10.5, 20.5), zoom=90.0)
    app.frame()
    zoomed = app.screenshot()
    assert app.composer.frame_spec().nearest
    cx, cy = x + w // 2, y + h // 2
    patch = zoomed[cy - 40 : cy + 40, cx - 40 : cx + 40].reshape(-1, 3)
    colours, counts = np.unique(patch, axis=0, return_counts=True)
    assert counts.max() > 0.5 * len(patch)  # one flat texel ...
    assert (patch.max(1) > 240).sum() > 10   # ... with white text on it
    app.camera.fit()


@pytest.mark.parametrize("kind", ["corrupt", "1x2", "not-2to1", "missing"])
def test_bad_files_show_an_error_and_the_app_keeps_running(app, tmp_path, kind):
    from PIL import Image

    path = tmp_path / {"corrupt": "bad.exr", "1x2": "tiny.png", "not-2to1": "square.png",
                       "missing": "nothere.hdr"}[kind]
    if kind == "corrupt":
        path.write_bytes(b"v/1\x01" + bytes(np.random.default_rng(0).integers(0, 255, 300, dtype=np.uint8)))
    elif kind == "1x2":
        Image.fromarray(np.zeros((1, 2, 3), np.uint8)).save(path)
    elif kind == "not-2to1":
        Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(path)
    app.open(path)
    assert app.wait_idle(30)
    assert app.messages.error is not None and str(path) in app.messages.error
    app.frame()
    img = app.screenshot().astype(int)
    x, y, w, h = app.view_rect()
    banner = img[y : y + 60, x : x + w]
    red = (banner[..., 0] > 110) & (banner[..., 1] < 40) & (banner[..., 2] < 40)
    assert red.sum() > 2000  # the red error banner over the view
    # still alive: a good scene opens and the banner goes
    app.open(box_room(32, 64, variant="viewer"))
    assert app.wait_idle(30) and app.messages.error is None and app.doc.scene is not None


def test_a_file_that_fails_to_open_keeps_the_scene_that_was_open(app, tmp_path):
    good = box_room(32, 64, variant="viewer")
    app.open(good, name="kept")
    assert app.wait_idle(30) and app.messages.error is None
    app.display.set_layer("image")
    before = app.screenshot()
    scene, name = app.doc.scene, app.doc.name
    bad = tmp_path / "broken.exr"
    bad.write_bytes(b"v/1\x01" + bytes(200))
    app.open(bad)
    assert app.wait_idle(30)
    assert app.messages.error is not None and str(bad) in app.messages.error
    assert app.doc.scene is scene and app.doc.name == name == "kept" and app.doc.path is None
    assert any(m.text == "still showing kept" for m in app.messages)
    app.messages.error = None  # the banner dismissed: the same picture as before
    after = app.screenshot()
    x, y, w, h = app.view_rect()
    assert np.abs(after[y : y + h, x : x + w].astype(int) - before[y : y + h, x : x + w]).mean() < 1


def test_export_gltf_writes_the_room_and_the_inserted_objects(app, tmp_path):
    import pygltflib

    app.open(box_room(32, 64, variant="viewer"), name="room")
    assert app.wait_idle(30) and app.messages.error is None
    app.objects.add("sphere")
    app.objects.add("cube", at=(10.0, 24.0))
    app.camera.views["perspective"].update(fov=75.0, yaw=0.5, pitch=-0.2)
    report = app.objects.export_gltf(tmp_path / "room.glb")
    assert report.objects == 2 and (tmp_path / "room_env.exr").is_file()
    doc = pygltflib.GLTF2().load(str(tmp_path / "room.glb"))
    assert len([n for n in doc.nodes if n.name.startswith("object_")]) == 2
    assert abs(doc.cameras[0].perspective.yfov - math.radians(75.0)) < 1e-6
    cam = next(n for n in doc.nodes if n.name == "camera")
    pose = np.array(cam.matrix).reshape(4, 4).T  # column-major
    forward = pose[:3, :3] @ [0, 0, -1]  # where the glTF camera looks: the perspective view's centre
    assert np.allclose(forward, app.camera.views["perspective"].rotation() @ [0, 0, -1])
    assert forward[1] < -0.1 and forward[0] > 0.3  # pitched down, turned toward +x
    assert any(m.text.startswith(f"exported {tmp_path / 'room.glb'}") for m in app.messages)
    for i in range(len(app.objects.objects) - 1, -1, -1):
        app.objects.delete(i)


def test_moving_an_object_around_the_camera_warns_once(app):
    app.open(box_room(32, 64, variant="viewer"), name="room")
    assert app.wait_idle(30)
    obj = app.objects.add("sphere")
    assert app.objects.problem is None
    obj.position = obj.position * 0.01  # its centre 1 cm from the camera's ...
    app.objects.set_scale(0, 0.3)  # ... and an edit: the check runs
    assert app.objects.problem and "camera is inside" in app.objects.problem
    warnings = [m for m in app.messages if "camera is inside" in m.text]
    app.objects.set_visible(0, True)  # still inside: no second warning
    assert len([m for m in app.messages if "camera is inside" in m.text]) == len(warnings) == 1
    app.objects.delete(0)
    assert app.objects.problem is None


def test_single_channel_views_show_one_channel_or_the_luminance_as_grey(app):
    from phyir.color import srgb_to_linear

    app.open(box_room(32, 64, variant="viewer"), name="room")
    assert app.wait_idle(30)
    x, y, w, h = app.view_rect()
    try:
        for layer in ("image", "albedo"):
            app.display.set_layer(layer)
            app.display.set_channel("rgb")
            rgb = app.screenshot()[y : y + h, x : x + w].astype(int)
            inside = rgb.std(-1) > 2  # panorama pixels (coloured), not the grey background
            assert inside.mean() > 0.3
            for k, name in enumerate(("r", "g", "b")):
                app.display.set_channel(name)
                one = app.screenshot()[y : y + h, x : x + w].astype(int)
                assert (one.max(-1) - one.min(-1))[inside].max() <= 1  # grey
                assert np.abs(one[..., 0] - rgb[..., k])[inside].max() <= 1  # the channel's value
            app.display.set_channel("luminance")
            lum = app.screenshot()[y : y + h, x : x + w].astype(float)
            want = linear_to_srgb(srgb_to_linear(rgb / 255.0) @ np.array([0.2126, 0.7152, 0.0722])) * 255
            err = np.abs(lum[..., 1] - want)[inside]  # (want is from 8-bit channels: dark ones are coarse)
            assert np.median(err) < 1 and np.percentile(err, 99) < 4
    finally:
        app.display.set_channel("rgb")
    with pytest.raises(PhyIRError, match="unknown channel"):
        app.display.set_channel("alpha")
    # the side panel's histogram of the shown layer (log2 for HDR), drawn for each kind of layer
    app.gui.side_panel.histogram_open = True
    try:
        for layer in ("image", "albedo", "depth", "normal"):
            app.display.set_layer(layer)
            app.frame()
            want = "normal" if layer == "normal" else layer
            side = app.gui.side_panel
            assert side._hist_key[1] == want and (side._hist is None) == (layer == "normal")
        app.display.set_layer("image")
        app.frame()
        counts, lo, hi, unit = app.gui.side_panel._hist
        assert unit.startswith("log2") and counts.sum() > 0.99 * np.prod(app.doc.size) and lo < hi
    finally:
        app.gui.side_panel.histogram_open = None


def test_a_watched_file_is_reloaded_when_it_changes_on_disk(app, tmp_path):
    import os

    from phyir.io import save_scene

    path = tmp_path / "room.exr"
    room = box_room(32, 64, variant="viewer")
    save_scene(room, path)
    app.open(path)
    assert app.wait_idle(30) and app.messages.error is None
    app.images.watch = True
    try:
        assert not app.images.check_file_changed(now=1e9)  # unchanged: nothing to do
        brighter = PanoScene(image=room.image * 4, depth=room.depth, normal=room.normal, albedo=room.albedo,
                             roughness=room.roughness, metallic=room.metallic, probes=room.probes)
        save_scene(brighter, path)
        st = os.stat(path)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a new time even on coarse clocks
        assert not app.images.check_file_changed(now=1e9 + 0.5)  # checked at most once a second
        assert app.images.check_file_changed(now=1e9 + 2)
        assert app.wait_idle(30) and app.messages.error is None
        assert np.allclose(app.doc.arrays["image"], brighter.image.permute(1, 2, 0).numpy())
        assert any("changed on disk: reloading" in m.text for m in app.messages)
        assert not app.images.check_file_changed(now=1e9 + 4)  # the reloaded file is the new reference
    finally:
        app.images.watch = False
    app.open(box_room(32, 64, variant="viewer"))
    assert app.wait_idle(30)
    with pytest.raises(PhyIRError, match="nothing to reload"):
        app.images.reload()


def test_layers_in_the_file_show_at_once_and_are_not_recomputed(app):
    truth = box_room(64, 128, variant="viewer")
    partial = PanoScene(image=truth.image, depth=truth.depth, normal=truth.normal)
    model = FakeModel(truth, steps=30)
    app.worker._predict = model
    try:
        app.open(partial)
        assert model.started.wait(30)
        app.frame()
        assert app.loader.busy and {"image", "depth", "normal"} <= set(app.doc.available())
        assert "albedo" not in app.doc.available()
        assert app.wait_idle(60)
    finally:
        app.worker._predict = None
    assert model.calls == [("albedo", "roughness", "metallic", "probes")]
    assert np.array_equal(app.doc.arrays["depth"][..., 0], truth.depth[0].numpy())
    assert {"albedo", "probes"} <= set(app.doc.available())


def test_model_failure_is_shown_and_layers_kept(app):
    truth = box_room(64, 128, variant="viewer")
    model = FakeModel(truth, fail=True)
    app.worker._predict = model
    try:
        app.open(PanoScene(image=truth.image, depth=truth.depth))
        assert app.wait_idle(30)
    finally:
        app.worker._predict = None
    assert "the network exploded" in app.messages.error and "model" in app.messages.error
    assert app.doc.available() == ["image", "depth"]
    app.display.set_layer("depth")
    app.frame()  # still draws


def test_opening_another_file_cancels_the_running_job(app):
    truth = box_room(64, 128, variant="viewer")
    slow = FakeModel(truth, steps=400)
    app.worker._predict = slow
    try:
        app.open(PanoScene(image=truth.image))
        assert slow.started.wait(30)
        app.open(box_room(32, 64, variant="viewer"))  # complete scene: no model needed
        assert app.wait_idle(30)
    finally:
        app.worker._predict = None
    assert app.doc.size == (32, 64) and app.messages.error is None
    time.sleep(0.2)
    done = slow.steps_done
    assert done < 100  # the cancelled model stopped at its next progress report
    time.sleep(0.2)
    assert slow.steps_done == done
    assert app.poll() is False  # nothing from the cancelled job arrives


def test_ui_keeps_drawing_during_inference(app, capsys):
    """Longest frame while a CPU-heavy model runs in the worker (reported, loosely bounded)."""
    truth = box_room(64, 128, variant="viewer")
    model = FakeModel(truth, steps=10, busy=0.25)
    app.worker._predict = model
    try:
        app.open(PanoScene(image=truth.image))
        assert app.wait_idle(120)
    finally:
        app.worker._predict = None
    assert app.loader.job_frames >= 5
    x, y, w, h = app.view_rect()
    with capsys.disabled():
        print(f"\n[viewer] {app.loader.job_frames} frames during fake inference "
              f"({app.doc.timings.get('job', 0):.1f} s), longest {1000 * app.loader.job_max_frame:.0f} ms "
              f"(window {SIZE[0]}x{SIZE[1]}, view {w}x{h}, headless EGL)")
    assert app.loader.job_max_frame < 1.0


def test_high_dpi_layout_scales(egl, tmp_path):
    from viewer.app import App

    a = App((500, 300), headless=True, scale=2.0, recent=False)
    try:
        a.open(box_room(32, 64, variant="viewer"))
        assert a.wait_idle(30)
        a.frame()
        img = a.screenshot()
        assert img.shape == (600, 1000, 3)
        x, y, w, h = a.view_rect()
        assert x == 0 and y > 30 and w < 1000 - 2 * 300 and h > 400
        uv = a.camera.screen_to_uv(w / 2, h / 2)
        assert abs(uv[0] - 32) < 1 and abs(uv[1] - 16) < 1
    finally:
        a.close()


def test_recent_files_are_kept_atomically(tmp_path):
    from viewer.recent import RecentFiles

    p = tmp_path / "cfg" / "recent.json"
    r = RecentFiles(p, limit=3)
    for k in range(5):
        r.add(tmp_path / f"f{k}.hdr")
    assert RecentFiles(p).files == [str(tmp_path / f"f{k}.hdr") for k in (4, 3, 2)]
    r.add(tmp_path / "f2.hdr")
    assert RecentFiles(p).files[0] == str(tmp_path / "f2.hdr")
    assert [f.name for f in p.parent.iterdir()] == ["recent.json"]  # no temp files left
    p.write_text("{not json")
    broken = RecentFiles(p)
    assert broken.files == [] and "unreadable" in broken.problem
