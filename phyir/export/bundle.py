"""``export_gltf``: a scene (and inserted objects) to one output set, ``OUT.glb`` + ``OUT.exr``.

The .glb holds the room mesh, its two materials, the camera, the lights and the objects
(:mod:`phyir.export.gltf`); the .exr is the HDR panorama itself (equirect, the project's mapping:
the environment for a renderer's world, and the room's full-HDR emission texture — the mesh's UVs
index it as they index the glb's textures).  Both are written to temporaries and renamed together;
if anything fails neither is left behind (and files that were there before are left alone).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from phyir.errors import InputError
from phyir.export.gltf import RoomTextures, encode_srgb8, write_glb
from phyir.export.lights import BRIGHT_FACTOR, LUMENS_PER_WATT, MAX_LIGHTS, scene_lights
from phyir.export.room_mesh import DEFAULT_GRID, MIN_GRAZING_DEG, room_mesh
from phyir.insert.objects import SceneObject
from phyir.io import atomic_write, exr
from phyir.scene import PanoScene


@dataclass
class ExportReport:
    glb: str
    exr: str
    vertices: int
    faces: int
    dropped: int  # triangles removed at depth discontinuities
    lights: int
    objects: int
    glb_bytes: int
    exr_bytes: int
    seconds: float


def room_textures(scene: PanoScene, base: torch.Tensor) -> RoomTextures:
    """The emissive texture (``base`` / its maximum, sRGB) and, when the scene has them, the PBR ones."""
    hwc = base.permute(1, 2, 0).double().numpy()
    strength = float(hwc.max()) if hwc.max() > 0 else 1.0
    tex = RoomTextures(emissive=encode_srgb8(hwc / strength), emissive_strength=strength)
    if scene.has("albedo", "roughness", "metallic"):
        tex.base_color = encode_srgb8(scene.albedo.permute(1, 2, 0).numpy())
        mr = torch.cat((torch.zeros_like(scene.roughness), scene.roughness, scene.metallic))
        tex.metallic_roughness = np.round(mr.permute(1, 2, 0).clamp(0, 1).numpy() * 255).astype(np.uint8)
    return tex


def write_together(paths: Sequence[str], writers: Sequence[Callable[[str], None]]) -> None:
    """Run ``writers[k](temporary)`` for every path (temporaries of :func:`phyir.io.atomic_write`),
    then rename them all into place.  If a writer or a rename fails, every temporary and every
    target already renamed by this call is removed."""
    renamed: list[str] = []

    def undo(exc_type, exc, tb) -> None:
        if exc_type is not None:
            for p in renamed:
                with contextlib.suppress(OSError):
                    os.remove(p)

    with contextlib.ExitStack() as stack:
        stack.push(undo)  # runs last, after every rename (or failure)
        tmps = [stack.enter_context(_renamed_into(p, renamed)) for p in paths]
        for tmp, write in zip(tmps, writers):
            write(tmp)


@contextlib.contextmanager
def _renamed_into(path: str, renamed: list[str]):
    with atomic_write(path) as tmp:
        yield tmp
    renamed.append(path)  # atomic_write returned: the temporary is now ``path``


def environment_path(glb_path: str) -> str:
    """The EXR of an output set: ``OUT_env.exr`` beside ``OUT.glb`` (not ``OUT.exr``: that is often
    the scene file the export was made from)."""
    return os.path.splitext(glb_path)[0] + "_env.exr"


def export_gltf(scene: PanoScene, path: str, *, exr_path: str | None = None,
                grid: tuple[int, int] = DEFAULT_GRID, objects: Sequence[SceneObject] = (),
                max_lights: int = MAX_LIGHTS, min_grazing_deg: float = MIN_GRAZING_DEG,
                fov_deg: float = 60.0, aspect: float = 1.5,
                camera_rotation: np.ndarray | None = None, environment: str | None = None) -> ExportReport:
    """Write ``path`` (.glb) and ``exr_path`` (default: :func:`environment_path`) for an unbatched scene
    with depth (see the module doc); the camera: ``fov_deg`` (vertical), ``aspect`` (width / height)
    and ``camera_rotation`` (see :func:`phyir.export.gltf.write_glb`).  ``environment``: the EXR's
    file name the glb records (default ``exr_path``'s; another when both are temporaries renamed
    later)."""
    t0 = time.perf_counter()
    if scene.depth is None:
        raise InputError(path, "the scene has no depth layer to build the room from")
    exr_path = exr_path or environment_path(path)
    room = room_mesh(scene, grid, min_grazing_deg)
    lights, base = scene_lights(scene, max_lights)
    tex = room_textures(scene, base)
    H, W = scene.size
    tex.extras = {"environment": environment or os.path.basename(exr_path),
                  "mapping": "equirect (docs/conventions.md)", "panorama_size": [H, W],
                  "light_threshold_factor": BRIGHT_FACTOR, "lumens_per_watt": LUMENS_PER_WATT}
    image = torch.nan_to_num(scene.image.float(), nan=0.0, posinf=0.0).clamp_min(0).numpy()
    write_together([path, exr_path], [
        lambda tmp: write_glb(tmp, room, tex, lights, list(objects), fov_deg, aspect, camera_rotation),
        lambda tmp: exr.write_parts(tmp, [("scene", {}, dict(zip("RGB", image)))])])
    return ExportReport(path, exr_path, len(room.positions), len(room.faces), room.dropped, len(lights),
                        len(objects), os.path.getsize(path), os.path.getsize(exr_path),
                        time.perf_counter() - t0)
