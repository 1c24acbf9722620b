"""The synthetic dataset's contact sheet (phyir.synth.report): one row of tiles per scene."""

from __future__ import annotations

import numpy as np
import torch
from PIL import Image

from phyir.io import save_scene
from phyir.scene import PanoScene
from phyir.synth.report import contact_sheet, scene_tiles


def scene(probes: bool) -> PanoScene:
    g = torch.Generator().manual_seed(0)
    def r(c: int) -> torch.Tensor:
        return torch.rand(c, 16, 32, generator=g)
    n = torch.nn.functional.normalize(r(3) - 0.5, dim=0)
    return PanoScene(image=r(3) * 2, depth=r(1) + 1, normal=n, albedo=r(3), roughness=r(1), metallic=r(1),
                     probes=torch.rand(4, 8, 3, 8, 16, generator=g) if probes else None,
                     masks={"emission": torch.zeros(1, 16, 32)})


def test_a_row_is_six_layers_and_three_probes_padded_to_the_row_height():
    tiles = scene_tiles(scene(True), height=16)
    assert [t.shape for t in tiles] == [(16, 32, 3)] * 6 + [(16, 16, 3)] * 3
    assert (tiles[6][8:] == 0).all()  # probes are half height, black below
    assert len(scene_tiles(scene(False), height=16)) == 6


def test_the_sheet_has_one_row_per_scene_with_two_white_pixels_after_each_tile(tmp_path):
    paths = [tmp_path / "scene_0.exr", tmp_path / "scene_1.exr"]
    save_scene(scene(True), paths[0])
    save_scene(scene(False), paths[1])
    out = contact_sheet(paths, tmp_path / "sheet" / "s.png", height=16)
    im = np.asarray(Image.open(out))
    assert im.shape == (2 * (16 + 2), 6 * (32 + 2) + 3 * (16 + 2), 3)
    assert (im[16:18] == 255).all() and (im[18:34, 6 * 34:] == 255).all()  # gap; row 2 has no probes
