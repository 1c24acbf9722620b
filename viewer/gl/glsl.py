"""GLSL sources from the ``viewer.shaders`` package, with ``#include "file"`` resolved."""

from __future__ import annotations

import re
from functools import cache
from importlib.resources import files

import moderngl

_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)


@cache
def source(name: str) -> str:
    """Text of shader ``name`` with its includes inlined (each file at most once)."""
    return _expand(name, set())


def _expand(name: str, seen: set[str]) -> str:
    if name in seen:
        return ""
    seen.add(name)
    text = files("viewer.shaders").joinpath(name).read_text(encoding="utf-8")
    return _INCLUDE.sub(lambda m: _expand(m.group(1), seen), text)


def program(ctx: moderngl.Context, vertex: str, fragment: str,
            defines: dict[str, int] | None = None) -> moderngl.Program:
    """Compile and link a program from two shader files; ``defines`` become ``#define`` lines
    after the fragment shader's ``#version`` (compile-time variants)."""
    return ctx.program(vertex_shader=source(vertex), fragment_shader=with_defines(source(fragment), defines))


def with_defines(text: str, defines: dict[str, int] | None) -> str:
    if not defines:
        return text
    head, _, rest = text.partition("\n")
    if not head.startswith("#version"):
        raise ValueError("shader must start with #version to take defines")
    lines = "".join(f"#define {k} {int(v)}\n" for k, v in sorted(defines.items()))
    return f"{head}\n{lines}{rest}"
