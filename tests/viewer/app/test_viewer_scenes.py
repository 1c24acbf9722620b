"""The viewer variant of the box room (support.scenes.box_room(..., variant="viewer")) is what the
viewer tests take it for: exact walls, and a probe grid whose probes all differ."""

from __future__ import annotations

import torch
from support.scenes import VIEWER_ROOM_HI, VIEWER_ROOM_LO, box_room

from phyir import pano


def test_box_room_depth_is_the_distance_to_the_walls():
    sc = box_room(32, 64, variant="viewer")
    pts = pano.depth_to_points(sc.depth.double())
    lo3 = torch.tensor(VIEWER_ROOM_LO, dtype=torch.float64)[:, None, None]
    hi3 = torch.tensor(VIEWER_ROOM_HI, dtype=torch.float64)[:, None, None]
    on_wall = ((pts - lo3).abs().amin(0) < 1e-6) | ((pts - hi3).abs().amin(0) < 1e-6)
    assert on_wall.all()
    assert ((pts >= lo3 - 1e-6) & (pts <= hi3 + 1e-6)).all()
    assert sc.probes.shape == (4, 8, 3, 8, 16)
    assert float(sc.probes[3, 7].mean() / sc.probes[0, 0].mean()) == 1 + 3 + 7 / 4
