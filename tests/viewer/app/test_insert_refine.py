"""After a drag (or any change) the viewer builds the objects' full-quality picture a slice per frame
while the draft stays on screen (viewer.refinement), and shows it once complete: the same pixels as
the frame drawn in one piece.  Headless (EGL), through the methods the panel and the mouse call;
work is counted in slices, not timed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.viewer import box_room_app  # noqa: E402

from phyir import pano  # noqa: E402

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def app(egl):
    from phyir.insert.objects import PRESETS

    a = box_room_app()
    a.objects.add("sphere", PRESETS["matte-silver"], 0.3, at=(40.5, 50.5))
    a.objects.add("cube", PRESETS["diffuse"], 0.2, at=(52.5, 50.5))
    H, W = a.doc.size
    lon, lat = pano.dir_to_lonlat(pano.uv_to_dir(torch.tensor(46.5), torch.tensor(50.5), H, W))
    a.camera.set_view("perspective")
    a.camera.views["perspective"].update(yaw=float(lon), pitch=float(lat))
    a.objects.hook.refinement.budget_s = 0.0  # the smallest strips: many slices
    yield a
    a.close()


def screen_of(app, point: np.ndarray) -> tuple[float, float]:
    H, W = app.doc.size
    u, v, _ = pano.points_to_uv(torch.as_tensor(point), H, W)
    x, y, _ = app.camera.view.uv_to_screen(np.array(float(u)), np.array(float(v)), app.view_size(),
                                           app.doc.size)
    return float(x), float(y)


def drag(app, index: int, dx: float) -> None:
    panel = app.objects
    cx, cy = screen_of(app, panel.objects[index].bounding_sphere()[0])
    assert panel.begin_drag(cx, cy)
    for k in range(1, 4):
        panel.drag_to(cx + dx * k / 3, cy)
        app.frame()
    panel.end_drag()


def refine(app, limit: int = 2000) -> list[int]:
    """Frames until the picture is complete: the slices each drew."""
    ref = app.objects.hook.refinement
    per_frame = []
    for _ in range(limit):
        before, starts = len(ref.slices), ref.starts
        app.frame()
        per_frame.append(len(ref.slices) - (before if ref.starts == starts else 0))
        if not app.objects.refining():
            return per_frame
        ref.twin.wait_lighting()  # (the worker's slices come in order, not in time)
    raise AssertionError("the refinement did not finish")


def view_pixels(app) -> np.ndarray:
    x, y, w, h = app.view_rect()
    return app.screenshot()[y:y + h, x:x + w].astype(np.int32)


def same_picture(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal up to a level in a few pixels: the objects' impostor tiles are looked up at their
    texel rectangle divided by the atlas's size, and an atlas only grows, so the pass's atlas and
    the refinement's may differ in size (each drew other layouts before): the texture coordinates
    then differ in their last bits.  With atlases of one size the pictures are equal bit for bit
    (the first test's)."""
    diff = np.abs(a - b).max(-1)
    return diff.max() <= 1 and (diff > 0).mean() < 1e-3


def in_one_piece(app) -> np.ndarray:
    """The view drawn at full quality in one frame (the pass without refinement)."""
    hook = app.objects.hook
    hook.progressive = False
    try:
        return view_pixels(app)
    finally:
        hook.progressive = True


def test_after_a_release_the_picture_is_built_a_slice_a_frame_and_is_the_one_piece_frame(app):
    ref, hook = app.objects.hook.refinement, app.objects.hook
    refine(app)
    draft_before = app.renderer.cache_misses
    drag(app, 0, 12)
    starts = ref.starts
    per_frame = refine(app)
    assert ref.starts == starts + 1 and ref.done
    assert max(per_frame) == 1  # never more than one slice in a frame
    kinds = set(ref.slices)
    assert {"impostor", "shadow", "composite"} <= kinds
    assert ref.slices.count("composite") > 3 and ref.slices.count("impostor") > 1  # in strips
    assert len(per_frame) > 10
    # the draft was drawn once and copied while the picture was built, then the picture once
    assert app.renderer.cache_misses - draft_before <= 2 + 3  # (+ the drag's frames: not cached)
    shown = view_pixels(app)
    assert len(ref.slices) == sum(per_frame)  # the screenshot found it complete
    assert hook.last_rect == ref.rect
    assert np.abs(shown - in_one_piece(app)).max() == 0  # (the atlases have one size here)


def test_a_change_while_refining_starts_again_and_nothing_stale_is_shown(app):
    ref = app.objects.hook.refinement
    refine(app)
    drag(app, 1, -10)
    for _ in range(6):  # part of the way
        app.frame()
        ref.twin.wait_lighting()
    assert not ref.done
    key = ref.key
    drag(app, 1, 8)  # moved again
    app.frame()
    assert ref.key != key and not ref.done and ref.slices == []  # the frame of a change: the draft only
    # while the view is turned frame after frame, each frame starts it again and draws no slice
    starts, yaw = ref.starts, app.camera.views["perspective"].yaw
    for k in range(1, 4):
        app.camera.views["perspective"].update(yaw=yaw + 0.01 * k)
        app.frame()
    assert ref.starts == starts + 3 and ref.slices == []
    app.camera.views["perspective"].update(yaw=yaw)
    per_frame = refine(app)
    assert max(per_frame) == 1
    assert same_picture(view_pixels(app), in_one_piece(app))
    # an exposure change redraws the composite only (the atlases are kept)
    app.display.set_exposure(app.display.hdr.exposure + 0.5)
    per_frame = refine(app)
    assert set(ref.slices) == {"composite"} and max(per_frame) == 1
    assert same_picture(view_pixels(app), in_one_piece(app))
    app.display.set_exposure(app.display.hdr.exposure - 0.5)


def test_a_screenshot_finishes_the_picture_first(app):
    """A capture (F12, --screenshot, the socket's screenshot) shows the full-quality picture, drawn
    in one go when the refinement had not finished."""
    ref = app.objects.hook.refinement
    refine(app)
    drag(app, 0, -12)
    app.frame()
    assert not ref.done
    shown = view_pixels(app)
    assert ref.done
    assert same_picture(shown, in_one_piece(app))


def test_a_resized_window_starts_it_again(app):
    ref = app.objects.hook.refinement
    refine(app)
    key, size = ref.key, app.surface.size
    app.surface.size = (size[0] - 60, size[1] - 30)
    try:
        app.frame()
        assert ref.key != key and not ref.done
        refine(app)
        assert same_picture(view_pixels(app), in_one_piece(app))
    finally:
        app.surface.size = size


def test_bench_with_objects_reports_drag_release_turn_and_exposure_frames(egl, capsys):
    """``phyir-view --object ... --bench``'s part with objects (viewer.app.cli.bench_drag) runs to
    the end and says what it measured: the drag, the frames after the release, the camera turning
    and the exposure dragged with the objects in view."""
    from phyir.insert.objects import PRESETS
    from viewer.app.cli import bench_drag

    a = box_room_app((480, 300))
    try:
        a.objects.add("sphere", PRESETS["diffuse"], 0.3, at=(46.5, 50.5))
        bench_drag(a, frames=6)
    finally:
        a.close()
    lines = capsys.readouterr().out.splitlines()
    starts = ["dragging 1 of 1 objects", "after release:", "turning the view with the objects:",
              "dragging the exposure with the objects:"]
    missing = [s for s in starts if not any(ln.startswith(s) for ln in lines)]
    assert not missing, lines
