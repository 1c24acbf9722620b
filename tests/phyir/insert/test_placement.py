"""Placement of inserted objects through the functions a click and a drag call (phyir.insert.placement)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from support.scenes import FLOOR_Y, TABLE_HI, TABLE_LO, box_room

from phyir import pano
from phyir.errors import PhyIRError
from phyir.insert import placement


@pytest.fixture(scope="module")
def room():
    return box_room(128, 256, grid=(4, 8), probe_size=(4, 8))


def floor_pixels(scene, n: int = 12, seed: int = 0) -> list[tuple[float, float]]:
    """Random continuous pixel coordinates where the camera sees the floor (away from the table)."""
    H, W = scene.size
    g = np.random.default_rng(seed)
    n_y = scene.normal[1].numpy()
    out = []
    while len(out) < n:
        u, v = g.uniform(0, W), g.uniform(H * 0.6, H - 1)
        i, j = int(v), int(u)
        if n_y[i, j] > 0.99 and scene.depth[0, i, j] < 5 and abs(float(scene.depth[0, i, j]) -
                                                                  float(scene.depth[0, i, j - 1])) < 0.05:
            p = float(scene.depth[0, i, j]) * pano.uv_to_dir(torch.tensor(u), torch.tensor(v), H, W).numpy()
            if abs(p[1] - FLOOR_Y) < 1e-3:
                out.append((u, v))
    return out


def base_point(pl: placement.Placement, base_offset: float) -> np.ndarray:
    """The object's lowest point: base_offset below its origin along its up axis."""
    return pl.position - base_offset * (pl.rotation @ np.array([0.0, 1.0, 0.0]))


@pytest.mark.parametrize("base_offset", [0.25, 1.0])
def test_drop_on_floor_puts_base_on_floor(room, base_offset):
    for u, v in floor_pixels(room):
        pl = placement.drop(room, u, v, base_offset)
        assert abs(base_point(pl, base_offset)[1] - FLOOR_Y) < 0.01
        np.testing.assert_allclose(pl.normal, [0, 1, 0], atol=1e-9)
        assert pl.position[1] == pytest.approx(FLOOR_Y + base_offset, abs=0.01)
        # and the contact point is the floor point the pixel looks at
        H, W = room.size
        d = pano.uv_to_dir(torch.tensor(u, dtype=torch.float64), torch.tensor(v, dtype=torch.float64), H, W)
        np.testing.assert_allclose(pl.contact, d.numpy() * (FLOOR_Y / float(d[1])), atol=1e-6)


def test_drop_on_table_top_and_wall(room):
    H, W = room.size
    top = np.array([0.2, TABLE_HI[1], -2.0])
    u, v, _ = pano.points_to_uv(torch.as_tensor(top), H, W)
    pl = placement.drop(room, float(u), float(v), 0.1)
    assert base_point(pl, 0.1)[1] == pytest.approx(TABLE_HI[1], abs=0.01)
    # a wall: the object stands out of it along the wall's normal
    wall = np.array([2.0, 0.0, -4.0])
    u, v, _ = pano.points_to_uv(torch.as_tensor(wall), H, W)
    pl = placement.drop(room, float(u), float(v), 0.1)
    np.testing.assert_allclose(pl.normal, [0, 0, 1], atol=1e-6)
    assert pl.position[2] == pytest.approx(-4.0 + 0.1, abs=0.01)
    np.testing.assert_allclose(pl.rotation @ [0, 1, 0], [0, 0, 1], atol=1e-9)


def test_snap_keeps_tilted_normals_and_snaps_near_vertical():
    assert np.allclose(placement.snap_normal(np.array([0.05, 1.0, 0.0])), [0, 1, 0])
    n = np.array([0.5, 1.0, 0.0]) / math.hypot(0.5, 1.0)
    assert np.allclose(placement.snap_normal(n), n)
    for up in (n, [0, -1, 0], [1, 0, 0]):
        r = placement.rotation_to(np.asarray(up, float))
        assert np.allclose(r @ [0, 1, 0], up) and np.allclose(r @ r.T, np.eye(3))


def test_drag_follows_the_floor_then_climbs_onto_the_table(room):
    H, W = room.size
    start = np.array([0.0, FLOOR_Y, -1.2])  # on the floor in front of the table
    su, sv, _ = pano.points_to_uv(torch.as_tensor(start), H, W)
    pl = placement.drop(room, float(su), float(sv), 0.1)
    # grab the ball a few pixels above its contact point, like a user clicking on it
    grab = (float(su) + 1.0, float(sv) - 6.0)
    drag = placement.Drag(room, pl.contact, grab, 0.1)
    for k in range(1, 8):  # sideways over the floor
        p = drag.move((grab[0] + 3.0 * k, grab[1]))
        assert abs(base_point(p, 0.1)[1] - FLOOR_Y) < 0.01
        assert p.contact[0] > pl.contact[0]  # it moved the way the cursor went
    # up the screen past the table's front edge: the ball lands on the table top
    top = np.array([0.0, TABLE_HI[1], -2.1])
    tu, tv, _ = pano.points_to_uv(torch.as_tensor(top), H, W)
    p = drag.move((float(tu) + (grab[0] - float(su)), float(tv) + (grab[1] - float(sv))))
    assert base_point(p, 0.1)[1] == pytest.approx(TABLE_HI[1], abs=0.01)
    assert TABLE_LO[2] < p.contact[2] < TABLE_HI[2]


def test_place_at_position_finds_the_support_below(room):
    centre = np.array([1.0, -0.5, -2.0])
    pl, free = placement.place_at_position(room, centre, np.zeros(3))
    assert free
    np.testing.assert_allclose(pl.position, centre)
    assert pl.contact[1] == pytest.approx(FLOOR_Y, abs=0.02)
    np.testing.assert_allclose(pl.normal, [0, 1, 0])
    # a point outside the room is behind the scene surface
    _, free = placement.place_at_position(room, np.array([0.0, 0.0, -6.0]), np.zeros(3))
    assert not free


def test_no_depth_is_an_error(room):
    with pytest.raises(PhyIRError, match="depth"):
        placement.drop(room.replace(depth=None), 10.0, 10.0, 0.1)
