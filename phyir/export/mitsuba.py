"""An exported output set (``OUT.glb`` + ``OUT_env.exr``) read back into a Mitsuba 3 scene.

The independent check of the export (tests/phyir/export/test_mitsuba.py, docs/export.md): what
Mitsuba renders is what the *file* says, read with pygltflib — the room's triangles and UVs, its
emissive texture and strength (or the full-HDR EXR beside it), the spot lights (candela back to
W/sr), the inserted objects with their node matrices and PBR factors.  Mitsuba is optional
(``pip install mitsuba``; the ``dev`` extra has it) and imported only here, in the CPU
``scalar_rgb`` variant.

Room emission, ``emission=``:
* ``"glb"``: the glb's own emissive texture x strength — the panorama without the bright sources,
  to be rendered **with** the lights (``lights=True``);
* ``"exr"``: the EXR beside the file — the whole panorama, to be rendered **without** the lights.
The room itself does not reflect (black BSDF): its emission is already the light it sends.
"""

from __future__ import annotations

import io
import math
import os

import numpy as np

from phyir.color import srgb_to_linear
from phyir.export.lights import LUMENS_PER_WATT

COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def mitsuba():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


class GlbFile:
    """A glb read with pygltflib, with numpy views of its accessors and decoded images."""

    def __init__(self, path: str):
        import pygltflib as gl

        self.path = path
        self.doc = gl.GLTF2().load(path)
        self.blob = self.doc.binary_blob()
        self.dtypes = {gl.FLOAT: np.float32, gl.UNSIGNED_INT: np.uint32, gl.UNSIGNED_SHORT: np.uint16}

    def array(self, index: int) -> np.ndarray:
        acc = self.doc.accessors[index]
        view = self.doc.bufferViews[acc.bufferView]
        n = COMPONENTS[acc.type]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        a = np.frombuffer(self.blob, self.dtypes[acc.componentType], acc.count * n, start)
        return a.reshape(acc.count, n) if n > 1 else a

    def image(self, texture: int) -> np.ndarray:
        """uint8 ``[H, W, 3]`` of a texture."""
        from PIL import Image

        img = self.doc.images[self.doc.textures[texture].source]
        view = self.doc.bufferViews[img.bufferView]
        data = self.blob[view.byteOffset:view.byteOffset + view.byteLength]
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    def node(self, name: str):
        return next((n for n in self.doc.nodes if n.name == name), None)

    def environment(self) -> str:
        extras = (self.doc.extras or {}).get("phyir", {})
        return os.path.join(os.path.dirname(os.path.abspath(self.path)), extras["environment"])


def node_matrix(node) -> np.ndarray:
    """4x4 local -> parent of a glTF node (``matrix``, or translation x rotation; no scale used here)."""
    if node.matrix:
        return np.asarray(node.matrix, np.float64).reshape(4, 4).T
    m = np.eye(4)
    if node.rotation:
        x, y, z, w = node.rotation
        m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    if node.translation:
        m[:3, 3] = node.translation
    return m


