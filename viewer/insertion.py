"""Virtual object insertion on the GPU (ModernGL): shading, shadows and compositing (docs/insertion.md).

:class:`InsertionRenderer` works on any moderngl context: the viewer's window (as a linear pass of
:class:`viewer.renderer.Renderer`, see :meth:`InsertionRenderer.linear_pass`) or a headless EGL
context (:meth:`InsertionRenderer.render_view`, used by ``phyir insert``).  Per frame:

1. each object's lighting (CPU, torch, only when it moved): the probe interpolated at its centre
   (:class:`phyir.lighting.object_lighting.ProbeField`), its mip pyramid, exact irradiance map and dominant
   lights placed in the room (:mod:`phyir.lighting.extract`), uploaded as small textures;
2. each object is drawn into its own tile of an *impostor atlas* by a perspective camera at the
   panorama's centre aimed at it (``object.frag``: IBL with the BRDF of phyir.shading.brdf, parallax-corrected
   mirror reflections, scene-occludes-object test); every view (equirect, perspective, export) then
   looks the object up by direction, so seams and poles need no special case;
3. each dominant light renders the object's distance into a *shadow atlas* tile (``shadow.frag``);
4. ``composite.frag`` runs over the view pixels the objects and their shadows can reach: receivers
   lose the light the object blocks and gain what it bounces (D.2's I_all - I_pl), the object's pixels
   take its radiance.  Fusion ``differential`` shades the object seeing the virtual supporting plane
   (I_all), ``three-image`` seeing the environment itself (I_obj).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import moderngl
import numpy as np
import torch

from phyir import pano
from phyir.errors import PhyIRError
from phyir.insert.objects import Material, Mesh, SceneObject
from phyir.lighting.object_lighting import (
    HALO,
    N_HALO,
    ObjectLighting,
    ProbeField,
    irradiance_map,
    object_lighting,
    peak_samples,
    probe_mips,
)
from phyir.lighting.projection import DepthSurface
from phyir.scene import PanoScene
from phyir.shading import prefilter
from phyir.shading.brdf import f0_from_material
from phyir.shading.render import MIRROR_ROUGHNESS
from viewer import glsl
from viewer.view import EquirectView, PerspectiveView

MAX_OBJECTS, MAX_LIGHTS, MAX_PROXIES = 8, 16, 64  # shaders/composite.frag
FUSIONS = ("three-image", "differential")
MAX_TILE = 2048
IMAGE_HALF_MAX = 65000.0


@dataclass(frozen=True)
class Quality:
    """Cost knobs: full quality for still frames and export, lower while dragging."""

    spec_samples: int = 128  # GGX samples per pixel for glossy objects (ibl.glsl)
    shadow_size: int = 512  # texels per shadow-map tile
    supersample: float = 1.5  # impostor texels per output pixel (per axis)
    march_steps: int = 32  # depth-panorama marching steps (mirror reflections, placing lights)
    shadow_taps: int = 16  # PCSS blocker-search and filter taps
    peak_subsamples: bool = True  # 2 x 2 samples per peak texel (else one at its centre)
    glossy_receivers: bool = True  # the object replaces what glossy receivers reflect
    halo: float = HALO  # receivers' ambient occlusion reaches this many bounding radii
    relight_tolerance: float = 0.0  # keep the lighting of a moved object while its probe changed less
    impostor_faces: int = 0  # draw the impostor from a decimated mesh of at most this many triangles (0: all)
    shadow_faces: int = 0  # the same for the shadow maps
    proxy_lookups: bool = True  # composite: the radiance an object hides per proxy sphere (else per object)
    blocker_search: bool = True  # composite: PCSS blocker search (else the blocker at the object's bounds)
    reuse_lights: bool = False  # a moved object keeps its lights' room positions (reuse_lights)
    own_shadow_bounds: bool = False  # object.frag: its own contact shadow from its bounding sphere


FULL = Quality(supersample=1.5)
DRAGGING = Quality(spec_samples=4, shadow_size=256, supersample=1.0, march_steps=16, shadow_taps=8,
                   peak_subsamples=False, glossy_receivers=False, halo=3.0, relight_tolerance=0.03,
                   impostor_faces=2048, shadow_faces=1024, proxy_lookups=False, blocker_search=False,
                   reuse_lights=True, own_shadow_bounds=True)


# ---------------------------------------------------------------------------------------------
# matrices (numpy, row-major; transposed when written to GLSL's column-major uniforms)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    f = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    f /= np.linalg.norm(f)
    up = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, np.float64)
    return m


def perspective(tan_half: float, near: float, far: float) -> np.ndarray:
    return np.array([[1 / tan_half, 0, 0, 0], [0, 1 / tan_half, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])


def _mat(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(np.asarray(m, np.float32).T).tobytes()


def _uniform(prog: moderngl.Program, name: str, value) -> None:
    if name in prog:
        prog[name] = value


def _write(prog: moderngl.Program, name: str, data: np.ndarray, dtype=np.float32) -> None:
    """Write a uniform array, zero-padded to its declared length."""
    if name not in prog:
        return
    u = prog[name]
    a = np.asarray(data, dtype).reshape(-1)
    full = np.zeros(u.array_length * u.dimension, dtype)
    full[:a.size] = a[:full.size]
    u.write(full.tobytes())


def pixel_angle(view: EquirectView | PerspectiveView, view_size: tuple[int, int],
                pano_size: tuple[int, int]) -> float:
    """Radians per screen pixel at the view's centre."""
    if isinstance(view, PerspectiveView):
        return 2 * math.tan(math.radians(view.fov) / 2) / view_size[1]
    return (2 * math.pi / pano_size[1]) / view.zoom


