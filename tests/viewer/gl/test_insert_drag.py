"""The cheaper dragging quality (viewer.insertion.DRAGGING) takes its cheaper paths and still looks
like the object: decimated meshes in the impostor and shadow maps, one look-up per object and no
blocker search in the composite (headless through EGL; benchmarks/insert_drag.py times them)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.scenes import box_room

from phyir.insert import placement

moderngl = pytest.importorskip("moderngl")
trimesh = pytest.importorskip("trimesh")

from phyir.insert.objects import PRESETS, SceneObject, _finish, primitive  # noqa: E402
from phyir.insert.views import EquirectView  # noqa: E402
from viewer.insertion import DRAGGING, FULL, InsertionRenderer  # noqa: E402

pytestmark = pytest.mark.gl
# DRAGGING with every pass as it was before the cheaper paths (the full mesh, per-proxy look-ups)
OLD_DRAGGING = dataclasses.replace(DRAGGING, impostor_faces=0, shadow_faces=0, proxy_lookups=True,
                                   blocker_search=True, reuse_lights=False, own_shadow_bounds=False)


@pytest.fixture(scope="module")
def setup(ctx):
    room = box_room(64, 128)
    r = InsertionRenderer(ctx)
    r.set_scene(room)
    m = trimesh.creation.icosphere(subdivisions=5)  # 20,480 triangles, as the benchmark's mesh
    mesh = _finish(m.vertices, None, m.faces, "ball", "ball")
    ball = SceneObject(mesh, PRESETS["matte-silver"], scale=0.25)
    pl = placement.drop(room, 40.5, 50.5, ball.base_offset())
    ball.position, ball.rotation, ball.support = pl.position, pl.rotation, (pl.contact, pl.normal)
    H, W = room.size
    yield r, ball, (EquirectView(center=(W / 2, H / 2), zoom=1.0), (W, H))
    r.release()


def test_dragging_draws_decimated_meshes(setup):
    r, ball, (view, size) = setup
    full = r.render_view([ball], view, size, FULL)
    lights = len(r.object_state(ball, FULL).lights)
    assert lights >= 1
    assert r.drawn_faces == {"impostor": 20480, "shadow": 20480 * lights}
    drag = r.render_view([ball], view, size, DRAGGING)
    lights = len(r.object_state(ball, DRAGGING).lights)
    assert 0 < r.drawn_faces["impostor"] <= DRAGGING.impostor_faces < 20480 // 8
    assert 0 < r.drawn_faces["shadow"] <= DRAGGING.shadow_faces * lights
    assert r.drawn_faces["shadow"] < 20480 * lights // 16
    # the same object: coverage within 2% of the full mesh's at the same impostor resolution, the
    # shadow where the full-quality frame has it
    old = r.render_view([ball], view, size, OLD_DRAGGING)
    assert drag["alpha"].sum() == pytest.approx(old["alpha"].sum(), rel=0.02)
    shadowed = full["shadow"] > 0.2
    assert shadowed.sum() > 3 and drag["shadow"][shadowed].min() > 0.1


def test_dragging_composite_is_close_to_the_full_per_proxy_one(setup):
    """One look-up per object instead of per proxy and PCSS without blocker search change the
    receivers' light by a few percent of the shadow matte, not its shape; the mesh's LOD changes
    the object's pixels by little."""
    r, ball, (view, size) = setup
    r.forget_tiles()
    old = r.render_view([ball], view, size, OLD_DRAGGING)
    assert r.drawn_faces["impostor"] == 20480
    new = r.render_view([ball], view, size, DRAGGING)
    receivers = (old["alpha"] == 0) & (new["alpha"] == 0) & (old["shadow"] > 0.02)
    assert receivers.sum() > 10
    diff = np.abs(new["shadow"] - old["shadow"])[receivers]
    assert 0 < diff.mean() < 0.05 and diff.max() < 0.25
    both = (old["alpha"] == 1) & (new["alpha"] == 1)
    rel = np.abs(new["object"][both] - old["object"][both]).sum() / old["object"][both].sum()
    assert rel < 0.03


def test_objects_that_did_not_change_keep_their_tiles(setup):
    """Dragging one object redraws its impostor and shadow maps only; the frame is the one drawn
    from scratch, bit for bit."""
    r, ball, (view, size) = setup
    other = SceneObject(primitive("cube"), PRESETS["diffuse"], scale=0.2)
    pl = placement.drop(r.scene, 80.5, 52.5, other.base_offset())
    other.position, other.rotation, other.support = pl.position, pl.rotation, (pl.contact, pl.normal)
    r.render_view([ball, other], view, size, DRAGGING)
    pl = placement.drop(r.scene, 84.5, 52.5, other.base_offset())  # the cube moves, the ball stays
    other.position, other.rotation, other.support = pl.position, pl.rotation, (pl.contact, pl.normal)
    moved = r.render_view([ball, other], view, size, DRAGGING)
    assert r.drawn_faces["impostor"] == len(other.mesh.faces)  # the ball's tile was kept
    r.forget_tiles()
    fresh = r.render_view([ball, other], view, size, DRAGGING)
    assert r.drawn_faces["impostor"] > len(other.mesh.faces)
    for name in ("composite", "alpha", "shadow"):
        assert np.array_equal(moved[name], fresh[name]), name

