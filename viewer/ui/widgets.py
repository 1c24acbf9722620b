"""What the imgui modules of ``viewer.ui`` share: ``imgui`` itself (imported after PyOpenGL's
per-call error checks are turned off: import it from here), sizes, colours and formatting."""

from __future__ import annotations

import functools

import numpy as np

from viewer.gl.window import fast_pyopengl
from viewer.renderer import colormap_lut

fast_pyopengl()
from imgui_bundle import imgui  # noqa: E402

PANEL_WIDTH = 370      # logical pixels
ERROR_BG = (0.55, 0.08, 0.08, 0.95)
FLAGS_FIXED = (imgui.WindowFlags_.no_title_bar | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_move
               | imgui.WindowFlags_.no_collapse | imgui.WindowFlags_.no_saved_settings
               | imgui.WindowFlags_.no_bring_to_front_on_focus)
LEVEL_COLOURS = {"error": (1, 0.4, 0.4, 1), "warning": (1, 0.8, 0.3, 1)}


def col32(r: float, g: float, b: float, a: float = 1.0) -> int:
    return imgui.color_convert_float4_to_u32(imgui.ImVec4(r, g, b, a))


def fmt_number(x: float) -> str:
    return f"{x:.4g}" if abs(x) < 1e5 else f"{x:.3e}"


def fmt_value(a: np.ndarray) -> str:
    a = np.atleast_1d(a)
    return ", ".join(fmt_number(float(x)) for x in a)


def colour_bar(name: str, lo: str, hi: str, scale: float) -> None:
    """Colour map ``name`` as a bar the width of the panel, its ends labelled ``lo`` and ``hi``."""
    lut = _bar_lut(name)
    dl = imgui.get_window_draw_list()
    p = imgui.get_cursor_screen_pos()
    w = imgui.get_content_region_avail().x
    h = 10 * scale
    n = len(lut)
    for k, c in enumerate(lut):
        x0, x1 = p.x + w * k / n, p.x + w * (k + 1) / n + 1
        dl.add_rect_filled(imgui.ImVec2(x0, p.y), imgui.ImVec2(x1, p.y + h), col32(*c))
    imgui.dummy(imgui.ImVec2(w, h))
    imgui.text(lo)
    imgui.same_line(max(0.0, w - imgui.calc_text_size(hi).x))
    imgui.text(hi)


@functools.cache
def _bar_lut(name: str) -> np.ndarray:
    """The colour bar's 64 colours of colour map ``name`` (computed once)."""
    return colormap_lut(name, 64)