# ---------------------------------------------------------------------------------------------
# per-object GPU state


@dataclass
class _Tile:
    vp: np.ndarray  # world -> clip
    rect: tuple[int, int, int, int]  # (x, y, w, h) texels in the atlas (GL, from the bottom)


@dataclass
class _ObjectGPU:
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


class InsertionRenderer:
    """Inserted objects over one scene (see the module doc).  All methods run on the GL thread."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self._programs: dict[tuple, moderngl.Program] = {}
        self._meshes: dict[int, tuple] = {}
        self._objects: dict[int, _ObjectGPU] = {}
        self._fbos: dict[str, tuple] = {}
        self.scene: PanoScene | None = None
        self.field: ProbeField | None = None
        self.surface: DepthSurface | None = None
        table = prefilter.dfg_table().permute(1, 2, 0).contiguous().numpy()  # [R, n.v, 2]
        self.dfg = ctx.texture((table.shape[1], table.shape[0]), 2, table.astype(np.float32).tobytes(),
                               dtype="f4")
        self.dfg.repeat_x = self.dfg.repeat_y = False
        self.dfg.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._scene_tex: dict[str, moderngl.Texture] = {}
        self.use_projection = True  # mirror reflections from the depth panorama (else the probe only)
        self.footprint_scale = 1.0  # 0: point-sampled mirror reflections (as a path tracer's pixel centres)
        self.drawn_faces = {"impostor": 0, "shadow": 0}  # triangles the last prepare() drew per pass

    # -- programs ----------------------------------------------------------------------------
    def program(self, vert: str, frag: str, **defines: int) -> moderngl.Program:
        key = (vert, frag, *sorted(defines.items()))
        if key not in self._programs:
            self._programs[key] = glsl.program(self.ctx, vert, frag, defines)
        return self._programs[key]

    def _fullscreen(self, prog: moderngl.Program) -> moderngl.VertexArray:
        key = ("vao", id(prog))
        if key not in self._fbos:
            self._fbos[key] = (self.ctx.vertex_array(prog, []),)
        return self._fbos[key][0]

    # -- textures ----------------------------------------------------------------------------
    def _equirect(self, array: np.ndarray, dtype: str = "f4", nearest: bool = False,
                  mipmaps: bool = False) -> moderngl.Texture:
        a = np.ascontiguousarray(array)
        h, w = a.shape[:2]
        c = 1 if a.ndim == 2 else a.shape[2]
        np_dtype = np.float16 if dtype == "f2" else np.float32
        tex = self.ctx.texture((w, h), c, a.astype(np_dtype).tobytes(), dtype=dtype)
        tex.repeat_x, tex.repeat_y = True, False
        if mipmaps:
            tex.build_mipmaps()
            tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        else:
            f = moderngl.NEAREST if nearest else moderngl.LINEAR
            tex.filter = (f, f)
        return tex

    def probe_texture(self, levels: list[torch.Tensor]) -> moderngl.Texture:
        """A probe with its area-weighted mip levels ``[3, h/2^k, w/2^k]`` (object_lighting.probe_mips)."""
        tex = self._equirect(levels[0].permute(1, 2, 0).numpy(), mipmaps=True)
        tex.build_mipmaps(0, len(levels) - 1)
        for k, lv in enumerate(levels[1:], 1):
            tex.write(np.ascontiguousarray(lv.permute(1, 2, 0).numpy(), np.float32).tobytes(), level=k)
        return tex

    def set_scene(self, scene: PanoScene) -> None:
        """Upload the panorama's layers and build its probe field and depth surface."""
        for name in ("depth", "probes"):
            if getattr(scene, name) is None:
                raise PhyIRError(f"insertion needs the scene's {name} layer")
        self.release_scene()
        self.scene = scene
        self.field = ProbeField(scene)
        self.surface = DepthSurface.from_scene(scene)
        hwc = lambda t: t.permute(1, 2, 0).float().numpy()  # noqa: E731
        normal = scene.normal if scene.normal is not None else pano.normals_from_depth(scene.depth.float())
        tex = self._scene_tex
        tex["scene_depth"] = self._equirect(scene.depth[0].float().numpy(), nearest=True)
        tex["scene_normal"] = self._equirect(hwc(normal), "f2", nearest=True)
        albedo = scene.albedo if scene.albedo is not None else torch.full_like(scene.image, 0.5)
        tex["scene_albedo"] = self._equirect(hwc(albedo), "f2")
        # float32 keeps untouched pixels bit-exact in exports; half floats above 4K (memory)
        image = hwc(scene.image)
        big = scene.size[1] > 4096
        tex["scene_image"] = self._equirect(np.minimum(image, IMAGE_HALF_MAX) if big else image,
                                            "f2" if big else "f4", mipmaps=True)
        tex["march_depth"] = self._equirect(self.surface.depth_tex[0, 0, :, 1:-1].numpy())
        tex["march_jump"] = self._equirect(self.surface.jump_tex[0, 0, :, 1:-1].numpy(), nearest=True)
        rough = scene.roughness if scene.roughness is not None else torch.ones_like(scene.depth)
        metal = scene.metallic if scene.metallic is not None else torch.zeros_like(scene.depth)
        tex["scene_rm"] = self._equirect(hwc(torch.cat([rough, metal])), nearest=True)
        self.has_albedo = scene.albedo is not None

    def release_scene(self) -> None:
        for t in self._scene_tex.values():
            t.release()
        self._scene_tex.clear()
        for st in self._objects.values():
            st.release()
        self._objects.clear()

    def _bind_scene(self, prog: moderngl.Program, first_unit: int = 3) -> None:
        """Units 3-9: the panorama's layers (units 0-2 and 10-15 are the passes' own)."""
        for k, name in enumerate(("scene_depth", "scene_normal", "scene_albedo", "scene_image",
                                  "march_depth", "march_jump", "scene_rm")):
            self._scene_tex[name].use(first_unit + k)
            _uniform(prog, name, first_unit + k)
        H, W = self.scene.size
        _uniform(prog, "scene_size", (float(W), float(H)))
        _uniform(prog, "r_bound", float(self.surface.r_bound))
        _uniform(prog, "jump_threshold", float(self.surface.jump_threshold))

    # -- meshes and per-object lighting -------------------------------------------------------
    def _mesh(self, m: Mesh) -> tuple:
        key = id(m)
        if key not in self._meshes:
            data = np.hstack([m.vertices, m.normals]).astype(np.float32)
            vbo = self.ctx.buffer(data.tobytes())
            ibo = self.ctx.buffer(m.faces.astype(np.uint32).tobytes())
            self._meshes[key] = (m, vbo, ibo, {})
        return self._meshes[key]

    def _forget(self, objects: list[SceneObject]) -> None:
        """Release the lighting of objects that are gone and the buffers of meshes no object uses
        (in the viewer objects come and go: each added object has a new mesh)."""
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

    def object_state(self, obj: SceneObject, quality: Quality = FULL) -> _ObjectGPU:
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
        raw = self.field.probe_at(torch.as_tensor(centre, dtype=torch.float32))
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
        st = _ObjectGPU(obj, key, lighting, env, spec, irr, lighting.ambient.numpy(),
                        lighting.ambient_bounce.numpy(), centre, radius, raw, lighting.reach.numpy(),
                        quality.halo)
        st.lights = self._light_cameras(lighting, centre, radius)
        self._objects[id(obj)] = st
        return st

    def _lighting_textures(self, lighting: ObjectLighting, old: _ObjectGPU | None) -> tuple:
        """(env, spec, irr) textures of ``lighting``: ``old``'s rewritten when their sizes match (a
        dragged object: no new textures, no mipmap generation), else new ones (``old``'s released)."""
        hwc = lambda t: np.ascontiguousarray(t.permute(1, 2, 0).numpy(), np.float32).tobytes()  # noqa: E731
        h, w = lighting.mips[0].shape[-2:]
        if old is not None and old.env.size == (w, h) and old.irr.size == lighting.irradiance.shape[:0:-1]:
            for tex, levels in ((old.env, lighting.mips), (old.spec, lighting.spec_mips)):
                for k, lv in enumerate(levels):
                    tex.write(hwc(lv), level=k)
            old.irr.write(hwc(lighting.irradiance))
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

    # -- passes -------------------------------------------------------------------------------
    def _atlas(self, name: str, size: tuple[int, int], components: int, depth: bool) -> moderngl.Framebuffer:
        """A framebuffer at least ``size`` large (grown, never shrunk, so dragging doesn't reallocate)."""
        have = self._fbos.get(name)
        if have is not None and have[1].size[0] >= size[0] and have[1].size[1] >= size[1]:
            return have[0]
        if have is not None:
            for r in have[1:]:
                r.release()
            have[0].release()
        w = max(size[0], have[1].size[0] if have else 0)
        h = max(size[1], have[1].size[1] if have else 0)
        colour = self.ctx.texture((w, h), components, dtype="f4")
        colour.filter = (moderngl.LINEAR, moderngl.LINEAR)
        colour.repeat_x = colour.repeat_y = False
        rb = self.ctx.depth_renderbuffer((w, h))
        fbo = self.ctx.framebuffer([colour], rb if depth else None)
        self._fbos[name] = (fbo, colour, rb)
        return fbo

    def prepare(self, objects: list[SceneObject], angle: float, quality: Quality = FULL,
                fusion: str = "three-image") -> list[tuple[_ObjectGPU, _Tile]]:
        """Draw the impostors and shadow maps of the visible objects for views of ``angle`` radians
        per pixel; returns the drawn objects (far to near) with their impostor tiles."""
        if fusion not in FUSIONS:
            raise PhyIRError(f"fusion must be one of {', '.join(FUSIONS)}, got {fusion!r}")
        self._forget(objects)
        ctx = self.ctx
        work = []
        for obj in objects:
            if not obj.visible:
                continue
            st = self.object_state(obj, quality)
            dist = float(np.linalg.norm(st.centre))
            if dist <= st.radius * 1.02:
                continue  # the camera is inside the object's bounds
            half = math.asin(min(st.radius / dist, 0.98)) * 1.03 + 1e-3
            n = int(np.clip(math.ceil(2 * math.tan(half) / angle * quality.supersample), 8, MAX_TILE))
            work.append((dist, st, half, n))
            if len(work) == MAX_OBJECTS:
                break
        work.sort(key=lambda t: -t[0])
        self._quality = quality
        self.drawn_faces = {"impostor": 0, "shadow": 0}
        out: list[tuple[_ObjectGPU, _Tile]] = []
        if not work:
            return out
        # impostors, one tile each in a row
        W = sum(n for *_, n in work)
        fbo = self._atlas("impostors", (W, max(n for *_, n in work)), 4, True)
        fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
        x0 = 0
        for dist, st, half, n in work:
            tan = math.tan(half)
            vp = perspective(tan, max(dist - st.radius, 0.01) * 0.95, dist + st.radius * 1.05) \
                @ look_at(np.zeros(3), st.centre)
            rect = (x0, 0, n, n)
            x0 += n
            fbo.viewport = rect
            ctx.scissor = rect
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=rect)
            prog = self._object_program(st.obj.material, quality, fusion)
            mesh = st.obj.mesh.lod(quality.impostor_faces)
            self.drawn_faces["impostor"] += len(mesh.faces)
            if mesh.closed:  # back faces hidden anyway: cull them
                ctx.enable(moderngl.CULL_FACE)
                self._draw_object(prog, st, vp, mesh)
                ctx.disable(moderngl.CULL_FACE)
            else:  # depth first, so the costly shading runs once per pixel whatever the order
                fbo.color_mask = (False, False, False, False)
                self._draw_depth(st, vp, mesh)
                fbo.color_mask = (True, True, True, True)
                ctx.depth_func = "<="
                self._draw_object(prog, st, vp, mesh)
                ctx.depth_func = "<"
            out.append((st, _Tile(vp, rect)))
        ctx.scissor = None
        self._draw_shadows([st for st, _ in out], quality)
        ctx.disable(moderngl.DEPTH_TEST)
        return out

    def _object_program(self, material: Material, quality: Quality, fusion: str) -> moderngl.Program:
        """object.frag for this material (SHARP: whether ibl.glsl's mirror branch can be taken: software
        GL runs both sides of a branch, so the marching is compiled out for glossy materials)."""
        prog = self.program("object.vert", "object.frag", FUSION_PLANE=int(fusion == "differential"),
                            SHARP=int(material.roughness < MIRROR_ROUGHNESS))
        self._bind_scene(prog)
        self.dfg.use(2)
        for name, unit in (("env", 0), ("env_irr", 1), ("dfg", 2), ("env_spec", 15)):
            _uniform(prog, name, unit)
        _uniform(prog, "spec_samples", int(quality.spec_samples))
        _uniform(prog, "mirror_roughness", float(MIRROR_ROUGHNESS))
        _uniform(prog, "lod_bias", 0.0)
        _uniform(prog, "march_steps", int(quality.march_steps))
        _uniform(prog, "use_projection", int(self.use_projection))
        _uniform(prog, "footprint_scale", float(self.footprint_scale))
        _uniform(prog, "occlusion_eps", 0.01)
        return prog

    def _draw_object(self, prog: moderngl.Program, st: _ObjectGPU, vp: np.ndarray, mesh: Mesh) -> None:
        obj, mat = st.obj, st.obj.material
        st.env.use(0)
        st.irr.use(1)
        st.spec.use(15)
        dirs, power = st.lighting.peak_dirs, st.lighting.peak_power
        if not self._quality.peak_subsamples and dirs.shape[0]:  # one sample per texel: the 4 merged
            dirs = torch.nn.functional.normalize(dirs.reshape(-1, 4, 3).sum(1), dim=-1)
            power = power.reshape(-1, 4, 3).sum(1)
        _set_lighting(prog, st.lighting.spec_mips, dirs, power)
        _uniform(prog, "base_color", tuple(float(c) for c in mat.base_color))
        _uniform(prog, "roughness", float(mat.roughness))
        _uniform(prog, "metallic", float(mat.metallic))
        model = obj.model_matrix()
        if "model" in prog:
            prog["model"].write(_mat(model))
        if "normal_matrix" in prog:
            prog["normal_matrix"].write(_mat(np.linalg.inv(model[:3, :3]).T))
        prog["view_proj"].write(_mat(vp))
        point, normal = obj.support if obj.support is not None else (st.centre - [0, st.radius, 0], (0, 1, 0))
        _uniform(prog, "plane_point", tuple(float(c) for c in point))
        _uniform(prog, "plane_normal", tuple(float(c) for c in normal))
        proxies = [(*st.centre, st.radius)] if self._quality.own_shadow_bounds else obj.world_proxies()[:16]
        _uniform(prog, "n_own_proxies", len(proxies))
        _write(prog, "own_proxies", proxies)
        self._vao(mesh, prog).render(moderngl.TRIANGLES)

    def _draw_depth(self, st: _ObjectGPU, vp: np.ndarray, mesh: Mesh) -> None:
        prog = self.program("shadow.vert", "depth.frag")
        prog["model"].write(_mat(st.obj.model_matrix()))
        prog["view_proj"].write(_mat(vp))
        self._vao(mesh, prog).render(moderngl.TRIANGLES)

    def _draw_shadows(self, states: list[_ObjectGPU], quality: Quality) -> None:
        lights = [(st, lt) for st in states for lt in st.lights][:MAX_LIGHTS]
        self._shadow_list = lights
        if not lights:
            return
        s = quality.shadow_size
        fbo = self._atlas("shadows", (s * len(lights), s), 1, True)
        self._shadow_size = (fbo.size, s)
        self._shadow_taps = quality.shadow_taps
        prog = self.program("shadow.vert", "shadow.frag")
        fbo.use()
        for i, (st, (pl, vp, *_)) in enumerate(lights):
            rect = (i * s, 0, s, s)
            fbo.viewport = rect
            self.ctx.scissor = rect
            fbo.clear(1e30, 1e30, 1e30, 1e30, depth=1.0, viewport=rect)
            prog["model"].write(_mat(st.obj.model_matrix()))
            prog["view_proj"].write(_mat(vp))
            prog["light_pos"] = tuple(float(c) for c in pl.position)
            mesh = st.obj.mesh.lod(quality.shadow_faces)
            self.drawn_faces["shadow"] += len(mesh.faces)
            self._vao(mesh, prog).render(moderngl.TRIANGLES)
        self.ctx.scissor = None

    def _composite_uniforms(self, prog: moderngl.Program, drawn: list[tuple[_ObjectGPU, _Tile]]) -> None:
        imp = self._fbos["impostors"][1]
        aw, ah = imp.size
        imp.use(11)
        _uniform(prog, "imp_atlas", 11)
        _uniform(prog, "has_albedo", int(self.has_albedo))
        n = len(drawn)
        _uniform(prog, "n_objects", n)
        _write(prog, "imp_vp", np.stack([t.vp.T for _, t in drawn]))
        _write(prog, "imp_tile", [(t.rect[0] / aw, t.rect[1] / ah, t.rect[2] / aw, t.rect[3] / ah)
                                  for _, t in drawn])
        _write(prog, "obj_sphere", [(*st.centre, st.radius) for st, _ in drawn])
        _write(prog, "obj_reach", [st.halo * st.radius for st, _ in drawn])
        _write(prog, "amb_full", np.stack([st.amb_full for st, _ in drawn]))
        _write(prog, "amb_bounce", np.stack([st.amb_bounce for st, _ in drawn]))
        _write(prog, "obj_albedo", [reflectance(st.obj.material) for st, _ in drawn])
        res = self._probe_array(drawn)
        res.use(13)
        _uniform(prog, "obj_probes", 13)
        _uniform(prog, "residual_texel", 2 * math.pi**2 / (res.width * res.height))
        self.dfg.use(14)
        _uniform(prog, "dfg", 14)
        index = {id(st): k for k, (st, _) in enumerate(drawn)}
        lights = [(st, lt) for st, lt in getattr(self, "_shadow_list", []) if id(st) in index]
        _uniform(prog, "n_lights", len(lights))
        if lights:
            (sw, sh), s = self._shadow_size
            self._fbos["shadows"][1].use(10)
            _uniform(prog, "shadow_atlas", 10)
            _uniform(prog, "shadow_texel", 2.0 / s)
            _uniform(prog, "shadow_taps", int(self._shadow_taps))
            _write(prog, "light_obj", [index[id(st)] for st, _ in lights], np.int32)
            _write(prog, "light_pos", [lt[0].position.numpy() for _, lt in lights])
            _write(prog, "light_power", [lt[0].light.power.numpy() for _, lt in lights])
            _write(prog, "light_dist", [lt[0].distance for _, lt in lights])
            _write(prog, "light_size", [lt[4] for _, lt in lights])
            _write(prog, "light_vp", np.stack([lt[1].T for _, lt in lights]))
            _write(prog, "light_tan", [lt[2] for _, lt in lights])
            _write(prog, "light_near", [lt[3] for _, lt in lights])
            _write(prog, "light_tile", [(i * s / sw, 0.0, s / sw, s / sh) for i in range(len(lights))])
        proxies, owners = [], []
        for k, (st, _) in enumerate(drawn):
            for p in st.obj.world_proxies():
                proxies.append(p)
                owners.append(k)
        proxies, owners = proxies[:MAX_PROXIES], owners[:MAX_PROXIES]
        _uniform(prog, "n_proxies", len(proxies))
        if proxies:
            _write(prog, "proxy", np.stack(proxies))
            _write(prog, "proxy_obj", owners, np.int32)

    def _probe_array(self, drawn: list[tuple[_ObjectGPU, _Tile]]) -> moderngl.TextureArray:
        """The drawn objects' probes as one mipmapped texture array: layer 2k object k's probe without
        its dominant lights, 2k+1 the probe."""
        key = tuple(st.lighting for st, _ in drawn)  # the objects themselves: ids can be reused
        have = self._fbos.get("probes")
        if have is not None and len(have[1]) == len(key) and all(a is b for a, b in zip(have[1], key)):
            return have[0]
        if have is not None:
            have[0].release()
        probes = [p.float() for st, _ in drawn for p in (st.lighting.residual, st.lighting.probe)]
        h, w = probes[0].shape[-2:]
        data = np.stack([p.permute(1, 2, 0).numpy() for p in probes]).astype(np.float32)
        tex = self.ctx.texture_array((w, h, len(probes)), 3, data.tobytes(), dtype="f4")
        tex.repeat_x, tex.repeat_y = True, False
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._fbos["probes"] = (tex, key)
        return tex

    def _set_view(self, prog: moderngl.Program, view, rect: tuple[float, float, float, float],
                  fb_height: float) -> None:
        """The uniforms of shaders/view.glsl (as viewer.renderer sets them for its passes)."""
        _uniform(prog, "view_rect", tuple(float(r) for r in rect))
        _uniform(prog, "fb_height", float(fb_height))
        if isinstance(view, EquirectView):
            _uniform(prog, "eq_center", tuple(float(c) for c in view.center))
            _uniform(prog, "eq_zoom", float(view.zoom))
        else:
            _uniform(prog, "persp", (float(math.radians(view.fov)), float(view.yaw), float(view.pitch)))

    # -- in the viewer: a linear pass of viewer.renderer.Renderer -----------------------------
    def screen_rect(self, drawn: list[tuple[_ObjectGPU, _Tile]], view, size: tuple[int, int]
                    ) -> tuple[int, int, int, int] | None:
        """(x, y, w, h) view pixels (y from the top) bounding what the objects change, or None."""
        w, h = size
        H, W = self.scene.size
        pts = np.concatenate([_reach_points(st) for st, _ in drawn])
        u, v, _ = pano.points_to_uv(torch.from_numpy(pts), H, W, dim=-1)
        u, v = u.numpy(), v.numpy()
        if isinstance(view, EquirectView):
            if np.ptp(u) > W / 2:  # across the seam: every column
                u = np.array([0.0, W])
            x, y, _ = view.uv_to_screen(np.array([u.min(), u.max()]), np.array([v.min(), v.max()]), size)
        else:
            x, y, front = view.uv_to_screen(u, v, size, (H, W))
            if not front.all():
                return 0, 0, w, h
        x0, x1 = int(max(math.floor(x.min()) - 2, 0)), int(min(math.ceil(x.max()) + 2, w))
        y0, y1 = int(max(math.floor(y.min()) - 2, 0)), int(min(math.ceil(y.max()) + 2, h))
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1 - x0, y1 - y0

    # -- headless rendering (export, tests) ---------------------------------------------------
    def render_view(self, objects: list[SceneObject], view: EquirectView | PerspectiveView,
                    size: tuple[int, int], quality: Quality = FULL, fusion: str = "three-image"
                    ) -> dict[str, np.ndarray]:
        """Render ``objects`` into a view of ``size`` = (width, height) pixels.

        Returns float32 arrays, rows from the top: ``composite [h,w,3]``, ``alpha [h,w]`` (object
        coverage), ``shadow [h,w]`` (shadow matte: the share of the receiver's light removed),
        ``object [h,w,3]`` (object radiance x alpha).
        """
        if self.scene is None:
            raise PhyIRError("insertion: no scene (call set_scene first)")
        w, h = size
        H, W = self.scene.size
        drawn = self.prepare(objects, pixel_angle(view, (w, h), (H, W)), quality, fusion)
        targets = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(3)]
        fbo = self.ctx.framebuffer(targets)
        try:
            kind = int(isinstance(view, PerspectiveView))
            prog = self.program("fullscreen.vert", "composite.frag", VIEW_KIND=kind, VIEWER=0,
                                **_composite_defines(quality))
            fbo.use()
            fbo.viewport = (0, 0, w, h)
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            self._bind_scene(prog)
            self._set_view(prog, view, (0, 0, w, h), h)
            if drawn:
                self._composite_uniforms(prog, drawn)
            else:
                _uniform(prog, "n_objects", 0)
                _uniform(prog, "n_lights", 0)
                _uniform(prog, "n_proxies", 0)
            self._fullscreen(prog).render(moderngl.TRIANGLES, vertices=3)
            read = lambda i: np.frombuffer(fbo.read(components=4, dtype="f4", attachment=i),  # noqa: E731
                                           np.float32).reshape(h, w, 4)[::-1]
            a, b, c = read(0), read(1), read(2)
            return {"composite": a[..., :3].copy(), "alpha": a[..., 3].copy(), "object": b[..., :3].copy(),
                    "shadow": c[..., 0].copy(), "shadow_delta": c[..., 1].copy()}
        finally:
            fbo.release()
            for t in targets:
                t.release()

    def shade_gbuffer(self, normal: torch.Tensor, view: torch.Tensor, material: Material, probe: torch.Tensor,
                      spec_samples: int = FULL.spec_samples) -> torch.Tensor:
        """``shaders/ibl.glsl`` on a G-buffer (``normal``, ``view [3,H,W]``) lit by ``probe [3,h,w]``
        (probe only, no scene): ``[3,H,W]`` radiance, zero where the normal is zero or faces away."""
        H, W = normal.shape[-2:]
        tex = lambda t: self.ctx.texture((W, H), 3, np.ascontiguousarray(  # noqa: E731
            t.permute(1, 2, 0).float().numpy()).tobytes(), dtype="f4")
        gn, gv = tex(normal), tex(view)
        probe = probe.float()
        dirs, power, residual = peak_samples(probe)
        env = self.probe_texture(probe_mips(probe))
        spec_levels = probe_mips(residual)
        spec = self.probe_texture(spec_levels)
        irr = self._equirect(irradiance_map(probe).permute(1, 2, 0).numpy())
        out = self.ctx.texture((W, H), 4, dtype="f4")
        fbo = self.ctx.framebuffer([out])
        try:
            prog = self.program("fullscreen.vert", "shade_gbuffer.frag")
            for name, t, unit in (("env", env, 0), ("env_irr", irr, 1), ("dfg", self.dfg, 2),
                                  ("gb_normal", gn, 3), ("gb_view", gv, 4), ("env_spec", spec, 5)):
                t.use(unit)
                _uniform(prog, name, unit)
            _set_lighting(prog, spec_levels, dirs, power)
            _uniform(prog, "spec_samples", int(spec_samples))
            _uniform(prog, "mirror_roughness", float(MIRROR_ROUGHNESS))
            _uniform(prog, "lod_bias", 0.0)
            _uniform(prog, "base_color", tuple(float(c) for c in material.base_color))
            _uniform(prog, "roughness", float(material.roughness))
            _uniform(prog, "metallic", float(material.metallic))
            fbo.use()
            fbo.viewport = (0, 0, W, H)
            self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
            self._fullscreen(prog).render(moderngl.TRIANGLES, vertices=3)
            a = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
            return torch.from_numpy(a[..., :3].copy()).permute(2, 0, 1)
        finally:
            for t in (gn, gv, env, spec, irr, out):
                t.release()
            fbo.release()

    def release(self) -> None:
        self.release_scene()
        for _mesh, vbo, ibo, vaos in self._meshes.values():
            for v in vaos.values():
                v.release()
            vbo.release()
            ibo.release()
        self._meshes.clear()
        for entry in self._fbos.values():
            for r in entry:
                if hasattr(r, "release"):
                    r.release()
        self._fbos.clear()
        for p in self._programs.values():
            p.release()
        self._programs.clear()
        self.dfg.release()


