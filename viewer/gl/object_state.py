"""Per-object GPU state of the insertion renderer (``viewer.insertion``): mesh buffers, and each
object's lighting (the probe interpolated at its centre, its mip pyramid, irradiance map and the
dominant lights' shadow cameras) uploaded as small textures, recomputed only when the object moved.
With ``Quality.background_lighting`` (the viewer while dragging) a moved object's lighting is
computed on a worker thread and swapped in when ready; frames meanwhile use the last one."""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
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
    lit_key: tuple | None = None  # the key its lighting was computed for (background lighting: may lag)
    lights: list = field(default_factory=list)  # (PlacedLight, view_proj, tan, near, size_m)

    def release(self) -> None:
        for t in (self.env, self.spec, self.irr):
            t.release()


@dataclass
class Relight:
    """A background lighting job: for ``key`` (the object's key when it was asked for) at ``quality``;
    ``future`` gives (raw probe, ObjectLighting or None: the probe changed less than the tolerance)."""

    future: Future
    key: tuple
    quality: Quality


def state_key(obj: SceneObject, quality: Quality) -> tuple:
    """What an object's lighting and atlas tiles depend on: its mesh, size, place and support, and
    the marching steps its lights were placed with."""
    support = None if obj.support is None else np.concatenate(obj.support).round(6).tobytes()
    return (id(obj.mesh), obj.scale, obj.position.round(6).tobytes(), obj.rotation.round(6).tobytes(),
            support, quality.march_steps)


def _hwc_bytes(t: torch.Tensor) -> bytes:
    """A [C, h, w] tensor as h x w x C float32 texture data."""
    return np.ascontiguousarray(t.permute(1, 2, 0).numpy(), np.float32).tobytes()


