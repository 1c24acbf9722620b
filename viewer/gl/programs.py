"""What both renderers (``viewer.renderer``, ``viewer.insertion``) need of a GL program: a cache of
compiled variants with their full-screen vertex arrays, and the uniform setters (a uniform the
compiler dropped from a variant is skipped), among them the view uniforms of ``shaders/view.glsl``."""

from __future__ import annotations

import math

import moderngl
import numpy as np

from phyir.insert.views import EquirectView, PerspectiveView
from viewer.gl import glsl


class ProgramCache:
    """Programs compiled once per (vertex shader, fragment shader, defines) on one context, and one
    attribute-less vertex array per program for full-screen triangles (``fullscreen.vert``)."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self._programs: dict[tuple, moderngl.Program] = {}
        self._vaos: dict[int, moderngl.VertexArray] = {}

    def program(self, vert: str, frag: str, **defines: int) -> moderngl.Program:
        """The program of two shader files compiled with ``defines`` (cached)."""
        key = (vert, frag, *sorted(defines.items()))
        if key not in self._programs:
            self._programs[key] = glsl.program(self.ctx, vert, frag, defines)
        return self._programs[key]

    def fullscreen(self, prog: moderngl.Program) -> moderngl.VertexArray:
        """The attribute-less vertex array that draws ``prog`` as one triangle (cached per program)."""
        if id(prog) not in self._vaos:
            self._vaos[id(prog)] = self.ctx.vertex_array(prog, [])
        return self._vaos[id(prog)]

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for prog in self._programs.values():
            prog.release()
        self._programs.clear()


def set_uniform(prog: moderngl.Program, name: str, value) -> None:
    """Set a uniform unless the compiler dropped it from this variant."""
    if name in prog:
        prog[name] = value


def write_array(prog: moderngl.Program, name: str, data: np.ndarray, dtype=np.float32) -> None:
    """Write a uniform array, zero-padded to its declared length."""
    if name not in prog:
        return
    u = prog[name]
    a = np.asarray(data, dtype).reshape(-1)
    full = np.zeros(u.array_length * u.dimension, dtype)
    full[:a.size] = a[:full.size]
    u.write(full.tobytes())


def matrix_bytes(m: np.ndarray) -> bytes:
    """A row-major numpy matrix as GLSL's column-major float32 uniform data."""
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()


def set_view(prog: moderngl.Program, view: EquirectView | PerspectiveView,
             rect: tuple[float, float, float, float], fb_height: float) -> None:
    """The uniforms of ``shaders/view.glsl``: the view rectangle (x, y, w, h; y from the top) in a
    framebuffer ``fb_height`` pixels high, and the camera."""
    set_uniform(prog, "view_rect", tuple(float(r) for r in rect))
    set_uniform(prog, "fb_height", float(fb_height))
    if isinstance(view, EquirectView):
        set_uniform(prog, "eq_center", tuple(float(c) for c in view.center))
        set_uniform(prog, "eq_zoom", float(view.zoom))
    elif isinstance(view, PerspectiveView):
        set_uniform(prog, "persp", (float(math.radians(view.fov)), float(view.yaw), float(view.pitch)))
    else:
        raise TypeError(f"unknown view {view!r}")
