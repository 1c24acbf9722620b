"""``write_blend``: a scene exported as a ready Blender file, built by Blender itself.

The glTF set of :func:`phyir.export.bundle.export_gltf` is written first (to temporaries when only
the .blend is asked for), then ``blender --background`` runs :mod:`phyir.export.blender_scene` on it:
that script imports the glb and sets up the world, the room as shadow catcher, the lights, the
camera and the compositing (docs/export.md, Blender).  The .blend (and the glb + EXR when asked for)
is one output set: nothing is left if Blender is missing, fails or writes nothing.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from phyir.errors import InputError
from phyir.export.bundle import ExportReport, environment_path, export_gltf
from phyir.export.lights import MAX_LIGHTS
from phyir.export.room_mesh import DEFAULT_GRID
from phyir.insert.objects import SceneObject
from phyir.io.files import AtomicSet
from phyir.scene import PanoScene

SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "blender_scene.py")
MARK = "phyir-blend:"  # blender_scene.MARK: the script's summary or error line
INSTALL = "install Blender (Debian: apt-get install blender) or give --blender PATH"


@dataclass
class BlendReport:
    blend: str
    blend_bytes: int
    blender: str  # its version, as it reports it
    lights: int
    lights_render: bool  # whether the lights are enabled in renders (the glb-texture emission)
    objects: int
    numpy: str  # the numpy Blender's glTF importer ran with
    gltf: ExportReport  # the glb + EXR the scene was built from (temporaries unless asked for)
    seconds: float


def find_blender(path: str | None = None) -> str:
    """The Blender program: ``path`` (a file or a name on PATH), else ``blender`` on PATH."""
    if path is None:
        found = shutil.which("blender")
        if found is None:
            raise InputError("--blend", f"needs Blender and there is no 'blender' on PATH: {INSTALL}")
        return found
    found = shutil.which(path) if path else None
    if found is None:
        problem = "not an executable program" if os.path.exists(path) else "no such program"
        raise InputError("--blender", f"{path}: {problem}")
    return found


def _failure(out: str) -> str:
    """The reason in Blender's output: the script's error line, else the last Python exception's
    (``KeyError: 'Env'``), else the last line that says error."""
    lines = [ln.strip() for ln in out.splitlines() if ln.strip()]
    for ln in reversed(lines):
        if ln.startswith(f"{MARK} error:"):
            return ln[len(MARK) + len(" error:"):].strip()
    raised = [ln for ln in lines if re.match(r"[A-Za-z_.]+(Error|Exception): ", ln)]
    said = [ln for ln in lines if "error" in ln.lower()]
    return (raised or said or lines or ["no output"])[-1][:300]


def run_blender(blender: str, args: Sequence[str]) -> dict:
    """Run the scene script in ``blender --background`` with ``args``; its summary (a dict)."""
    numpy_dir = os.path.dirname(os.path.dirname(os.path.abspath(np.__file__)))
    cmd = [blender, "--background", "--factory-startup", "--python-exit-code", "1", "--python", SCRIPT,
           "--", *args, "--numpy-path", numpy_dir, "--numpy-python", "{}.{}".format(*sys.version_info[:2])]
    try:
        proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True, errors="replace")
    except OSError as e:
        raise InputError("--blender", f"{blender}: cannot run it: {e.strerror}") from None
    out = proc.stdout + "\n" + proc.stderr
    summary = next((ln[len(MARK):].strip() for ln in out.splitlines()
                    if ln.startswith(MARK) and not ln.startswith(f"{MARK} error:")), None)
    if proc.returncode != 0:
        raise InputError("--blender", f"{blender} failed (exit code {proc.returncode}): {_failure(out)}")
    if summary is None:
        raise InputError("--blender", f"{blender} built no scene (is it Blender 3.4 or newer?): "
                                      f"{_failure(out)}")
    return json.loads(summary)


def write_blend(scene: PanoScene, path: str, *, blender: str | None = None, gltf: str | None = None,
                exr: str | None = None, grid: tuple[int, int] = DEFAULT_GRID,
                objects: Sequence[SceneObject] = (), max_lights: int = MAX_LIGHTS, fov_deg: float = 60.0,
                aspect: float = 1.5) -> BlendReport:
    """Write ``path`` (.blend) for an unbatched scene with depth, and ``gltf`` + ``exr`` (default
    :func:`environment_path`) too when ``gltf`` is given; ``blender``: the program (default: the
    ``blender`` on PATH).  The others as :func:`phyir.export.bundle.export_gltf`'s."""
    t0 = time.perf_counter()
    program = find_blender(blender)
    if gltf is not None:
        exr = exr or environment_path(gltf)
    scratch = AtomicSet()  # the glb + EXR when not asked for: temporaries, never renamed into place
    try:
        with AtomicSet() as outputs:
            tmp_blend = outputs.add(path)
            if gltf is not None:
                tmp_glb, tmp_exr = outputs.add(gltf), outputs.add(exr)
            else:
                tmp_glb, tmp_exr = scratch.add(path + ".glb"), scratch.add(path + "_env.exr")
            final_exr = exr or environment_path(os.path.splitext(path)[0] + ".glb")  # the glb's, or beside
            exr_name = os.path.relpath(os.path.abspath(final_exr), os.path.dirname(os.path.abspath(path)))
            report = export_gltf(scene, tmp_glb, exr_path=tmp_exr, environment=os.path.basename(final_exr),
                                 grid=grid, objects=objects, max_lights=max_lights, fov_deg=fov_deg,
                                 aspect=aspect)
            summary = run_blender(program, ["--glb", tmp_glb, "--exr", tmp_exr, "--out", tmp_blend,
                                            "--exr-name", exr_name])
            if os.path.getsize(tmp_blend) == 0:
                raise InputError("--blender", f"{program} wrote no .blend file: {path}")
            size = os.path.getsize(tmp_blend)
    finally:
        scratch.abort()
    if gltf is not None:
        report.glb, report.exr = gltf, exr
    return BlendReport(path, size, summary.get("blender", "?"), int(summary.get("lights", 0)),
                       bool(summary.get("lights_render")), len(summary.get("objects", [])),
                       summary.get("numpy", "?"), report, time.perf_counter() - t0)
