"""What the imgui modules of ``viewer.ui`` share: ``imgui`` itself (imported after PyOpenGL's
per-call error checks are turned off: import it from here), sizes, colours and formatting."""

from __future__ import annotations

import numpy as np

from viewer.gl.window import fast_pyopengl

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
