"""The one contact-sheet layout (phyir.sheets): sizes, placement, text bands, the atomic PNG."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from phyir.sheets import BARE, DARK, LIGHT, SheetStyle, compose_sheet, save_sheet


def tile(h: int, w: int, v: int) -> np.ndarray:
    return np.full((h, w, 3), v, np.uint8)


def test_tiles_are_placed_by_column_and_row_with_the_styles_spacing():
    rows = [("a", [tile(8, 16, 10), tile(4, 8, 20)]), ("b", [tile(8, 16, 30)])]
    im = np.asarray(compose_sheet(rows, style=BARE))
    assert im.shape == (2 * (8 + 2), 16 + 2 + 8 + 2, 3)  # columns and rows each followed by 2 px
    assert (im[0:8, 0:16] == 10).all() and (im[0:4, 18:26] == 20).all() and (im[10:18, 0:16] == 30).all()
    assert (im[4:8, 18:26] == 255).all() and (im[10:18, 18:] == 255).all()  # short tile, missing tile


def test_header_label_and_legend_bands_hold_text_and_tiles_are_not_drawn_over():
    style = SheetStyle(legend_height=28, legend_offset=(0, 2))
    rows = [("room", [tile(20, 40, 0), tile(20, 40, 0)])]
    im = np.asarray(compose_sheet(rows, ["input", "depth"], "a legend", style))
    s = DARK
    height = s.header_height + s.label_height + 20 + s.row_gap + 28
    assert im.shape == (height, s.margin + 2 * (40 + s.gap), 3)
    header, label = im[:s.header_height], im[s.header_height:s.header_height + s.label_height]
    legend = im[-28:]
    for band in (header, label, legend):  # text drawn (antialiased) on the background
        assert (band != s.background).any(-1).any()
    top = s.header_height + s.label_height
    assert (im[top:top + 20, s.margin:s.margin + 40] == 0).all()


def test_light_labels_rows_in_black_on_white():
    im = np.asarray(compose_sheet([("x", [tile(10, 30, 128)])], ["c"], style=LIGHT))
    assert im.shape == (18 + 18 + 10, 30, 3)
    assert (im[:18] != 255).any() and (im[18:36] != 255).any() and (im[36:] == 128).all()


def test_save_sheet_writes_a_png_atomically(tmp_path):
    out = tmp_path / "sheet.png"
    im = save_sheet(out, [("r", [tile(6, 6, 50)])], ["c"], "legend")
    assert np.array_equal(np.asarray(Image.open(out)), np.asarray(im))
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]


def test_a_sheet_needs_rows():
    with pytest.raises(ValueError):
        compose_sheet([])