class ObjectStates:
    """The mesh buffers and per-object lighting of :class:`viewer.insertion.InsertionRenderer` (a
    part of it: ``ctx``, ``field``, ``surface``, ``probe_texture`` and ``equirect_texture`` are the
    renderer's)."""

    def __init__(self):
        self._meshes: dict[int, tuple] = {}
        self._field_lock = threading.Lock()  # the probe field's caches: one thread at a time
        self._relight_after = 0.0  # time.monotonic() before which no background job starts
        self.own_object_states()

    def own_object_states(self) -> None:
        """Start object states and a lighting worker of its own (empty); the meshes and the field's
        lock stay (a fork shares them)."""
        self._objects: dict[int, ObjectGPU] = {}
        self._relights: dict[int, Relight] = {}  # id(obj) -> its background lighting job (one each)
        self._relight_pool: ThreadPoolExecutor | None = None

    def release_object_states(self) -> None:
        """Drop the background lighting jobs and free every object's state."""
        self._relights.clear()
        for st in self._objects.values():
            st.release()
        self._objects.clear()

    def release_meshes(self) -> None:
        """Free the mesh buffers and their vertex arrays."""
        for _mesh, vbo, ibo, vaos in self._meshes.values():
            for v in vaos.values():
                v.release()
            vbo.release()
            ibo.release()
        self._meshes.clear()

    def stop_lighting_worker(self, cancel: bool = False) -> None:
        """Shut the background lighting thread down (``cancel``: drop the jobs that have not started)."""
        if self._relight_pool is not None:
            if cancel:
                self._relight_pool.shutdown(cancel_futures=True)
            else:
                self._relight_pool.shutdown()

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
        for k in [k for k in self._relights if k not in alive]:
            del self._relights[k]  # it finishes unseen (the field's lock keeps it apart)
        used = {id(m) for o in objects for m in (o.mesh, *o.mesh.lods.values())}
        for k in [k for k in self._meshes if k not in used]:
            _mesh, vbo, ibo, vaos = self._meshes.pop(k)
            for v in vaos.values():
                v.release()
            vbo.release()
            ibo.release()

    def vertex_array(self, mesh: Mesh, prog: moderngl.Program) -> moderngl.VertexArray:
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
        (relative L1); only its position-dependent parts (shadow cameras, reach) follow it.  With
        ``quality.background_lighting`` a moved object's lighting is computed on a worker thread:
        it keeps the last lighting (moved with it) until that is ready (:meth:`lighting_pending`)."""
        key = state_key(obj, quality)
        st = self._objects.get(id(obj))
        if st is not None:
            self._take_relight(st)
        if st is not None and st.key == key:
            st.obj = obj
            if quality.background_lighting and st.lit_key != key:
                self._relight_later(st, quality)
            return st
        centre, radius = obj.bounding_sphere()
        same_shape = st is not None and st.key[:2] == key[:2] and st.key[-1] == key[-1]
        if same_shape and quality.background_lighting:
            self._move(st, obj, key, centre, radius, quality.halo)
            self._relight_later(st, quality)
            return st
        self._relights.pop(id(obj), None)
        with self._field_lock:  # waits for a background job still using the field
            old = (st.raw_probe, st.lighting) if same_shape else None
            raw, lighting = self._lighting_at(obj.support, centre, radius, quality, old)
        if lighting is None:  # the probe changed less than the tolerance
            self._move(st, obj, key, centre, radius, quality.halo)
            st.lit_key = key
            return st
        return self._install(obj, key, raw, lighting, quality.halo, st)

    def _install(self, obj: SceneObject, key: tuple, raw: torch.Tensor, lighting: ObjectLighting,
                 halo: float, old: ObjectGPU | None) -> ObjectGPU:
        """The object's state lit by ``lighting`` (GL thread: uploads its textures, ``old``'s reused
        when their sizes match)."""
        centre, radius = obj.bounding_sphere()
        env, spec, irr = self._lighting_textures(lighting, old)
        st = ObjectGPU(obj, key, lighting, env, spec, irr, lighting.ambient.numpy(),
                       lighting.ambient_bounce.numpy(), centre, radius, raw, lighting.reach.numpy(),
                       halo, key)
        st.lights = self._light_cameras(lighting, centre, radius)
        self._objects[id(obj)] = st
        return st

    def _lighting_at(self, support: tuple | None, centre: np.ndarray, radius: float, quality: Quality,
                     old: tuple[torch.Tensor, ObjectLighting] | None
                     ) -> tuple[torch.Tensor, ObjectLighting | None]:
        """(the probe at ``centre``, the object's lighting there); None for the lighting when the
        probe differs from ``old``'s (raw probe, lighting) by less than ``quality.relight_tolerance``.
        Any thread, holding the field's lock."""
        # while dragging: one ray per texel, on the light grid (mostly cached)
        raw = self.field.probe_at(torch.as_tensor(centre, dtype=torch.float32),
                                  draft=quality.light_grid > 0, grid=quality.light_grid)
        if old is not None and quality.relight_tolerance > 0:
            change = float((raw - old[0]).abs().sum() / old[0].abs().sum().clamp(min=1e-12))
            if change < quality.relight_tolerance:
                return raw, None
        point, normal = support if support is not None else (centre - [0, radius, 0], (0, 1, 0))
        lighting = object_lighting(self.field, torch.as_tensor(centre, dtype=torch.float32), self.surface,
                                   radius=radius, steps=quality.march_steps,
                                   support=(torch.as_tensor(point), torch.as_tensor(normal)), probe=raw,
                                   previous=old[1] if old is not None and quality.reuse_lights else None)
        return raw, lighting

    def _move(self, st: ObjectGPU, obj: SceneObject, key: tuple, centre: np.ndarray, radius: float,
              halo: float) -> None:
        """``st`` keeps its lighting; its position-dependent parts (reach, shadow cameras) follow."""
        st.obj, st.key, st.halo = obj, key, halo
        st.reach = st.lighting.reach.numpy() + (centre - st.lighting.centre.numpy())
        st.centre, st.radius = centre, radius
        st.lights = self._light_cameras(st.lighting, centre, radius)

    # -- background lighting (the viewer while dragging) --------------------------------------
    def lighting_ready(self, objects: list[SceneObject], quality: Quality) -> bool:
        """The visible objects' lighting at ``quality``, computed on the worker thread: starts a job
        for each object whose state is missing or outdated (for where it now is), installs the
        finished ones (GL thread: uploads their textures).  True once every state is current, so
        that :meth:`object_state` computes nothing (the viewer's refinement, ``viewer.refinement``).
        The lighting is the one :meth:`object_state` computes, without a previous one to reuse."""
        ready = True
        for obj in objects:
            if not obj.visible:
                continue
            key = state_key(obj, quality)
            st = self._objects.get(id(obj))
            job = self._relights.get(id(obj))
            if st is not None and st.key == key and st.lit_key == key:
                self._relights.pop(id(obj), None)  # a job for a place the object has left
                continue
            if job is not None and job.key == key and job.future.done():
                del self._relights[id(obj)]
                raw, lighting = job.future.result()  # (never None: no previous lighting to keep)
                self._install(obj, key, raw, lighting, quality.halo, st)
                continue
            ready = False
            if job is None or job.key != key:  # (a job for where it was finishes unseen)
                centre, radius = obj.bounding_sphere()
                args = (obj.support, centre, radius, quality, None)
                self._relights[id(obj)] = Relight(self._submit(args), key, quality)
        return ready

    def _submit(self, args: tuple) -> Future:
        """``_lighting_at(*args)`` on the worker thread, holding the field's lock."""
        if self._relight_pool is None:
            self._relight_pool = ThreadPoolExecutor(1, thread_name_prefix="phyir-relight")

        def job() -> tuple[torch.Tensor, ObjectLighting | None]:
            with self._field_lock:
                return self._lighting_at(*args)

        return self._relight_pool.submit(job)

    def _relight_later(self, st: ObjectGPU, quality: Quality) -> None:
        """Compute ``st``'s lighting where its object now is on the worker thread, unless a job for it
        is running (when that one is taken, the latest position gets the next) or the last one ended
        less than ``quality.relight_interval`` ago (the worker would take a core from the frames)."""
        if id(st.obj) in self._relights or time.monotonic() < self._relight_after:
            return
        # the job gets what the UI thread may change meanwhile as it is now
        args = (st.obj.support, st.centre, st.radius, quality, (st.raw_probe, st.lighting))
        self._relights[id(st.obj)] = Relight(self._submit(args), st.key, quality)

    def _take_relight(self, st: ObjectGPU) -> None:
        """Swap in ``st``'s finished background lighting (GL thread: uploads its textures)."""
        job = self._relights.get(id(st.obj))
        if job is None or not job.future.done():
            return
        del self._relights[id(st.obj)]
        raw, lighting = job.future.result()
        self._relight_after = time.monotonic() + job.quality.relight_interval
        st.raw_probe, st.lit_key = raw, job.key
        if lighting is not None:
            st.env, st.spec, st.irr = self._lighting_textures(lighting, st)
            st.lighting, st.raw_probe = lighting, raw
            st.amb_full, st.amb_bounce = lighting.ambient.numpy(), lighting.ambient_bounce.numpy()
        self._move(st, st.obj, st.key, st.centre, st.radius, st.halo)

    def lighting_pending(self) -> bool:
        """Whether a background lighting job is running or waits to be swapped in, or an object's
        lighting lags its position (frames should go on)."""
        return bool(self._relights) or any(st.lit_key != st.key for st in self._objects.values())

    def wait_lighting(self) -> None:
        """Wait for the background lighting jobs (the next :meth:`object_state` swaps them in)."""
        for job in list(self._relights.values()):
            job.future.result()

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
                self.equirect_texture(lighting.irradiance.permute(1, 2, 0).numpy()))

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
