"""Virtual object insertion on the GPU (ModernGL): shading, shadows and compositing (docs/insertion.md).

:class:`InsertionRenderer` works on any moderngl context: the viewer's window (as an overlay pass of
:class:`viewer.renderer.Renderer`, see :class:`viewer.insertion_pass.InsertionPass`) or a headless EGL
context (:meth:`InsertionRenderer.render_view`, used by ``phyir insert``).  Per frame:

1. each object's lighting (CPU, torch, only when it moved): the light at its centre
   (:class:`phyir.lighting.at_point.LightAtPoint`: the panorama projected from the object, learned
   probes where the camera did not see), its mip pyramid, exact irradiance map and dominant lights
   placed in the room (:mod:`phyir.lighting.extract`), uploaded as small textures;
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

import copy
import math

import moderngl
import numpy as np
import torch

from phyir import pano
from phyir.errors import PhyIRError
from phyir.insert.objects import ObjectMaterial, SceneObject
from phyir.insert.views import EquirectView, PerspectiveView, pixel_angle
from phyir.lighting.at_point import LightAtPoint
from phyir.lighting.object_lighting import (
    HALO,
    N_HALO,
    irradiance_map,
    peak_samples,
    probe_mips,
)
from phyir.lighting.projection import DepthSurface
from phyir.scene import PanoScene
from phyir.shading import prefilter
from phyir.shading.render import MIRROR_ROUGHNESS
from viewer.gl.impostors import FUSIONS, ImpostorPasses, set_lighting
from viewer.gl.object_state import ObjectGPU, ObjectStates, Tile
from viewer.gl.programs import ProgramCache, set_uniform, set_view
from viewer.gl.quality import DRAGGING, FULL, Quality

__all__ = ["DRAGGING", "FULL", "FUSIONS", "IMAGE_HALF_MAX", "InsertionRenderer", "Quality",
           "composite_defines"]

IMAGE_HALF_MAX = 65000.0


class InsertionRenderer(ObjectStates, ImpostorPasses):
    """Inserted objects over one scene (see the module doc).  All methods run on the GL thread; the
    per-object state is :class:`viewer.gl.object_state.ObjectStates`', the atlas passes
    :class:`viewer.gl.impostors.ImpostorPasses`'."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.programs = ProgramCache(ctx)
        ObjectStates.__init__(self)  # meshes and per-object lighting
        ImpostorPasses.__init__(self)  # atlases and their tiles
        self._draft: tuple = ()  # draft_targets()
        self.scene: PanoScene | None = None
        self.field: LightAtPoint | None = None
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
        """The program of two shader files compiled with ``defines`` (cached)."""
        return self.programs.program(vert, frag, **defines)

    def draw_fullscreen(self, prog: moderngl.Program) -> None:
        """Draw ``prog`` over the viewport: one full-screen triangle."""
        self.programs.fullscreen(prog).render(moderngl.TRIANGLES, vertices=3)

    # -- textures ----------------------------------------------------------------------------
    def equirect_texture(self, array: np.ndarray, dtype: str = "f4", nearest: bool = False,
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
        tex = self.equirect_texture(levels[0].permute(1, 2, 0).numpy(), mipmaps=True)
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
        self.surface = DepthSurface.from_scene(scene)
        self.field = LightAtPoint(scene, surface=self.surface)  # the panorama's light, at the object
        normal = scene.normal if scene.normal is not None else pano.normals_from_depth(scene.depth.float())
        tex = self._scene_tex
        tex["scene_depth"] = self.equirect_texture(scene.depth[0].float().numpy(), nearest=True)
        tex["scene_normal"] = self.equirect_texture(_hwc(normal), "f2", nearest=True)
        albedo = scene.albedo if scene.albedo is not None else torch.full_like(scene.image, 0.5)
        tex["scene_albedo"] = self.equirect_texture(_hwc(albedo), "f2")
        # float32 keeps untouched pixels bit-exact in exports; half floats above 4K (memory)
        image = _hwc(scene.image)
        big = scene.size[1] > 4096
        tex["scene_image"] = self.equirect_texture(np.minimum(image, IMAGE_HALF_MAX) if big else image,
                                                   "f2" if big else "f4", mipmaps=True)
        tex["march_depth"] = self.equirect_texture(self.surface.depth_tex[0, 0, :, 1:-1].numpy())
        tex["march_jump"] = self.equirect_texture(self.surface.jump_tex[0, 0, :, 1:-1].numpy(), nearest=True)
        rough = scene.roughness if scene.roughness is not None else torch.ones_like(scene.depth)
        metal = scene.metallic if scene.metallic is not None else torch.zeros_like(scene.depth)
        tex["scene_rm"] = self.equirect_texture(_hwc(torch.cat([rough, metal])), nearest=True)
        self.has_albedo = scene.albedo is not None

    def release_scene(self) -> None:
        self.wait_lighting()  # jobs read the old field
        for t in self._scene_tex.values():
            t.release()
        self._scene_tex.clear()
        self.release_object_states()
        self.forget_tiles()  # the atlas tiles were shaded with this scene

    def bind_scene(self, prog: moderngl.Program, first_unit: int = 3) -> None:
        """Bind the panorama's layers to units 3-9 and set their uniforms (units 0-2 and 10-15 are the
        passes' own)."""
        for k, name in enumerate(("scene_depth", "scene_normal", "scene_albedo", "scene_image",
                                  "march_depth", "march_jump", "scene_rm")):
            self._scene_tex[name].use(first_unit + k)
            set_uniform(prog, name, first_unit + k)
        H, W = self.scene.size
        set_uniform(prog, "scene_size", (float(W), float(H)))
        set_uniform(prog, "r_bound", float(self.surface.r_bound))
        set_uniform(prog, "jump_threshold", float(self.surface.jump_threshold))

    # -- in the viewer: the overlay pass (InsertionPass) ------------------------------------
    def screen_rect(self, drawn: list[tuple[ObjectGPU, Tile]], view, size: tuple[int, int],
                    reach: bool = True) -> tuple[int, int, int, int] | None:
        """(x, y, w, h) view pixels (y from the top) bounding what the objects change (with
        ``reach``: their shadows and occlusion too, else the objects themselves), or None."""
        w, h = size
        H, W = self.scene.size
        pts = np.concatenate([_reach_points(st) if reach else _outline_points(st) for st, _ in drawn])
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
                                **composite_defines(quality))
            fbo.use()
            fbo.viewport = (0, 0, w, h)
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            self.bind_scene(prog)
            set_view(prog, view, (0, 0, w, h), h)
            if drawn:
                self.composite_uniforms(prog, drawn)
            else:
                set_uniform(prog, "n_objects", 0)
                set_uniform(prog, "n_lights", 0)
            self.draw_fullscreen(prog)
            a, b, c = (_read_rgba(fbo, i, w, h) for i in range(3))
            return {"composite": a[..., :3].copy(), "alpha": a[..., 3].copy(), "object": b[..., :3].copy(),
                    "shadow": c[..., 0].copy(), "shadow_delta": c[..., 1].copy()}
        finally:
            fbo.release()
            for t in targets:
                t.release()

    def shade_gbuffer(self, normal: torch.Tensor, view: torch.Tensor, material: ObjectMaterial,
                      probe: torch.Tensor, spec_samples: int = FULL.spec_samples) -> torch.Tensor:
        """``shaders/ibl.glsl`` on a G-buffer (``normal``, ``view [3,H,W]``) lit by ``probe [3,h,w]``
        (probe only, no scene): ``[3,H,W]`` radiance, zero where the normal is zero or faces away."""
        H, W = normal.shape[-2:]
        gn, gv = (self.ctx.texture((W, H), 3, np.ascontiguousarray(_hwc(t)).tobytes(), dtype="f4")
                  for t in (normal, view))
        probe = probe.float()
        dirs, power, residual = peak_samples(probe)
        env = self.probe_texture(probe_mips(probe))
        spec_levels = probe_mips(residual)
        spec = self.probe_texture(spec_levels)
        irr = self.equirect_texture(irradiance_map(probe).permute(1, 2, 0).numpy())
        out = self.ctx.texture((W, H), 4, dtype="f4")
        fbo = self.ctx.framebuffer([out])
        try:
            prog = self.program("fullscreen.vert", "shade_gbuffer.frag")
            for name, t, unit in (("env", env, 0), ("env_irr", irr, 1), ("dfg", self.dfg, 2),
                                  ("gb_normal", gn, 3), ("gb_view", gv, 4), ("env_spec", spec, 5)):
                t.use(unit)
                set_uniform(prog, name, unit)
            set_lighting(prog, spec_levels, dirs, power)
            set_uniform(prog, "spec_samples", int(spec_samples))
            set_uniform(prog, "mirror_roughness", float(MIRROR_ROUGHNESS))
            set_uniform(prog, "lod_bias", 0.0)
            set_uniform(prog, "base_color", tuple(float(c) for c in material.base_color))
            set_uniform(prog, "roughness", float(material.roughness))
            set_uniform(prog, "metallic", float(material.metallic))
            fbo.use()
            fbo.viewport = (0, 0, W, H)
            self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
            self.draw_fullscreen(prog)
            a = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
            return torch.from_numpy(a[..., :3].copy()).permute(2, 0, 1)
        finally:
            for t in (gn, gv, env, spec, irr, out):
                t.release()
            fbo.release()

    def draft_targets(self, w: int, h: int) -> tuple:
        """The viewer's draft composite target at w x h (kept while the size stays): a framebuffer
        and its linear-filtered float texture (the receivers' kept share)."""
        have = self._draft
        if have and have[1].size == (w, h):
            return have
        for r in have:
            r.release()
        keep = self.ctx.texture((w, h), 4, dtype="f2")
        keep.filter = (moderngl.LINEAR, moderngl.LINEAR)
        keep.repeat_x = keep.repeat_y = False
        self._draft = (self.ctx.framebuffer([keep]), keep)
        return self._draft

    def _release_draft(self) -> None:
        for r in self._draft:
            r.release()
        self._draft = ()

    def fork(self) -> InsertionRenderer:
        """A renderer of the same scene with object states, atlases and tile keys of its own, sharing
        this one's context, programs, scene textures, meshes and the probe field (and its lock): the
        viewer's full-quality picture is built in one (``viewer.refinement``) while draft frames
        draw from the other.  Free it with :meth:`release_fork` before this one; fork again after
        :meth:`set_scene`."""
        twin = copy.copy(self)
        twin.own_object_states()
        twin.own_atlases()
        twin._draft = ()
        twin.drawn_faces = {"impostor": 0, "shadow": 0}
        return twin

    def release_fork(self) -> None:
        """Free what a fork owns: its object states, atlases and lighting worker."""
        self.stop_lighting_worker(cancel=True)
        self.release_object_states()
        self.forget_tiles()
        self.release_atlases()
        self._release_draft()

    def release(self) -> None:
        self.release_scene()
        self.release_meshes()
        self.release_atlases()
        self._release_draft()
        self.stop_lighting_worker()
        self.programs.release()
        self.dfg.release()


