"""Writing the exported room as binary glTF 2.0 with pygltflib (docs/export.md: what is in the file).

One node per thing: ``room`` (the mesh, one primitive with two material variants), ``camera`` (at the
origin looking down -z, +y up: the panorama's centre), ``lights`` (a group of spot lights,
KHR_lights_punctual) and one node per inserted object.  The room's material variants
(KHR_materials_variants) share the geometry:

* ``photo`` (the default): black base colour, the panorama as emissive texture times
  KHR_materials_emissive_strength — a renderer sees the room exactly as photographed (the base
  image of :mod:`phyir.export.lights`: what is brighter than the lights' threshold is in the lights);
* ``pbr``: the predicted layers as glTF PBR textures (base colour = albedo, sRGB; metallicRoughness
  = roughness in G, metalness in B, linear), to be lit by the lights and the EXR environment.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field

import numpy as np
import pygltflib as gl

from phyir.color import linear_to_srgb
from phyir.export.lights import SPOT_OUTER, PunctualLight, spot_rotation
from phyir.export.room_mesh import RoomMesh
from phyir.insert.objects import SceneObject

VARIANTS = ("photo", "pbr")
EXTENSIONS = ("KHR_materials_emissive_strength", "KHR_materials_variants", "KHR_lights_punctual")


@dataclass
class RoomTextures:
    """8-bit images ``[H, W, C]`` of the room's materials and the emissive scale."""

    emissive: np.ndarray  # sRGB-encoded base image / emissive_strength
    emissive_strength: float
    base_color: np.ndarray | None = None  # sRGB albedo
    metallic_roughness: np.ndarray | None = None  # linear: G roughness, B metalness
    extras: dict = field(default_factory=dict)  # written to the file's root extras under "phyir"


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear values in [0, 1], ``[H, W, C]`` -> sRGB uint8."""
    return np.round(linear_to_srgb(linear) * 255).astype(np.uint8)


def png_bytes(img: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img), "RGB").save(buf, format="PNG", compress_level=4)
    return buf.getvalue()


class GlbBuilder:
    """A pygltflib document and its one binary buffer, filled view by view."""

    def __init__(self) -> None:
        self.doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator="phyir export"))
        self.blob = bytearray()

    def view(self, data: bytes, target: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)  # accessors need 4-byte alignment
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob),
                                                  byteLength=len(data), target=target))
        self.blob += data
        return len(self.doc.bufferViews) - 1

    def accessor(self, a: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        """An accessor of float32 vectors (``kind`` VEC2/VEC3) or uint32 indices (SCALAR)."""
        ctype = gl.UNSIGNED_INT if a.dtype == np.uint32 else gl.FLOAT
        flat = np.ascontiguousarray(a, dtype=np.uint32 if ctype == gl.UNSIGNED_INT else np.float32)
        acc = gl.Accessor(bufferView=self.view(flat.tobytes(), target), componentType=ctype,
                          count=len(flat) if kind != "SCALAR" else flat.size, type=kind)
        if bounds:  # required for POSITION
            acc.min, acc.max = flat.min(0).tolist(), flat.max(0).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def texture(self, img: np.ndarray, name: str) -> int:
        if not self.doc.samplers:  # wrap in longitude, clamp at the poles, filtered
            self.doc.samplers.append(gl.Sampler(magFilter=gl.LINEAR, minFilter=gl.LINEAR_MIPMAP_LINEAR,
                                                wrapS=gl.REPEAT, wrapT=gl.CLAMP_TO_EDGE))
        self.doc.images.append(gl.Image(bufferView=self.view(png_bytes(img)), mimeType=gl.IMAGEPNG,
                                        name=name))
        self.doc.textures.append(gl.Texture(source=len(self.doc.images) - 1, sampler=0, name=name))
        return len(self.doc.textures) - 1

    def material(self, m: gl.Material) -> int:
        self.doc.materials.append(m)
        return len(self.doc.materials) - 1

    def node(self, n: gl.Node) -> int:
        self.doc.nodes.append(n)
        return len(self.doc.nodes) - 1

    def save(self, path: str) -> None:
        self.doc.buffers = [gl.Buffer(byteLength=len(self.blob))]
        self.doc.set_binary_blob(bytes(self.blob))
        self.doc.save_binary(path)


def room_materials(b: GlbBuilder, tex: RoomTextures) -> list[int]:
    """The ``photo`` and (with the PBR layers) ``pbr`` materials, in :data:`VARIANTS` order."""
    photo = gl.Material(
        name="room_photo", emissiveFactor=[1.0, 1.0, 1.0],
        emissiveTexture=gl.TextureInfo(index=b.texture(tex.emissive, "panorama")),
        pbrMetallicRoughness=gl.PbrMetallicRoughness(baseColorFactor=[0.0, 0.0, 0.0, 1.0],
                                                     metallicFactor=0.0, roughnessFactor=1.0),
        extensions={"KHR_materials_emissive_strength": {"emissiveStrength": float(tex.emissive_strength)}})
    out = [b.material(photo)]
    if tex.base_color is not None and tex.metallic_roughness is not None:
        pbr = gl.Material(name="room_pbr", pbrMetallicRoughness=gl.PbrMetallicRoughness(
            baseColorTexture=gl.TextureInfo(index=b.texture(tex.base_color, "albedo")),
            metallicRoughnessTexture=gl.TextureInfo(index=b.texture(tex.metallic_roughness,
                                                                     "metallic_roughness")),
            metallicFactor=1.0, roughnessFactor=1.0))
        out.append(b.material(pbr))
    return out


def add_room(b: GlbBuilder, room: RoomMesh, tex: RoomTextures) -> int:
    mats = room_materials(b, tex)
    prim = gl.Primitive(
        attributes=gl.Attributes(
            POSITION=b.accessor(room.positions, "VEC3", gl.ARRAY_BUFFER, bounds=True),
            NORMAL=b.accessor(room.normals, "VEC3", gl.ARRAY_BUFFER),
            TEXCOORD_0=b.accessor(room.texcoords, "VEC2", gl.ARRAY_BUFFER)),
        indices=b.accessor(room.faces, "SCALAR", gl.ELEMENT_ARRAY_BUFFER), material=mats[0],
        extensions={"KHR_materials_variants": {"mappings": [
            {"material": m, "variants": [i]} for i, m in enumerate(mats)]}})
    b.doc.meshes.append(gl.Mesh(name="room", primitives=[prim]))
    b.doc.extensions.setdefault("KHR_materials_variants", {})["variants"] = [
        {"name": name} for name in VARIANTS[:len(mats)]]
    return b.node(gl.Node(name="room", mesh=len(b.doc.meshes) - 1))


def add_lights(b: GlbBuilder, lights: list[PunctualLight]) -> int:
    """A ``lights`` group node holding one spot-light node per light."""
    defs, children = [], []
    for k, light in enumerate(lights):
        defs.append({"name": f"light_{k}", "type": "spot", "color": list(light.color),
                     "intensity": float(light.intensity),
                     "spot": {"innerConeAngle": 0.0, "outerConeAngle": SPOT_OUTER}})
        children.append(b.node(gl.Node(name=f"light_{k}", translation=light.position.tolist(),
                                       rotation=list(spot_rotation(light.direction)),
                                       extensions={"KHR_lights_punctual": {"light": k}})))
    b.doc.extensions["KHR_lights_punctual"] = {"lights": defs}
    return b.node(gl.Node(name="lights", children=children))


def add_object(b: GlbBuilder, obj: SceneObject, k: int) -> int:
    """An inserted object: its mesh (local frame) under a node with its model matrix, PBR factors."""
    m = obj.material
    mat = b.material(gl.Material(name=f"{obj.name}_material", pbrMetallicRoughness=gl.PbrMetallicRoughness(
        baseColorFactor=[*map(float, m.base_color), 1.0], metallicFactor=float(m.metallic),
        roughnessFactor=float(m.roughness)), doubleSided=not obj.mesh.closed))
    mesh = obj.mesh
    prim = gl.Primitive(attributes=gl.Attributes(
        POSITION=b.accessor(mesh.vertices, "VEC3", gl.ARRAY_BUFFER, bounds=True),
        NORMAL=b.accessor(mesh.normals, "VEC3", gl.ARRAY_BUFFER)),
        indices=b.accessor(np.asarray(mesh.faces, np.uint32), "SCALAR", gl.ELEMENT_ARRAY_BUFFER),
        material=mat)
    b.doc.meshes.append(gl.Mesh(name=obj.name, primitives=[prim]))
    matrix = obj.model_matrix().T.ravel().tolist()  # glTF matrices are column-major
    return b.node(gl.Node(name=f"object_{k}_{obj.name}", mesh=len(b.doc.meshes) - 1, matrix=matrix))


def write_glb(path: str, room: RoomMesh, tex: RoomTextures, lights: list[PunctualLight],
              objects: list[SceneObject] = (), fov_deg: float = 60.0, aspect: float = 1.5,
              camera_rotation: np.ndarray | None = None) -> None:
    """Write the whole document to ``path`` (not atomic: callers write to a temporary).
    ``camera_rotation``: the camera's camera-to-world 3x3 (looking along its -z, +y up, as glTF's),
    e.g. a viewer's perspective view; default: looking along -z."""
    b = GlbBuilder()
    b.doc.extensions = {}
    nodes = [add_room(b, room, tex)]
    b.doc.cameras.append(gl.Camera(name="camera", type=gl.PERSPECTIVE, perspective=gl.Perspective(
        yfov=math.radians(fov_deg), aspectRatio=aspect, znear=0.05)))
    pose = np.eye(4)
    if camera_rotation is not None:
        pose[:3, :3] = camera_rotation
    nodes.append(b.node(gl.Node(name="camera", camera=0, matrix=pose.T.ravel().tolist())))
    if lights:
        nodes.append(add_lights(b, lights))
    nodes += [add_object(b, obj, k) for k, obj in enumerate(objects)]
    b.doc.scenes = [gl.Scene(name="room", nodes=nodes)]
    b.doc.scene = 0
    b.doc.extensionsUsed = [e for e in EXTENSIONS if e in b.doc.extensions
                            or e == "KHR_materials_emissive_strength"]
    if tex.extras:
        b.doc.extras = {"phyir": tex.extras}
    b.save(path)
