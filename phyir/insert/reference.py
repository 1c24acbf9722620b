"""References for object insertion.

Path-traced: a synthetic room rendered with and without an added sphere by the data generator's tracer
(:mod:`phyir.synth`), used by ``benchmarks.insert_vs_pathtrace`` to measure the GPU insertion against
ground truth.  The room is the one :func:`phyir.synth.dataset.generate_scene` draws for
``(seed, index)``; the sphere is one more primitive of the room (its own material and culling group),
so the tracer simulates everything the insertion approximates: shadows, occlusion near contact,
interreflection.

Brute force: what a sphere hides of the light arriving at floor points (:func:`sphere_occlusion`) and
the irradiance of a probe around given normals (:func:`irradiance_towards`), the pieces of
``benchmarks.shadow_ring_reference``'s floor-ring darkening.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano
from phyir.scene import PanoScene
from phyir.synth import geometry as G
from phyir.synth.materials import PLAIN, Material
from phyir.synth.room import PrimSpec, Room
from phyir.synth.rooms import generate_room
from phyir.synth.trace_settings import TraceSettings
from phyir.synth.tracer import trace


@dataclass
class Reference:
    scene: PanoScene  # the room without the sphere: GT layers and probes (what insertion gets)
    without: torch.Tensor  # [3, H, W] the room traced without the sphere at the reference's settings
    with_sphere: dict[str, torch.Tensor]  # material name -> [3, H, W] the room traced with the sphere
    centre: np.ndarray  # camera frame, metres
    radius: float
    seconds: float


def room_for(seed: int, index: int) -> Room:
    return generate_room(np.random.default_rng([seed, index]))


def add_sphere(room: Room, centre_cam: np.ndarray, radius: float,
               material: tuple[tuple[float, float, float], float, float]) -> Room:
    """A copy of ``room`` with a sphere (``material`` = base colour, roughness, metalness) whose
    centre is ``centre_cam`` in the camera frame of :meth:`Room.build`."""
    import copy

    r = copy.deepcopy(room)
    R = r.camera_matrix()
    c_room = R.T @ np.asarray(centre_cam, np.float64) + np.asarray(r.camera, np.float64)  # inverse of build's
    base, rough, metal = material
    r.materials = list(r.materials) + [Material(PLAIN, tuple(base), tuple(base), 1.0, (rough, rough), metal)]
    group = 1 + max([p.group for p in r.prims] + [-1])
    r.prims = list(r.prims) + [PrimSpec(G.SPH, tuple(float(x) for x in c_room), (float(radius),),
                                        len(r.materials) - 1, group=group)]
    return r


def floor_spot(scene: PanoScene, distance: tuple[float, float] = (1.3, 2.2), clearance: float = 0.5
               ) -> tuple[float, float]:
    """Pixel (u, v) of a floor point at ``distance`` metres whose neighbourhood within ``clearance``
    metres is floor too (no furniture), nearest the image centre column."""
    H, W = scene.size
    d = pano.directions(H, W)
    p = scene.depth * d
    floor_y = float(p[1][scene.normal[1] > 0.99].median())
    is_floor = (scene.normal[1] > 0.99) & ((p[1] - floor_y).abs() < 0.02)
    horiz = torch.sqrt(p[0] ** 2 + p[2] ** 2)
    cand = is_floor & (horiz > distance[0]) & (horiz < distance[1])
    best, best_score = None, math.inf
    for i, j in torch.nonzero(cand).tolist():
        c = p[:, i, j]
        near = (torch.linalg.vector_norm(p - c[:, None, None], dim=0) < clearance) & (p[1] > floor_y - 0.5)
        # every scene point near the spot must be floor (no furniture or wall within the clearance)
        if bool((near & ~is_floor).any()):
            continue
        score = abs(j + 0.5 - W / 2) + 0.1 * abs(i - 0.75 * H)
        if score < best_score:
            best, best_score = (j + 0.5, i + 0.5), score
    if best is None:
        raise RuntimeError("no free floor spot in this room")
    return best


def trace_reference(seed: int, index: int, radius: float,
                    materials: dict[str, tuple[tuple[float, float, float], float, float]], *,
                    size: tuple[int, int] = (128, 256), probe_grid: tuple[int, int] = (16, 32),
                    probe_size: tuple[int, int] = (16, 32), spp: int = 64, ref_spp: int = 256,
                    sampler_seed: int = 7) -> Reference:
    """Trace room ``(seed, index)`` without the sphere (layers + probes at ``spp``; image at
    ``ref_spp``) and with a sphere of each material (image at ``ref_spp``), the sphere of ``radius``
    resting on a free floor spot in front of the camera."""
    import time

    from phyir.insert.placement import surface_at

    t0 = time.perf_counter()
    room = room_for(seed, index)
    st = TraceSettings(size=size, probe_grid=probe_grid, probe_size=probe_size, spp=spp)
    res = trace(room.build(), st, seed=sampler_seed)
    scene = PanoScene(image=res.image, depth=res.depth, normal=res.normal, albedo=res.albedo,
                      roughness=res.roughness, metallic=res.metallic, probes=res.probes,
                      masks={"emission": res.emission})
    u, v = floor_spot(scene)
    contact = surface_at(scene, u, v).point
    centre = contact + np.array([0.0, radius, 0.0])
    st_ref = TraceSettings(size=size, probe_grid=None, spp=ref_spp)
    without = trace(room.build(), st_ref, seed=sampler_seed).image
    with_sphere = {name: trace(add_sphere(room, centre, radius, m).build(), st_ref, seed=sampler_seed).image
                   for name, m in materials.items()}
    return Reference(scene, without, with_sphere, centre, radius, time.perf_counter() - t0)


def sphere_mask(centre: np.ndarray, radius: float, depth: torch.Tensor) -> torch.Tensor:
    """[H, W] bool: pixels whose camera ray meets the sphere before the scene surface."""
    H, W = depth.shape[-2:]
    d = pano.directions(H, W, dtype=torch.float64)
    c = torch.as_tensor(centre, dtype=torch.float64)[:, None, None]
    b = (d * c).sum(0)
    disc = b * b - float((c * c).sum()) + radius * radius
    t = b - torch.sqrt(disc.clamp(min=0))
    return (disc > 0) & (t > 0) & (t < depth[0].double())


def sphere_occlusion(x: torch.Tensor, dirs: torch.Tensor, centre: torch.Tensor, r: float,
                     sub: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    """Per point ``x [N,3]`` and texel direction ``dirs [3,h,w]``: the share of the texel the sphere
    covers (``sub`` x ``sub`` jittered directions) and the mean unit normal where they hit it."""
    h, w = dirs.shape[-2:]
    rows, cols = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                                indexing="ij")
    cover = torch.zeros(x.shape[0], h, w, dtype=torch.float64)
    normal = torch.zeros(x.shape[0], 3, h, w, dtype=torch.float64)
    oc = centre[None, :, None, None] - x[:, :, None, None]  # [N,3,1,1]
    for a in range(sub):
        for b in range(sub):
            d = pano.uv_to_dir(cols + (b + 0.5) / sub, rows + (a + 0.5) / sub, h, w)[None]  # [1,3,h,w]
            t = (oc * d).sum(1)
            miss2 = (oc * oc).sum(1) - t * t
            hit = (t > 0) & (miss2 < r * r)
            th = t - torch.sqrt((r * r - miss2).clamp_min(0))
            p = x[:, :, None, None] + th[:, None] * d
            m = (p - centre[None, :, None, None]) / r
            cover += hit.double()
            normal += m * hit[:, None].double()
    cover /= sub * sub
    normal = torch.nn.functional.normalize(normal, dim=1)
    return cover, normal


def irradiance_towards(probe: torch.Tensor, normals: torch.Tensor, map_size: tuple[int, int] = (32, 64)
                       ) -> torch.Tensor:
    """Irradiance ``[N,3,h,w]`` of ``probe [3,ph,pw]`` around unit normals ``normals [N,3,h,w]``: its
    irradiance map (brute force over the probe's texels, smooth), looked up bilinearly."""
    ph, pw = probe.shape[-2:]
    d = pano.directions(ph, pw, dtype=torch.float64).reshape(3, -1)
    om = pano.solid_angles(ph, pw, dtype=torch.float64).reshape(-1)
    L = probe.double().reshape(3, -1) * om  # [3,T]
    mh, mw = map_size
    n = pano.directions(mh, mw, dtype=torch.float64).reshape(3, -1)
    emap = (L @ (n.T @ d).clamp_min(0).T).reshape(3, mh, mw)
    N, _, h, w = normals.shape
    flat = normals.permute(1, 0, 2, 3).reshape(3, -1)
    return pano.sample_dir(emap, flat).reshape(3, N, h, w).permute(1, 0, 2, 3)
