"""Inserted objects in the viewer app, headless (EGL), through the methods its panel and mouse call."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.scenes import FLOOR_Y  # noqa: E402
from support.viewer import box_room_app  # noqa: E402

from phyir import pano  # noqa: E402

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def app(egl):
    a = box_room_app()
    yield a
    a.close()


def view_pixels(app) -> np.ndarray:
    x, y, w, h = app.view_rect()
    return app.screenshot()[y:y + h, x:x + w].astype(np.int32)


def screen_of(app, point: np.ndarray) -> tuple[float, float]:
    H, W = app.doc.size
    u, v, _ = pano.points_to_uv(torch.as_tensor(point), H, W)
    x, y, _ = app.camera.view.uv_to_screen(np.array(float(u)), np.array(float(v)), app.view_size(),
                                           app.doc.size)
    return float(x), float(y)


def test_add_drag_layers_delete_and_export(app, tmp_path):
    from phyir.insert.objects import PRESETS

    panel = app.objects
    before = view_pixels(app)
    obj = panel.add("sphere", PRESETS["matte-silver"], 0.25, at=(40.5, 50.5))
    with_obj = view_pixels(app)
    cx, cy = screen_of(app, obj.bounding_sphere()[0])
    changed = np.abs(with_obj - before).sum(-1) > 0
    assert changed[int(cy), int(cx)]  # the object's centre pixel shows the object
    ys, xs = np.nonzero(changed)
    assert np.hypot(xs - cx, ys - cy).max() < 0.3 * app.view_size()[0]  # only around it
    # drag it sideways by 40 screen pixels: it slides over the floor, the picture follows
    assert panel.begin_drag(cx, cy)
    for k in range(1, 5):
        panel.drag_to(cx + 10 * k, cy)
        app.frame()
    panel.end_drag()
    base = obj.position - obj.base_offset() * (obj.rotation @ np.array([0.0, 1.0, 0.0]))
    assert abs(base[1] - FLOOR_Y) < 0.01
    cx2, _ = screen_of(app, obj.bounding_sphere()[0])
    assert 30 < cx2 - cx < 50
    moved = view_pixels(app)
    assert (np.abs(moved - with_obj).sum(-1) > 0)[int(cy), int(cx2)]
    # objects are drawn over the image layer only
    app.display.set_layer("depth")
    depth_with = view_pixels(app)
    panel.set_visible(0, False)
    assert np.array_equal(view_pixels(app), depth_with)
    panel.set_visible(0, True)
    app.display.set_layer("image")
    # export: EXR passes and a PNG
    files = panel.export(str(tmp_path / "room_insert.exr"))
    assert [f.rsplit(".", 1)[1] for f in files] == ["exr", "png"]
    # duplicate, then delete both: the panorama is back, pixel for pixel
    panel.duplicate(0)
    assert len(panel.objects) == 2
    panel.delete(1)
    panel.delete(0)
    assert np.array_equal(view_pixels(app), before)


def test_view_at_takes_fractions_and_warns_on_the_ceiling(app):
    """phyir-view --object ... --at as phyir insert takes it: pixels or fractions of the size, and a
    point on the ceiling hangs the object there with a warning (not an error)."""
    from phyir.commands import options
    from viewer.app.cli_objects import ObjectSpec, add_objects

    panel, point = app.objects, options.image_point(1e6)
    add_objects(app.objects, [ObjectSpec("sphere", at=point("0.3125,0.78125")),
                      ObjectSpec("sphere", at=(39.5, 49.5))])
    assert np.allclose(panel.objects[0].position, panel.objects[1].position)  # (128x64: 40, 50)
    assert not any("ceiling" in m.text for m in app.messages)
    add_objects(app.objects, [ObjectSpec("sphere", at=point("0.5,0.05"))])
    last = app.messages[-1]
    assert last.level == "warning" and "--at 0.5,0.05: the point is on the ceiling" in last.text
    assert panel.objects[-1].support[1][1] < -0.5
    while panel.objects:
        panel.delete(0)


def test_click_to_drop_takes_the_click_from_the_probe_pin(app):
    from phyir.insert.objects import PRESETS

    panel, ui = app.objects, app.gui.objects_panel
    panel.add("cube", PRESETS["diffuse"], 0.2, at=(64.5, 50.5))
    ui.drop_mode = True
    pins = len(app.pins)
    x, y = screen_of(app, np.array([0.8, FLOOR_Y, -1.5]))
    took = ui.view_mouse(True, True, True, False, False, x, y)
    assert took and len(app.pins) == pins
    obj = panel.objects[-1]
    np.testing.assert_allclose(obj.support[0], [0.8, FLOOR_Y, -1.5], atol=0.05)
    ui.drop_mode = False
    panel.delete(len(panel.objects) - 1)


def test_panel_and_gizmo_build_in_a_frame(app, monkeypatch):
    """The Objects panel and the gizmo go through imgui in a real frame without errors."""
    from imgui_bundle import imgui

    from phyir.insert.objects import PRESETS

    panel = app.objects
    panel.add("cylinder", PRESETS["mirror-silver"], 0.2, at=(50.5, 50.5))
    app.camera.set_view("perspective", yaw=0.0, pitch=-0.5)
    original = app.gui.build
    calls = []

    def build():
        original()
        imgui.begin("objects test")
        app.gui.objects_panel.draw()
        x, y, w, h = app.view_rect()
        s = app.gui.fb_scale
        calls.append(app.gui.objects_panel.gizmo((x / s, y / s, w / s, h / s), (w, h)))
        imgui.end()

    monkeypatch.setattr(app.gui, "build", build)
    app.frame()
    app.frame()
    assert len(calls) == 2
    app.camera.set_view("equirect")
    panel.delete(len(panel.objects) - 1)


def _steps(img: np.ndarray) -> np.ndarray:
    """Per pixel, the largest grey-level step to its right or lower neighbour."""
    grey = img.astype(float).mean(-1)
    out = np.zeros_like(grey)
    out[:, :-1] = np.abs(np.diff(grey, axis=1))
    out[:-1] = np.maximum(out[:-1], np.abs(np.diff(grey, axis=0)))
    return out


@pytest.mark.parametrize("view", ["equirect", "perspective"])
def test_dragging_draws_receivers_coarse_under_sharp_objects_over_the_sharp_layer(app, view):
    """While an object moves the receivers run at DRAGGING.composite_scale (1/4) of the region's
    resolution and composite_up.frag puts them, and the objects at full resolution, over the layer:
    away from the objects and their shadows the picture is the full-quality one bit for bit, near
    them within the draft's coarseness, and the objects' outlines stay sharp."""
    from phyir.insert.objects import PRESETS

    panel = app.objects
    app.camera.set_view(view)
    if view == "perspective":  # aimed at where the object will stand
        H, W = app.doc.size
        d = pano.uv_to_dir(torch.tensor(40.5), torch.tensor(50.5), H, W)
        lon, lat = pano.dir_to_lonlat(d)
        app.camera.views["perspective"].update(yaw=float(lon), pitch=float(lat))
    bare = view_pixels(app)
    panel.add("sphere", PRESETS["diffuse"], 0.3, at=(40.5, 50.5))
    try:
        still = view_pixels(app)
        panel.hook.dragging = True
        draft = view_pixels(app)
        rect = panel.hook.last_rect
        keep = panel.insertion._draft[1]  # the draft path ran, at a quarter of the resolution
        assert keep.size == tuple(-(-n // 4) for n in rect[2:])
    finally:
        panel.hook.dragging = False
        panel.delete(len(panel.objects) - 1)
        app.camera.set_view("equirect")
    diff = np.abs(draft - still).max(-1)
    untouched = (np.abs(still - bare).max(-1) == 0) & (np.abs(draft - bare).max(-1) == 0)
    assert untouched.mean() > 0.3 and diff[untouched].max() == 0
    changed = np.abs(still - bare).max(-1) > 8
    assert changed.sum() > 100
    assert np.median(diff[changed]) < 12 and diff.mean() < 2  # the same objects and shadows, coarser
    # outlines: where the objects make the still frame step by > 10 between neighbours, the draft
    # steps there too (objects drawn at 1/4 resolution: median difference 20 in the equirect view)
    edge = (_steps(still) > 10) & (_steps(bare) < 3)
    assert edge.sum() > 20 and np.median(diff[edge]) < 8


@pytest.mark.parametrize("view", ["equirect", "perspective"])
def test_a_draft_frame_skips_the_display_pass_where_the_objects_redraw_the_view(app, view):
    """While dragging, the draft composite draws its region whole, so the renderer's display pass
    skips it (``InsertionPass.overwrites``): the picture is the same pixel for pixel as with the
    display pass drawn everywhere; still frames draw it everywhere."""
    from phyir.insert.objects import PRESETS

    panel = app.objects
    app.camera.set_view(view)
    if view == "perspective":
        app.camera.views["perspective"].update(yaw=0.0, pitch=-0.4)
    panel.add("sphere", PRESETS["diffuse"], 0.3, at=(40.5, 50.5))
    w, h = app.view_size()
    try:
        view_pixels(app)
        assert app.renderer.display_pixels == w * h  # a still frame: everywhere
        panel.hook.dragging = True
        skipped = view_pixels(app)
        rw, rh = panel.hook.last_rect[2:]
        assert 0 < rw * rh and app.renderer.display_pixels == w * h - rw * rh
        panel.hook.overwrites = lambda renderer, frame: None  # the display pass everywhere
        everywhere = view_pixels(app)
        assert app.renderer.display_pixels == w * h
    finally:
        del panel.hook.overwrites
        panel.hook.dragging = False
        panel.delete(len(panel.objects) - 1)
        app.camera.set_view("equirect")
    assert np.abs(skipped - everywhere).max() == 0


def test_strips_around_a_hole_cover_the_rest_once():
    """renderer.strips_around (the display pass around the draft's region, the draft's pass around
    the objects' outline): every pixel of the rectangle outside the hole exactly once."""
    from viewer.renderer import strips_around

    for hole in [(13, 9, 20, 7), (10, 5, 60, 40), (10, 20, 5, 25), (40, 5, 30, 3)]:
        cover = np.zeros((50, 80), int)
        for x, y, w, h in strips_around((10, 5, 60, 40), hole):
            cover[y:y + h, x:x + w] += 1
        want = np.zeros((50, 80), int)
        want[5:45, 10:70] = 1
        hx, hy, hw, hh = hole
        want[hy:hy + hh, hx:hx + hw] = 0
        assert np.array_equal(cover, want)


def test_a_dragging_frame_that_draws_an_impostor_keeps_the_last_receivers(app):
    """While dragging, the moved object's impostor is drawn every other frame and the draft's
    receivers on the frames in between (InsertionPass.receivers_every): each frame pays for one of
    the two, and the shadows are never more than a frame old."""
    from phyir.insert.objects import PRESETS

    panel, hook = app.objects, app.objects.hook
    app.camera.set_view("perspective")
    H, W = app.doc.size
    d = pano.uv_to_dir(torch.tensor(40.5), torch.tensor(50.5), H, W)
    lon, lat = pano.dir_to_lonlat(d)
    fov = app.camera.views["perspective"].fov
    # narrow: the objects' reach covers the view, so the draft's region stays the same
    app.camera.views["perspective"].update(fov=25.0, yaw=float(lon), pitch=float(lat))
    obj = panel.add("sphere", PRESETS["diffuse"], 0.3, at=(40.5, 50.5))
    cx, cy = screen_of(app, obj.bounding_sphere()[0])
    drawn, impostors, rects = [], [], []
    try:
        assert panel.begin_drag(cx, cy)
        for k in range(1, 11):
            panel.drag_to(cx + 2 * k, cy)
            before = hook.receivers_drawn
            app.frame()
            drawn.append(hook.receivers_drawn - before)
            impostors.append(panel.insertion.drawn_faces["impostor"] > 0)
            rects.append(hook.last_rect)
        panel.end_drag()
    finally:
        panel.delete(len(panel.objects) - 1)
        app.camera.views["perspective"].update(fov=fov)
        app.camera.set_view("equirect")
    assert len(set(rects)) == 1
    assert drawn.count(0) >= 3 and "00" not in "".join(map(str, drawn))
    assert all(imp for imp, n in zip(impostors, drawn) if n == 0)  # kept only when the impostor was drawn
