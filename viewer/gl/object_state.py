"""Per-object GPU state of the insertion renderer (``viewer.insertion``): mesh buffers, and each
object's lighting (the probe interpolated at its centre, its mip pyramid, irradiance map and the
dominant lights' shadow cameras) uploaded as small textures, recomputed only when the object moved."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import moderngl
import numpy as np
import torch

from phyir.insert.objects import Mesh, SceneObject
from phyir.insert.views import look_at, perspective
from phyir.lighting.object_lighting import HALO, ObjectLighting, object_lighting
from viewer.gl.quality import FULL, Quality


@dataclass
class Tile:
    vp: np.ndarray  # world -> clip
    rect: tuple[int, int, int, int]  # (x, y, w, h) texels in the atlas (GL, from the bottom)


@dataclass
class ObjectGPU:
    obj: SceneObject
    key: tuple
    lighting: ObjectLighting
    env: moderngl.Texture
    spec: moderngl.Texture
    irr: moderngl.Texture
    amb_full: np.ndarray  # [6, 3]
    amb_bounce: np.ndarray  # [6, 3] what the object's surface receives (its shadow on the support darkens it)
    centre: np.ndarray
    radius: float
    raw_probe: torch.Tensor  # the interpolated probe the lighting was computed from
    reach: np.ndarray  # [P, 3] lighting.reach moved with the object
    halo: float = HALO
    lights: list = field(default_factory=list)  # (PlacedLight, view_proj, tan, near, size_m)

    def release(self) -> None:
        for t in (self.env, self.spec, self.irr):
            t.release()


def _hwc_bytes(t: torch.Tensor) -> bytes:
    """A [C, h, w] tensor as h x w x C float32 texture data."""
    return np.ascontiguousarray(t.permute(1, 2, 0).numpy(), np.float32).tobytes()


class ObjectStates:
    """The mesh buffers and per-object lighting of :class:`viewer.insertion.InsertionRenderer` (a
    part of it: ``ctx``, ``field``, ``surface``, ``probe_texture`` and ``_equirect`` are the renderer's)."""

    _meshes: dict[int, tuple]
    _objects: dict[int, ObjectGPU]

    # -- meshes and per-object lighting -------------------------------------------------------
    def _mesh(self, m: Mesh) -> tuple:
        key = id(m)
        if key not in self._meshes:
            data = np.hstack([m.vertices, m.normals]).astype(np.float32)
            vbo = self.ctx.buffer(data.tobytes())
            ibo = self.ctx.buffer(m.faces.astype(np.uint32).tobytes())
            self._meshes[key] = (m, vbo, ibo, {})
        return self._meshes[key]

    def forget(self, objects: list[SceneObject]) -> None:
        """Release the lighting of objects that are gone and the buffers of meshes no object uses
        (in the viewer objects come and go: each added object has a new mesh).  Every draw calls it
        first with the objects it draws."""
        alive = {id(o) for o in objects}
        for k in [k for k in self._objects if k not in alive]:
            self._objects.pop(k).release()
        used = {id(m) for o in objects for m in (o.mesh, *o.mesh.lods.values())}
        for k in [k for k in self._meshes if k not in used]:
            _mesh, vbo, ibo, vaos = self._meshes.pop(k)
            for v in vaos.values():
                v.release()
            vbo.release()
            ibo.release()

    def _vao(self, mesh: Mesh, prog: moderngl.Program) -> moderngl.VertexArray:
        m, vbo, ibo, vaos = self._mesh(mesh)
        if id(prog) not in vaos:
            if "in_normal" in prog:
                fmt = [(vbo, "3f 3f", "in_position", "in_normal")]
            else:
                fmt = [(vbo, "3f 12x", "in_position")]
            vaos[id(prog)] = self.ctx.vertex_array(prog, fmt, index_buffer=ibo, index_element_size=4)
        return vaos[id(prog)]

    def object_state(self, obj: SceneObject, quality: Quality = FULL) -> ObjectGPU:
        """The object's lighting and textures, recomputed only when it moved, changed size or the
        quality changed (lights are placed with fewer marching steps while dragging).  With
        ``quality.relight_tolerance`` a moved object keeps its lighting (textures, lights) while the
        probe interpolated at its new centre differs from the one it was lit with by less than that
        (relative L1); only its position-dependent parts (shadow cameras, reach) follow it."""
        support = None if obj.support is None else np.concatenate(obj.support).round(6).tobytes()
        key = (id(obj.mesh), obj.scale, obj.position.round(6).tobytes(), obj.rotation.round(6).tobytes(),
               support, quality.march_steps)
        st = self._objects.get(id(obj))
        if st is not None and st.key == key:
            st.obj = obj
            return st
        centre, radius = obj.bounding_sphere()
        # while dragging: one ray per texel, on the light grid (mostly cached)
        raw = self.field.probe_at(torch.as_tensor(centre, dtype=torch.float32),
                                  draft=quality.light_grid > 0, grid=quality.light_grid)
        same_shape = st is not None and st.key[:2] == key[:2] and st.key[-1] == key[-1]
        if same_shape and quality.relight_tolerance > 0:
            change = float((raw - st.raw_probe).abs().sum() / st.raw_probe.abs().sum().clamp(min=1e-12))
            if change < quality.relight_tolerance:
                st.obj, st.key, st.halo = obj, key, quality.halo
                st.reach = st.lighting.reach.numpy() + (centre - st.lighting.centre.numpy())
                st.centre, st.radius = centre, radius
                st.lights = self._light_cameras(st.lighting, centre, radius)
                return st
        point, normal = obj.support if obj.support is not None else (centre - [0, radius, 0], (0, 1, 0))
        lighting = object_lighting(self.field, torch.as_tensor(centre, dtype=torch.float32), self.surface,
                                   radius=radius, steps=quality.march_steps,
                                   support=(torch.as_tensor(point), torch.as_tensor(normal)), probe=raw,
                                   previous=st.lighting if same_shape and quality.reuse_lights else None)
        env, spec, irr = self._lighting_textures(lighting, st)
        st = ObjectGPU(obj, key, lighting, env, spec, irr, lighting.ambient.numpy(),
                        lighting.ambient_bounce.numpy(), centre, radius, raw, lighting.reach.numpy(),
                        quality.halo)
        st.lights = self._light_cameras(lighting, centre, radius)
        self._objects[id(obj)] = st
        return st

    def _lighting_textures(self, lighting: ObjectLighting, old: ObjectGPU | None) -> tuple:
        """(env, spec, irr) textures of ``lighting``: ``old``'s rewritten when their sizes match (a
        dragged object: no new textures, no mipmap generation), else new ones (``old``'s released)."""
        h, w = lighting.mips[0].shape[-2:]
        if old is not None and old.env.size == (w, h) and old.irr.size == lighting.irradiance.shape[:0:-1]:
            for tex, levels in ((old.env, lighting.mips), (old.spec, lighting.spec_mips)):
                for k, lv in enumerate(levels):
                    tex.write(_hwc_bytes(lv), level=k)
            old.irr.write(_hwc_bytes(lighting.irradiance))
            return old.env, old.spec, old.irr
        if old is not None:
            old.release()
        return (self.probe_texture(lighting.mips), self.probe_texture(lighting.spec_mips),
                self._equirect(lighting.irradiance.permute(1, 2, 0).numpy()))

    @staticmethod
    def _light_cameras(lighting: ObjectLighting, centre: np.ndarray, radius: float) -> list:
        """Per placed light: (light, view_proj, tan of the half field of view, near, source radius in
        metres) of the shadow camera at the light aimed at the object's bounding sphere."""
        out = []
        for pl in lighting.lights:
            dist = float(np.linalg.norm(pl.position.numpy() - centre))
            if dist <= radius * 1.05:  # the light is inside the object's bounds: no useful shadow
                continue
            half = math.asin(min(radius / dist, 0.95)) * 1.1 + 0.01
            tan = math.tan(half)
            near = max(dist - radius, 0.01) * 0.8
            vp = perspective(tan, near, dist + 1.2 * radius) @ look_at(pl.position.numpy(), centre)
            size = math.tan(min(pl.light.spread, 1.2)) * pl.distance
            out.append((pl, vp, tan, near, size))
        return out