def composite_defines(quality: Quality) -> dict[str, int]:
    """composite.frag's defines for ``quality``'s cheaper paths."""
    return {"GLOSSY_RECEIVERS": int(quality.glossy_receivers), "PROXY_LOOKUPS": int(quality.proxy_lookups),
            "BLOCKER_SEARCH": int(quality.blocker_search)}


def _reach_points(st: ObjectGPU) -> np.ndarray:
    """The object's reach points with its halo at ``st.halo`` radii (object_lighting's are at HALO)."""
    c = st.centre[None]
    halo = c + (st.reach[:N_HALO] - c) * (st.halo / HALO)
    return np.concatenate([halo, st.reach[N_HALO:]])


def _outline_points(st: ObjectGPU, n: int = 16) -> np.ndarray:
    """Directions around the cone from the panorama's centre that holds the object's bounding sphere
    (a little wider, as its impostor camera's: ``ImpostorPasses.prepare``)."""
    dist = float(np.linalg.norm(st.centre))
    if dist <= st.radius:  # the camera inside the object (warned about): it covers every direction
        return np.concatenate([np.eye(3), -np.eye(3)])
    axis = st.centre / dist
    half = math.asin(min(st.radius / dist, 0.98)) * 1.03 + 1e-3
    a = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    phi = np.linspace(0, 2 * math.pi, n, endpoint=False)[:, None]
    ring = np.cos(phi) * a + np.sin(phi) * b
    # the polygon's edges touch the circle: it holds the cone
    return math.cos(half) * axis + math.sin(half) * ring / math.cos(math.pi / n)


def _hwc(t: torch.Tensor) -> np.ndarray:
    """A [C, h, w] tensor as an h x w x C float32 array."""
    return t.permute(1, 2, 0).float().numpy()


def _read_rgba(fbo: moderngl.Framebuffer, attachment: int, w: int, h: int) -> np.ndarray:
    """An RGBA32F attachment's pixels, rows from the top."""
    return np.frombuffer(fbo.read(components=4, dtype="f4", attachment=attachment),
                         np.float32).reshape(h, w, 4)[::-1]
