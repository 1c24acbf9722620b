"""The insertion renderer's passes (``viewer.insertion``): each object drawn into its own tile of an
*impostor atlas* (``object.frag``), each dominant light's view of it into a *shadow atlas* tile
(``shadow.frag``), and the uniforms ``composite.frag`` reads them with."""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterator
from dataclasses import astuple

import moderngl
import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.insert.objects import Mesh, ObjectMaterial, SceneObject
from phyir.insert.placement import CAMERA_CLEARANCE
from phyir.insert.views import look_at, perspective
from phyir.shading import prefilter
from phyir.shading.brdf import f0_from_material
from phyir.shading.render import MIRROR_ROUGHNESS
from viewer.gl.object_state import ObjectGPU, Tile
from viewer.gl.programs import matrix_bytes, set_uniform, write_array
from viewer.gl.quality import FULL, Quality

MAX_OBJECTS, MAX_LIGHTS, MAX_PROXIES = 8, 16, 64  # shaders/composite.frag
FUSIONS = ("three-image", "differential")
MAX_TILE = 2048


class ImpostorPasses:
    """The atlas passes and composite uniforms of :class:`viewer.insertion.InsertionRenderer` (a part
    of it: ``ctx``, ``dfg``, ``program``, ``bind_scene`` and the object states are the renderer's)."""

    def __init__(self):
        self.own_atlases()

    def own_atlases(self) -> None:
        """Start atlases and tile keys of its own (empty; a fork's are not its renderer's)."""
        self._fbos: dict[str, tuple] = {}
        self._tile_keys: dict[tuple, tuple] = {}  # (pass, rect) -> what that atlas tile holds (see prepare)

    def release_atlases(self) -> None:
        """Free the atlases."""
        for entry in self._fbos.values():
            for r in entry:
                if hasattr(r, "release"):
                    r.release()
        self._fbos.clear()

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
                fusion: str = "three-image") -> list[tuple[ObjectGPU, Tile]]:
        """Draw the impostors and shadow maps of the visible objects for views of ``angle`` radians
        per pixel; returns the drawn objects (far to near) with their impostor tiles."""
        return run_steps(self.prepare_steps(objects, angle, quality, fusion))

    def prepare_steps(self, objects: list[SceneObject], angle: float, quality: Quality = FULL,
                      fusion: str = "three-image", rows: Callable[[str, int, int], int] | None = None
                      ) -> Generator[tuple[str, tuple | None], None, list[tuple[ObjectGPU, Tile]]]:
        """:meth:`prepare` a piece at a time (the viewer's refinement, ``viewer.refinement``): yields
        ("impostor", (n, y, rows)) after each strip of an n x n impostor tile, its rows y to y + rows
        from ``rows("impostor", n, y)`` (None: whole tiles), and ("shadow", None) after each shadow
        map; returns what :meth:`prepare` returns.  The same pixels as :meth:`prepare` (scissored
        strips of the same draws); a tile counts as drawn (kept by later calls) only once all its
        strips are."""
        if fusion not in FUSIONS:
            raise PhyIRError(f"fusion must be one of {', '.join(FUSIONS)}, got {fusion!r}")
        self.forget(objects)
        work = []
        for obj in objects:
            if not obj.visible:
                continue
            st = self.object_state(obj, quality)
            dist = float(np.linalg.norm(st.centre))
            if dist <= st.radius * CAMERA_CLEARANCE:
                continue  # the camera is inside the object's bounds (placement.camera_inside says so)
            half = math.asin(min(st.radius / dist, 0.98)) * 1.03 + 1e-3
            n = int(np.clip(math.ceil(2 * math.tan(half) / angle * quality.supersample), 8, MAX_TILE))
            work.append((dist, st, half, n))
            if len(work) == MAX_OBJECTS:
                break
        work.sort(key=lambda t: -t[0])
        self._quality = quality
        self.drawn_faces = {"impostor": 0, "shadow": 0}
        out: list[tuple[ObjectGPU, Tile]] = []
        if not work:
            self._shadow_list = []
            return out
        # impostors, one tile each in a row
        work = self._keep_layout(work)
        W = sum(n for *_, n in work)
        fbo = self._atlas("impostors", (W, max(n for *_, n in work)), 4, True)
        x0 = 0
        for dist, st, half, n in work:
            vp = perspective(math.tan(half), max(dist - st.radius, 0.01) * 0.95, dist + st.radius * 1.05) \
                @ look_at(np.zeros(3), st.centre)
            rect = (x0, 0, n, n)
            x0 += n
            out.append((st, Tile(vp, rect)))
            # a tile whose object, lighting, material and camera are as when it was drawn is kept
            # (objects that don't move while another is dragged cost nothing here)
            key = (st.key, id(st.lighting), astuple(st.obj.material), quality, fusion, half, id(fbo),
                   self.use_projection, self.footprint_scale)
            if self._tile_keys.get(("impostor", rect)) == key:
                continue
            same = (st.obj, st.lighting, key[2:5] + key[6:])  # all but the position and apparent size
            turned = self._turned_tile(("impostor-last", rect), same, vp, st.centre)
            if turned is not None:
                out[-1] = (st, Tile(turned, rect))
                continue
            self._claim("impostor", rect)
            mesh = st.obj.mesh.lod(quality.impostor_faces)
            self.drawn_faces["impostor"] += len(mesh.faces)
            y = 0
            while y < n:
                step = n - y if rows is None else max(1, min(n - y, rows("impostor", n, y)))
                self._draw_impostor(fbo, st, vp, mesh, rect, (rect[0], y, n, step), fusion)
                y += step
                if y == n:
                    self._tile_keys[("impostor", rect)] = key
                yield "impostor", (n, y - step, step)
        yield from self._shadow_steps([st for st, _ in out], quality)
        self.ctx.disable(moderngl.DEPTH_TEST)
        return out

    def _claim(self, kind: str, rect: tuple[int, int, int, int]) -> None:
        """Forget what the atlas tiles of ``kind`` overlapping ``rect`` held (it is drawn over; a
        tile of another layout or quality there would otherwise count as kept)."""
        x, y, w, h = rect
        for k in [k for k in self._tile_keys if k[0] == kind and len(k) == 2]:
            a, b, c, d = k[1]
            if a < x + w and x < a + c and b < y + h and y < b + d:
                del self._tile_keys[k]

    def _draw_impostor(self, fbo: moderngl.Framebuffer, st: ObjectGPU, vp: np.ndarray, mesh: Mesh,
                       rect: tuple[int, int, int, int], strip: tuple[int, int, int, int],
                       fusion: str) -> None:
        """The rows ``strip`` of the object's impostor tile ``rect`` (sets all the GL state it uses:
        other passes may run between two strips)."""
        ctx = self.ctx
        fbo.use()
        fbo.viewport = rect
        ctx.scissor = strip
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=strip)
        prog = self._object_program(st.obj.material, self._quality, fusion)
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
        ctx.scissor = None
        ctx.disable(moderngl.DEPTH_TEST)

    def _turned_tile(self, slot: tuple, same: tuple, vp: np.ndarray, centre: np.ndarray) -> np.ndarray | None:
        """With ``quality.impostor_every`` > 1: the camera of the object's last impostor turned to show
        it at ``centre`` (None: draw it; recorded as the last).  ``same``: what must not have
        changed (the object and its lighting held, so their ids can't be reused)."""
        last = self._tile_keys.get(slot)
        every = self._quality.impostor_every
        if every > 1 and last is not None and all(a is b for a, b in zip(last[0][:2], same[:2])) \
                and last[0][2] == same[2] and last[3] + 1 < every:
            self._tile_keys[slot] = (last[0], last[1], last[2], last[3] + 1)
            return turned_camera(last[1], last[2], centre)
        self._tile_keys[slot] = (same, vp, np.array(centre, float), 0)
        return None

    def _keep_layout(self, work: list[tuple]) -> list[tuple]:
        """With ``quality.impostor_every`` > 1 the atlas keeps last time's tiles while it holds the same
        objects in the same order at sizes within 5%: moves change the sizes by a texel or two, and
        a turned impostor needs its tile where it was.  Otherwise the last impostors' cameras are
        forgotten (another layout may have drawn over them)."""
        last = self._tile_keys.get(("impostor-layout",))
        same = self._quality.impostor_every > 1 and last is not None and len(last) == len(work) and all(
            a[0] is w[1].obj and abs(a[1] - w[3]) <= 0.05 * a[1] for a, w in zip(last, work))
        if same:
            work = [(*w[:3], a[1]) for a, w in zip(last, work)]
        else:
            for k in [k for k in self._tile_keys if k[0] == "impostor-last"]:
                del self._tile_keys[k]
        self._tile_keys[("impostor-layout",)] = [(w[1].obj, w[3]) for w in work]
        return work

    def forget_tiles(self) -> None:
        """Draw every impostor and shadow-map tile again at the next :meth:`prepare`."""
        self._tile_keys.clear()

    def _object_program(self, material: ObjectMaterial, quality: Quality, fusion: str) -> moderngl.Program:
        """object.frag for this material (SHARP: whether ibl.glsl's mirror branch can be taken: software
        GL runs both sides of a branch, so the marching is compiled out for glossy materials)."""
        prog = self.program("object.vert", "object.frag", FUSION_PLANE=int(fusion == "differential"),
                            SHARP=int(material.roughness < MIRROR_ROUGHNESS))
        self.bind_scene(prog)
        self.dfg.use(2)
        for name, unit in (("env", 0), ("env_irr", 1), ("dfg", 2), ("env_spec", 15)):
            set_uniform(prog, name, unit)
        set_uniform(prog, "spec_samples", int(quality.spec_samples))
        set_uniform(prog, "mirror_roughness", float(MIRROR_ROUGHNESS))
        set_uniform(prog, "lod_bias", 0.0)
        set_uniform(prog, "march_steps", int(quality.march_steps))
        set_uniform(prog, "use_projection", int(self.use_projection))
        set_uniform(prog, "footprint_scale", float(self.footprint_scale))
        set_uniform(prog, "occlusion_eps", 0.01)
        return prog

    def _draw_object(self, prog: moderngl.Program, st: ObjectGPU, vp: np.ndarray, mesh: Mesh) -> None:
        obj, mat = st.obj, st.obj.material
        st.env.use(0)
        st.irr.use(1)
        st.spec.use(15)
        dirs, power = st.lighting.peak_dirs, st.lighting.peak_power
        if not self._quality.peak_subsamples and dirs.shape[0]:  # one sample per texel: the 4 merged
            dirs = torch.nn.functional.normalize(dirs.reshape(-1, 4, 3).sum(1), dim=-1)
            power = power.reshape(-1, 4, 3).sum(1)
        set_lighting(prog, st.lighting.spec_mips, dirs, power)
        set_uniform(prog, "base_color", tuple(float(c) for c in mat.base_color))
        set_uniform(prog, "roughness", float(mat.roughness))
        set_uniform(prog, "metallic", float(mat.metallic))
        model = obj.model_matrix()
        if "model" in prog:
            prog["model"].write(matrix_bytes(model))
        if "normal_matrix" in prog:
            prog["normal_matrix"].write(matrix_bytes(np.linalg.inv(model[:3, :3]).T))
        prog["view_proj"].write(matrix_bytes(vp))
        point, normal = obj.support if obj.support is not None else (st.centre - [0, st.radius, 0], (0, 1, 0))
        set_uniform(prog, "plane_point", tuple(float(c) for c in point))
        set_uniform(prog, "plane_normal", tuple(float(c) for c in normal))
        proxies = [(*st.centre, st.radius)] if self._quality.own_shadow_bounds else obj.world_proxies()[:16]
        set_uniform(prog, "n_own_proxies", len(proxies))
        write_array(prog, "own_proxies", proxies)
        self.vertex_array(mesh, prog).render(moderngl.TRIANGLES)

    def _draw_depth(self, st: ObjectGPU, vp: np.ndarray, mesh: Mesh) -> None:
        prog = self.program("shadow.vert", "depth.frag")
        prog["model"].write(matrix_bytes(st.obj.model_matrix()))
        prog["view_proj"].write(matrix_bytes(vp))
        self.vertex_array(mesh, prog).render(moderngl.TRIANGLES)

    def _shadow_steps(self, states: list[ObjectGPU], quality: Quality) -> Iterator[tuple[str, None]]:
        """Each dominant light's view of its object into a shadow-atlas tile; yields ("shadow",
        None) after each map drawn."""
        lights = [(st, lt) for st in states for lt in st.lights][:MAX_LIGHTS]
        self._shadow_list = lights
        if not lights:
            return
        s = quality.shadow_size
        fbo = self._atlas("shadows", (s * len(lights), s), 1, True)
        self._shadow_size = (fbo.size, s)
        self._shadow_taps = quality.shadow_taps
        prog = self.program("shadow.vert", "shadow.frag")
        for i, (st, (pl, vp, *_)) in enumerate(lights):
            rect = (i * s, 0, s, s)
            key = (st.key, np.asarray(vp).tobytes(), tuple(np.asarray(pl.position, float)), quality, id(fbo))
            if self._tile_keys.get(("shadow", rect)) == key:
                continue  # the same object seen from the same light camera: the map is still there
            self._claim("shadow", rect)
            fbo.use()
            self.ctx.enable(moderngl.DEPTH_TEST)
            self.ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
            fbo.viewport = rect
            self.ctx.scissor = rect
            fbo.clear(1e30, 1e30, 1e30, 1e30, depth=1.0, viewport=rect)
            prog["model"].write(matrix_bytes(st.obj.model_matrix()))
            prog["view_proj"].write(matrix_bytes(vp))
            prog["light_pos"] = tuple(float(c) for c in pl.position)
            mesh = st.obj.mesh.lod(quality.shadow_faces)
            self.drawn_faces["shadow"] += len(mesh.faces)
            self.vertex_array(mesh, prog).render(moderngl.TRIANGLES)
            self.ctx.scissor = None
            self.ctx.disable(moderngl.DEPTH_TEST)
            self._tile_keys[("shadow", rect)] = key
            yield "shadow", None

    def composite_uniforms(self, prog: moderngl.Program, drawn: list[tuple[ObjectGPU, Tile]]) -> None:
        """The uniforms of ``composite.frag`` for the objects :meth:`prepare` drew: their impostor
        tiles, bounds, ambient terms, probes, shadow maps and proxy spheres."""
        self.impostor_uniforms(prog, drawn)
        set_uniform(prog, "has_albedo", int(self.has_albedo))
        write_array(prog, "obj_sphere", [(*st.centre, st.radius) for st, _ in drawn])
        write_array(prog, "obj_reach", [st.halo * st.radius for st, _ in drawn])
        write_array(prog, "amb_full", np.stack([st.amb_full for st, _ in drawn]))
        write_array(prog, "amb_bounce", np.stack([st.amb_bounce for st, _ in drawn]))
        write_array(prog, "obj_albedo", [reflectance(st.obj.material) for st, _ in drawn])
        res = self._probe_array(drawn)
        res.use(13)
        set_uniform(prog, "obj_probes", 13)
        set_uniform(prog, "residual_texel", 2 * math.pi**2 / (res.width * res.height))
        self.dfg.use(14)
        set_uniform(prog, "dfg", 14)
        index = {id(st): k for k, (st, _) in enumerate(drawn)}
        lights = [(st, lt) for st, lt in getattr(self, "_shadow_list", []) if id(st) in index]
        set_uniform(prog, "n_lights", len(lights))
        if lights:
            (sw, sh), s = self._shadow_size
            self._fbos["shadows"][1].use(10)
            set_uniform(prog, "shadow_atlas", 10)
            set_uniform(prog, "shadow_texel", 2.0 / s)
            set_uniform(prog, "shadow_taps", int(self._shadow_taps))
            write_array(prog, "light_obj", [index[id(st)] for st, _ in lights], np.int32)
            write_array(prog, "light_pos", [lt[0].position.numpy() for _, lt in lights])
            write_array(prog, "light_power", [lt[0].light.power.numpy() for _, lt in lights])
            write_array(prog, "light_dist", [lt[0].distance for _, lt in lights])
            write_array(prog, "light_size", [lt[4] for _, lt in lights])
            write_array(prog, "light_vp", np.stack([lt[1].T for _, lt in lights]))
            write_array(prog, "light_tan", [lt[2] for _, lt in lights])
            write_array(prog, "light_near", [lt[3] for _, lt in lights])
            write_array(prog, "light_tile", [(i * s / sw, 0.0, s / sw, s / sh) for i in range(len(lights))])
        proxies, ranges = [], []
        for st, _ in drawn:
            first = len(proxies)
            proxies += list(st.obj.world_proxies())[:MAX_PROXIES - first]
            ranges.append((first, len(proxies)))
        write_array(prog, "proxy_range", ranges, np.int32)
        if proxies:
            write_array(prog, "proxy", np.stack(proxies))

    def impostor_uniforms(self, prog: moderngl.Program, drawn: list[tuple[ObjectGPU, Tile]]) -> None:
        """The uniforms of ``impostors.glsl`` (unit 11) for the objects :meth:`prepare` drew."""
        imp = self._fbos["impostors"][1]
        aw, ah = imp.size
        imp.use(11)
        set_uniform(prog, "imp_atlas", 11)
        set_uniform(prog, "n_objects", len(drawn))
        write_array(prog, "imp_vp", np.stack([t.vp.T for _, t in drawn]))
        write_array(prog, "imp_tile", [(t.rect[0] / aw, t.rect[1] / ah, t.rect[2] / aw, t.rect[3] / ah)
                                  for _, t in drawn])

    def _probe_array(self, drawn: list[tuple[ObjectGPU, Tile]]) -> moderngl.TextureArray:
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