class InsertionPass:
    """The objects of one scene as an overlay pass of :class:`viewer.renderer.Renderer`
    (``renderer.overlay_passes.insert(0, InsertionPass(...))``).

    Overlay passes run right after the display pass, with its framebuffer and viewport bound; the
    region the objects change is drawn again from the layer (``layer.glsl``, the renderer's own
    look-up) composited and tonemapped (``display.glsl``), so a frame with objects costs the bare
    frame plus that region.  Draws while ``enabled`` and ``frame.extras.get("insert", True)``;
    ``dragging`` selects the cheaper :data:`DRAGGING` quality."""

    def __init__(self, insertion: InsertionRenderer, objects: list[SceneObject] | None = None):
        self.insertion = insertion
        self.objects: list[SceneObject] = objects if objects is not None else []
        self.enabled = True
        self.dragging = False
        self.fusion = "three-image"
        self.last_rect: tuple[int, int, int, int] | None = None

    def __call__(self, renderer, frame) -> None:
        ins = self.insertion
        self.last_rect = None
        ins._forget(self.objects)  # deleted objects' lighting, unused meshes
        if not self.enabled or not frame.extras.get("insert", True) or ins.scene is None:
            return
        if not any(o.visible for o in self.objects):
            return
        ctx = ins.ctx
        target = ctx.fbo
        vx, vy, vw, vh = ctx.viewport  # the display pass's: (x, fb_h - y - h, w, h)
        x, y, w, h = frame.rect
        fb_h = vy + y + h
        quality = DRAGGING if self.dragging else FULL
        H, W = ins.scene.size
        drawn = ins.prepare(self.objects, pixel_angle(frame.view, (w, h), (H, W)), quality, self.fusion)
        target.use()
        ctx.viewport = (vx, vy, vw, vh)
        if not drawn:
            return
        rect = ins.screen_rect(drawn, frame.view, (w, h))
        if rect is None:
            return
        rx, ry, rw, rh = rect
        d = frame.display
        from viewer.renderer import KINDS, TONEMAPS

        prog = ins.program("fullscreen.vert", "composite.frag", VIEWER=1, **_composite_defines(quality),
                           VIEW_KIND=int(isinstance(frame.view, PerspectiveView)), NEAREST=int(frame.nearest),
                           KIND=KINDS[d.kind], TONEMAP=TONEMAPS.index(d.tonemap) if d.kind == "hdr" else 0)
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.viewport = (x + rx, fb_h - y - ry - rh, rw, rh)
        ins._bind_scene(prog)
        ins._set_view(prog, frame.view, (x, y, w, h), fb_h)
        frame.texture.use(12)
        _uniform(prog, "layer", 12)
        _uniform(prog, "pano_size", (float(frame.pano_size[1]), float(frame.pano_size[0])))
        renderer._set_display(prog, frame)  # exposure, tone map and colour map as the display pass
        ins._composite_uniforms(prog, drawn)
        ins._fullscreen(prog).render(moderngl.TRIANGLES, vertices=3)
        ctx.viewport = (vx, vy, vw, vh)
        self.last_rect = rect


