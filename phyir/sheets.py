"""Contact sheets: rows of image tiles under column headers, each row with its label, a legend below,
written atomically as PNG.  The callers say what the tiles are (``phyir eval --real`` and ``--scans``,
the synthetic dataset's report, ``scripts/contact_sheet.py``); the layout lives here.

A sheet, top to bottom: a header band (the column names), then per row a label band (the row's
name), the tiles side by side and a gap, then a legend band.  Columns start ``margin`` from the left,
each is as wide as its widest tile and followed by ``gap``; every row is as tall as the tallest tile.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Colour = tuple[int, int, int]
DEPTH_RAMP = np.array([[0.85, 0.15, 0.1], [0.95, 0.8, 0.2], [0.3, 0.8, 0.4], [0.2, 0.45, 0.9],
                       [0.08, 0.05, 0.35]])  # near (red) to far (dark blue)
Row = tuple[str, Sequence[np.ndarray]]  # a row's label and its uint8 [h,w,3] tiles, left to right


@dataclass(frozen=True)
class SheetStyle:
    """Sizes in pixels.  Text goes ``text_offset`` from its band's corner (a column's header, a row's
    label), the legend ``legend_offset`` from the legend band's."""

    background: Colour = (24, 24, 24)
    margin: int = 4
    gap: int = 4
    header_height: int = 14
    label_height: int = 14
    row_gap: int = 4
    legend_height: int = 14
    text_offset: tuple[int, int] = (0, 1)
    legend_offset: tuple[int, int] = (0, 1)
    header_colour: Colour = (200, 200, 200)
    label_colour: Colour = (240, 240, 160)
    legend_colour: Colour = (200, 200, 200)


DARK = SheetStyle()  # the evaluation's sheets: dark, tiles spaced, a one-line legend
LIGHT = SheetStyle(background=(255, 255, 255), margin=0, gap=0, header_height=18, label_height=18,
                   row_gap=0, legend_height=0, text_offset=(4, 3), header_colour=(0, 0, 0),
                   label_colour=(0, 0, 0), legend_colour=(0, 0, 0))  # white, tiles touching
BARE = SheetStyle(background=(255, 255, 255), margin=0, gap=2, header_height=0, label_height=0,
                  row_gap=2, legend_height=0)  # tiles only, 2 px of white after each


def compose_sheet(rows: Sequence[Row], columns: Sequence[str] = (), legend: str = "",
                  style: SheetStyle = DARK):
    """The sheet as a ``PIL.Image`` (RGB); rows may have fewer tiles than others."""
    from PIL import Image, ImageDraw

    if not rows:
        raise ValueError("a contact sheet needs at least one row")
    widths = [max(t[c].shape[1] for _, t in rows if c < len(t)) for c in range(max(len(t) for _, t in rows))]
    height = max(tile.shape[0] for _, t in rows for tile in t)
    xs = [style.margin + sum(w + style.gap for w in widths[:c]) for c in range(len(widths))]
    step = style.label_height + height + style.row_gap
    size = (style.margin + sum(w + style.gap for w in widths),
            style.header_height + len(rows) * step + style.legend_height)
    sheet = Image.new("RGB", size, style.background)
    draw = ImageDraw.Draw(sheet)
    dx, dy = style.text_offset
    for x, name in zip(xs, columns):
        draw.text((x + dx, dy), name, fill=style.header_colour)
    for r, (name, tiles) in enumerate(rows):
        y = style.header_height + r * step
        if name:
            draw.text((style.margin + dx, y + dy), name, fill=style.label_colour)
        for x, tile in zip(xs, tiles):
            sheet.paste(Image.fromarray(tile), (x, y + style.label_height))
    if legend:
        lx, ly = style.legend_offset
        draw.text((style.margin + lx, size[1] - style.legend_height + ly), legend, fill=style.legend_colour)
    return sheet


def save_sheet(path: str | os.PathLike, rows: Sequence[Row], columns: Sequence[str] = (),
               legend: str = "", style: SheetStyle = DARK):
    """:func:`compose_sheet` written atomically as PNG; returns the image."""
    from phyir.io import atomic_write

    sheet = compose_sheet(rows, columns, legend, style)
    with atomic_write(path) as tmp:
        sheet.save(tmp, format="PNG")
    return sheet


def ramp_colours(t: np.ndarray, stops: np.ndarray = DEPTH_RAMP) -> np.ndarray:
    """Values ``t`` (0 near .. 1 far, clipped) through the colour ramp ``stops``: uint8 [...,3]."""
    t = np.clip(t, 0, 1) * (len(stops) - 1)
    rgb = np.stack([np.interp(t, np.arange(len(stops)), stops[:, c]) for c in range(3)], -1)
    return (rgb * 255 + 0.5).astype(np.uint8)