def make_mesh(name: str, positions: np.ndarray, faces: np.ndarray, texcoords: np.ndarray | None = None,
              normals: np.ndarray | None = None, bsdf=None, emitter=None):
    """A ``mitsuba.Mesh`` from numpy arrays."""
    mi = mitsuba()
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    mesh = mi.Mesh(name, len(positions), len(faces), props=props, has_vertex_normals=normals is not None,
                   has_vertex_texcoords=texcoords is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(positions, np.float32).ravel()
    params["faces"] = np.ascontiguousarray(faces, np.uint32).ravel()
    if texcoords is not None:
        params["vertex_texcoords"] = np.ascontiguousarray(texcoords, np.float32).ravel()
    if normals is not None:
        params["vertex_normals"] = np.ascontiguousarray(normals, np.float32).ravel()
    params.update()
    return mesh


def room_emission(glb: GlbFile, emission: str) -> np.ndarray:
    """Linear radiance ``[H, W, 3]`` the room emits (see the module doc)."""
    if emission == "exr":
        from phyir.io import load_panorama

        return load_panorama(glb.environment()).permute(1, 2, 0).numpy()
    mat = glb.doc.materials[glb.doc.meshes[glb.node("room").mesh].primitives[0].material]
    strength = mat.extensions["KHR_materials_emissive_strength"]["emissiveStrength"]
    tex = glb.image(mat.emissiveTexture.index).astype(np.float32) / 255
    return srgb_to_linear(tex) * np.float32(strength) * np.asarray(mat.emissiveFactor, np.float32)


def scene_dict(path: str, *, emission: str = "exr", lights: bool = False, objects: bool = True) -> dict:
    """A ``mitsuba.load_dict`` dictionary (without sensor and integrator) of an exported glb."""
    mi = mitsuba()
    glb = GlbFile(path)
    black = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})
    room_prim = glb.doc.meshes[glb.node("room").mesh].primitives[0]
    radiance = {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(room_emission(glb, emission))),
                "raw": True, "filter_type": "bilinear"}
    out: dict = {"type": "scene", "room": make_mesh(
        "room", glb.array(room_prim.attributes.POSITION), glb.array(room_prim.indices).reshape(-1, 3),
        glb.array(room_prim.attributes.TEXCOORD_0), bsdf=black,
        emitter=mi.load_dict({"type": "area", "radiance": radiance}))}
    if lights and glb.node("lights") is not None:
        defs = glb.doc.extensions["KHR_lights_punctual"]["lights"]
        for k in glb.node("lights").children:
            node = glb.doc.nodes[k]
            light = defs[node.extensions["KHR_lights_punctual"]["light"]]
            m = node_matrix(node)
            rgb = np.asarray(light["color"]) * light["intensity"] / LUMENS_PER_WATT
            out[node.name] = {"type": "spot", "cutoff_angle": math.degrees(light["spot"]["outerConeAngle"]),
                              "beam_width": math.degrees(light["spot"]["innerConeAngle"]),
                              "intensity": {"type": "rgb", "value": rgb.tolist()},
                              "to_world": mi.ScalarTransform4f().look_at(
                                  origin=m[:3, 3].tolist(), target=(m[:3, 3] - m[:3, 2]).tolist(),
                                  up=m[:3, 1].tolist())}
    for k, node in enumerate(glb.doc.nodes):
        if objects and node.name and node.name.startswith("object_"):
            out[node.name] = object_mesh(glb, node, k)
    return out


def object_mesh(glb: GlbFile, node, k: int):
    mi = mitsuba()
    prim = glb.doc.meshes[node.mesh].primitives[0]
    m = node_matrix(node)
    pos = glb.array(prim.attributes.POSITION) @ m[:3, :3].T + m[:3, 3]
    nrm = glb.array(prim.attributes.NORMAL) @ np.linalg.inv(m[:3, :3])
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    pbr = glb.doc.materials[prim.material].pbrMetallicRoughness
    base = [float(x) for x in pbr.baseColorFactor[:3]]
    if pbr.metallicFactor == 0 and pbr.roughnessFactor == 1:
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": base}}
    else:
        bsdf = {"type": "principled", "base_color": {"type": "rgb", "value": base},
                "roughness": float(pbr.roughnessFactor), "metallic": float(pbr.metallicFactor)}
    return make_mesh(f"object_{k}", pos, glb.array(prim.indices).reshape(-1, 3), normals=nrm,
                     bsdf=mi.load_dict(bsdf))


def render_view(scene: dict, yaw: float, pitch: float, fov_deg: float, size: int | tuple[int, int],
                spp: int, max_depth: int = 2, seed: int = 0) -> np.ndarray:
    """Linear RGB ``[h, w, 3]`` of a pinhole view from the origin (``phyir.pano.perspective_dirs``'
    camera: yaw toward +x, pitch up, radians; vertical ``fov_deg``); ``size``: w or (w, h)."""
    w, h = (size, size) if isinstance(size, int) else size
    mi = mitsuba()
    target = [math.cos(pitch) * math.sin(yaw), math.sin(pitch), -math.cos(pitch) * math.cos(yaw)]
    sensor = {"type": "perspective", "fov": fov_deg, "fov_axis": "y",
              "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=target, up=[0, 1, 0]),
              "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}},
              "sampler": {"type": "independent", "sample_count": spp}}
    loaded = mi.load_dict({**scene, "sensor": sensor,
                           "integrator": {"type": "path", "max_depth": max_depth}})
    return np.asarray(mi.render(loaded, seed=seed), dtype=np.float32)[..., :3]