def _composite_defines(quality: Quality) -> dict[str, int]:
    return {"GLOSSY_RECEIVERS": int(quality.glossy_receivers), "PROXY_LOOKUPS": int(quality.proxy_lookups),
            "BLOCKER_SEARCH": int(quality.blocker_search)}


def _reach_points(st: _ObjectGPU) -> np.ndarray:
    """The object's reach points with its halo at ``st.halo`` radii (object_lighting's are at HALO)."""
    c = st.centre[None]
    halo = c + (st.reach[:N_HALO] - c) * (st.halo / HALO)
    return np.concatenate([halo, st.reach[N_HALO:]])


def _set_lighting(prog: moderngl.Program, spec_levels: list[torch.Tensor], dirs: torch.Tensor,
                  power: torch.Tensor) -> None:
    """ibl.glsl's probe uniforms: the residual's size and levels, the peak samples."""
    h, w = spec_levels[0].shape[-2:]
    _uniform(prog, "env_size", (float(w), float(h)))
    _uniform(prog, "env_max_lod", float(len(spec_levels) - 1))
    _uniform(prog, "n_peaks", int(dirs.shape[0]))
    if dirs.shape[0]:
        _write(prog, "peak_dir", dirs.numpy())
        _write(prog, "peak_power", power.numpy())


def reflectance(material: Material) -> np.ndarray:
    """What a surface of this material reflects of uniform light: B (1 - M) + F0 A + B at n.v = 1."""
    b = torch.tensor(material.base_color, dtype=torch.float32)
    m = torch.tensor(float(material.metallic))
    spec = prefilter.specular_albedo(torch.tensor(1.0), torch.tensor(float(material.roughness)),
                                     f0_from_material(b, m))
    return (b * (1 - m) + spec).numpy()
