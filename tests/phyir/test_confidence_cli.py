"""The geometry confidence users see: ``phyir info`` on a scene with depth and normals."""

from __future__ import annotations

import torch

from phyir.cli import main
from phyir.io import save_scene
from phyir.scene import PanoScene
from phyir.synth.analytic import box_room


def room(collapsed: bool) -> PanoScene:
    depth, normal = box_room(32, 64, (-2.0, -1.5, -3.0), (2.5, 1.3, 2.0))
    if collapsed:  # every normal "up", as the network predicted in some real rooms
        normal = torch.tensor([0.0, 1.0, 0.0], dtype=normal.dtype)[:, None, None].expand(3, 32, 64)
    return PanoScene(image=torch.full((3, 32, 64), 0.5), depth=depth.float(), normal=normal.float())


def test_info_reports_confidence_of_exact_geometry_and_flags_collapsed_normals(tmp_path, capsys):
    good, bad = tmp_path / "good.exr", tmp_path / "bad.exr"
    save_scene(room(False), good)
    save_scene(room(True), bad)
    assert main(["info", str(good), str(bad)]) == 0
    out = capsys.readouterr().out
    good_line, bad_line = (ln for ln in out.splitlines() if "geometry confidence" in ln)
    assert "plausible" in good_line and float(good_line.split(":")[1].split()[0]) > 0.9
    assert "flagged" in bad_line and float(bad_line.split(":")[1].split()[0]) < 0.5