def set_lighting(prog: moderngl.Program, spec_levels: list[torch.Tensor], dirs: torch.Tensor,
                  power: torch.Tensor) -> None:
    """ibl.glsl's probe uniforms: the residual's size and levels, the peak samples."""
    h, w = spec_levels[0].shape[-2:]
    set_uniform(prog, "env_size", (float(w), float(h)))
    set_uniform(prog, "env_max_lod", float(len(spec_levels) - 1))
    set_uniform(prog, "n_peaks", int(dirs.shape[0]))
    if dirs.shape[0]:
        write_array(prog, "peak_dir", dirs.numpy())
        write_array(prog, "peak_power", power.numpy())


def reflectance(material: ObjectMaterial) -> np.ndarray:
    """What a surface of this material reflects of uniform light: B (1 - M) + F0 A + B at n.v = 1."""
    b = torch.tensor(material.base_color, dtype=torch.float32)
    m = torch.tensor(float(material.metallic))
    spec = prefilter.specular_albedo(torch.tensor(1.0), torch.tensor(float(material.roughness)),
                                     f0_from_material(b, m))
    return (b * (1 - m) + spec).numpy()


def turned_camera(vp: np.ndarray, old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """``vp`` (an impostor camera at the origin aimed at ``old``) for an object moved to ``new``: the
    rotation about the origin taking ``new``'s direction to ``old``'s and the change of apparent size
    (clip x, y scaled by the distances' ratio).  A draft's stand-in for drawing the impostor again;
    exact for rotations about the camera, close for moves of a few pixels."""
    dn, do = float(np.linalg.norm(new)), float(np.linalg.norm(old))
    a, b = old / do, new / dn
    v, c = np.cross(b, a), float(np.dot(b, a))
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    turn = np.eye(4)
    turn[:3, :3] = np.eye(3) + k + k @ k / max(1.0 + c, 1e-9)  # Rodrigues: b -> a
    return np.diag([dn / do, dn / do, 1.0, 1.0]) @ vp @ turn


def run_steps(steps: Generator[object, None, object]) -> object:
    """Run a generator of steps to its end; returns what it returns."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value
