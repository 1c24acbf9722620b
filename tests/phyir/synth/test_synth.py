"""Synthetic data generator: rooms, exact geometry, files, manifest/resume/sharding."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from phyir.pano import depth_to_points, normals_from_depth
from phyir.synth import geometry as G
from phyir.synth.dataset import (
    DatasetConfig,
    generate_dataset,
    generate_scene,
    make_tiny_dataset,
    scene_name,
    shard_indices,
    split_of,
    tiny_settings,
)
from phyir.synth.footprints import point_in_obb
from phyir.synth.lights import AREA, PORTAL, SUN
from phyir.synth.rooms import (
    CAMERA_HEIGHT,
    HALL_HEIGHT,
    HALL_SHARE,
    HALL_SOURCES,
    HALL_WIDTH,
    ROOM_HEIGHT,
    ROOM_WIDTH,
    SOURCES,
    generate_room,
)
from phyir.synth.tracer import trace

ROOMS = [generate_room(np.random.default_rng([11, i])) for i in range(25)]


def _solid_sdf(P: G.Prims, p: torch.Tensor) -> torch.Tensor:
    """Signed distances ``[N, boxes+cylinders+spheres]`` of points ``p [N,3]`` (negative inside),
    computed from the primitive parameters independently of the intersection code."""
    out = []
    if P.counts[G.BOX]:
        c, s = torch.cos(P.b_yaw), torch.sin(P.b_yaw)
        q = p[:, None] - P.b_c[None]
        loc = torch.stack((c * q[..., 0] - s * q[..., 2], q[..., 1], s * q[..., 0] + c * q[..., 2]), -1)
        d = loc.abs() - P.b_h[None]
        out.append(d.clamp(min=0).norm(dim=-1) + d.amax(-1).clamp(max=0))
    if P.counts[G.CYL]:
        q = p[:, None] - P.c_c[None]
        dr = torch.sqrt(q[..., 0] ** 2 + q[..., 2] ** 2) - P.c_r
        dy = q[..., 1].abs() - P.c_hh
        outside = torch.sqrt(dr.clamp(min=0) ** 2 + dy.clamp(min=0) ** 2)
        out.append(outside + torch.maximum(dr, dy).clamp(max=0))
    if P.counts[G.SPH]:
        out.append((p[:, None] - P.s_c[None]).norm(dim=-1) - P.s_r)
    return torch.cat(out, 1)


def _sample_inside(P: G.Prims, gid: int, n: int, g: torch.Generator) -> torch.Tensor:
    u = torch.rand(n, 3, generator=g) * 2 - 1
    k = int(P.kind[gid])
    i = gid - P.offsets[k]
    if k == G.BOX:
        loc = u * P.b_h[i] * 0.98
        c, s = math.cos(float(P.b_yaw[i])), math.sin(float(P.b_yaw[i]))
        x, z = c * loc[:, 0] + s * loc[:, 2], -s * loc[:, 0] + c * loc[:, 2]
        return P.b_c[i] + torch.stack((x, loc[:, 1], z), 1)
    if k == G.CYL:
        r = P.c_r[i] * 0.98 * u[:, 0].abs().sqrt()
        a = math.pi * u[:, 1]
        return P.c_c[i] + torch.stack((r * torch.cos(a), u[:, 2] * P.c_hh[i] * 0.98, r * torch.sin(a)), 1)
    d = u / u.norm(dim=1, keepdim=True).clamp(min=1e-6)
    return P.s_c[i] + d * P.s_r[i] * 0.98 * torch.rand(n, 1, generator=g)


def test_rooms_are_deterministic():
    a = generate_room(np.random.default_rng([5, 3]))
    b = generate_room(np.random.default_rng([5, 3]))
    assert a.prims == b.prims and a.camera == b.camera and a.yaw == b.yaw
    c = generate_room(np.random.default_rng([5, 4]))
    assert c.prims != a.prims


def test_rooms_cover_halls_studios_dark_ceilings_and_camera_heights():
    rooms = [generate_room(np.random.default_rng([12, i])) for i in range(300)]
    halls = [r for r in rooms if r.hall]
    # binomial(300, HALL_SHARE): 45 +- 6.2; 4 sigma either side
    assert abs(len(halls) - 300 * HALL_SHARE) < 4 * (300 * HALL_SHARE * (1 - HALL_SHARE)) ** 0.5
    assert max(max(r.summary()["width"], r.summary()["depth"]) for r in halls) > 20
    assert max(r.height for r in halls) > 6
    styles = {r.style for r in rooms}
    assert styles == {"home", "studio", "dark_ceiling"}
    heights = [r.camera[1] for r in rooms]
    assert min(heights) < 1.1 and max(heights) > 1.9
    # a dark ceiling is dark, a studio's walls white (ceiling material is the shell's second)
    dark = next(r for r in rooms if r.style == "dark_ceiling")
    assert max(dark.materials[1].c1) < 0.25
    studio = next(r for r in rooms if r.style == "studio")
    assert min(studio.materials[2].c1) > 0.75


@pytest.mark.parametrize("room", ROOMS, ids=[f"room{i}" for i in range(len(ROOMS))])
def test_room_sizes_camera_and_lights(room):
    s = room.summary()
    sides, heights, n_sources = (HALL_WIDTH, HALL_HEIGHT, HALL_SOURCES) if s["hall"] else \
        (ROOM_WIDTH, ROOM_HEIGHT, SOURCES)
    for side in (s["width"], s["depth"]):
        assert sides[0] - 1e-9 <= side <= sides[1] + 1e-9
    assert heights[0] <= room.height <= heights[1]
    x, y, z = room.camera
    assert CAMERA_HEIGHT[0] <= y <= CAMERA_HEIGHT[1]
    assert room.contains(x, z, 0.3)
    assert not any(point_in_obb(room.camera, it, 0.1) for it in room.items)
    sc = room.build()
    kinds = sc.lights.kind.tolist()
    sources = len(kinds) - kinds.count(SUN)
    assert 1 <= sources <= n_sources[1]
    # dynamic range: a room lit by the sky alone would be too flat; without the sun it has a lamp or panel
    if SUN not in kinds:
        assert kinds.count(AREA) >= 1
    # the camera is in free space: no primitive contains it (independent signed distances)
    assert float(_solid_sdf(sc.prims, torch.zeros(1, 3)).min()) > 0.05


@pytest.mark.parametrize("room", ROOMS[:12], ids=[f"room{i}" for i in range(12)])
def test_furniture_does_not_interpenetrate(room):
    """Points sampled inside each item's primitives lie outside every other item's primitives
    and inside the room (floor to ceiling, within the footprint)."""
    P = room.build().prims
    g = torch.Generator().manual_seed(0)
    solids = list(range(P.counts[0], P.n_prims))
    pts = torch.cat([_sample_inside(P, gid, 100, g) for gid in solids])
    owner = P.group[torch.tensor(solids)].repeat_interleave(100)
    sdf = _solid_sdf(P, pts)
    other = owner[:, None] != P.group[P.counts[0]:][None]
    assert float(sdf[other].min()) > -2e-3
    # inside the room: rotate back to the room frame and test the footprint polygon
    R = torch.tensor(room.camera_matrix(), dtype=torch.float32)
    pts = pts[::10] @ R + torch.tensor(room.camera, dtype=torch.float32)  # R^T p + cam
    assert float(pts[:, 1].min()) > -1e-3 and float(pts[:, 1].max()) < room.height + 1e-3
    assert all(room.contains(float(p[0]), float(p[2]), -1e-3) for p in pts)


@pytest.fixture(scope="module")
def small_trace():
    room = generate_room(np.random.default_rng([3, 1]))
    sc = room.build()
    res = trace(sc, tiny_settings(size=(64, 128), probe_grid=None, spp=1), seed=0)
    return sc, res


def test_geometry_ground_truth_is_exact(small_trace):
    sc, res = small_trace
    n_est = normals_from_depth(res.depth)
    cosang = (n_est * res.normal).sum(0).clamp(-1, 1)
    ang = torch.rad2deg(torch.acos(cosang))
    assert float(ang.median()) < 2.0
    # re-projected depth lies on the analytic surfaces of the room (camera frame)
    pts = depth_to_points(res.depth).reshape(3, -1).T
    dist = G.surface_distance(sc.prims, pts)
    assert float(dist.max()) < 1e-3 * float(res.depth.max())
    # the normal layer faces the camera and is unit
    assert float((res.normal * depth_to_points(res.depth)).sum(0).max()) < 1e-4
    assert torch.allclose(res.normal.norm(dim=0), torch.ones(1), atol=1e-4)


def test_same_seed_same_scene_other_seed_other_noise():
    st = tiny_settings()
    a = generate_scene(4, 2, st)
    b = generate_scene(4, 2, st)
    for name in ("image", "depth", "normal", "albedo", "roughness", "metallic", "probes"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    timing = ("render_seconds", "render_stats")
    assert {k: v for k, v in a.meta.items() if k not in timing} == {k: v for k, v in b.meta.items()
                                                                     if k not in timing}
    c = generate_scene(4, 2, st, sampler_seed=99)
    assert torch.equal(a.depth, c.depth) and torch.equal(a.albedo, c.albedo)  # same room, exact layers
    assert not torch.equal(a.image, c.image)  # other sampler seed


def test_dataset_manifest_resume_and_shards(tmp_path):
    from phyir.errors import PhyIRError
    from phyir.io import load_scene

    out = tmp_path / "ds"
    cfg = DatasetConfig(seed=7, count=4, size=(16, 32), probe_grid=(4, 8), probe_size=(4, 8), spp=2,
                        half=True)
    st = tiny_settings((16, 32), (4, 8), (4, 8), 2)
    r0 = generate_dataset(out, cfg, (0, 2), settings=st, progress=False)
    assert r0["written"] == 2 and sorted(p.name for p in out.glob("*.exr")) == [scene_name(0), scene_name(2)]
    r1 = generate_dataset(out, cfg, (1, 2), settings=st, progress=False)
    assert r1["written"] == 2
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.exr")}
    r2 = generate_dataset(out, cfg, (0, 1), settings=st, progress=False)  # resume: nothing left
    assert r2 == {**r2, "written": 0, "skipped": 4}
    assert mtimes == {p.name: p.stat().st_mtime_ns for p in out.glob("*.exr")}
    man = json.loads((out / "manifest.json").read_text())
    names = sorted(n for v in man["splits"].values() for n in v)
    assert names == [scene_name(i) for i in range(4)]
    for split, files in man["splits"].items():
        assert all(split_of(7, int(f[6:12])) == split for f in files)
    # a shard renders exactly what a single run would
    single = generate_scene(7, 1, st)
    sharded = load_scene(out / scene_name(1))
    assert torch.allclose(sharded.depth, single.depth, rtol=1e-3)  # half floats on disk
    # other settings in the same folder are refused
    with pytest.raises(PhyIRError, match="other settings"):
        generate_dataset(out, DatasetConfig(seed=8, count=4, size=(16, 32)), settings=st, progress=False)


def test_shards_partition_and_splits():
    for n in (1, 3, 7):
        parts = [shard_indices(50, (k, n)) for k in range(n)]
        assert sorted(i for p in parts for i in p) == list(range(50))
    splits = [split_of(0, i) for i in range(2000)]
    assert abs(splits.count("train") / 2000 - 0.8) < 0.04
    assert splits[:50] == [split_of(0, i) for i in range(50)]


def test_tiny_dataset_files_open_and_validate(tmp_path):
    from phyir.io import load_scene

    paths = make_tiny_dataset(tmp_path, count=2)
    for p in paths:
        s = load_scene(p).validate()
        assert s.image.shape == (3, 32, 64) and s.probes.shape == (8, 16, 3, 8, 16)
        assert set(s.masks) == {"emission"} and float(s.masks["emission"].max()) <= 1
        assert float(s.depth.min()) > 0.3
        lights = json.loads(s.meta["lights"])
        assert lights["panels_and_lamps"] + lights["windows"] >= 1
        # the brightest source is 10^2-10^4 x the median non-emissive pixel (the sun counts even unseen)
        median = float(s.image.mean(0)[s.masks["emission"][0] < 0.5].median())
        assert 100 <= float(s.meta["brightest_source"]) / median <= 1e4
        # exposure normalisation: median non-emissive luminance near 0.18 (x 2^+-1)
        lum = s.image.mean(0)[s.masks["emission"][0] < 0.5]
        assert 0.05 < float(lum.median()) < 0.5


def test_cli_synth(tmp_path, capsys):
    from phyir.cli import main

    assert main(["synth", "--out", str(tmp_path / "x"), "--count", "1", "--size", "bad"]) == 2
    assert main(["synth", "--out", str(tmp_path / "x"), "--count", "1", "--shard", "3/2"]) == 2
    assert main(["synth", "--out", str(tmp_path / "x"), "--count", "1", "--size", "32x64",
                 "--probe-grid", "7x16"]) == 2
    err = capsys.readouterr().err
    assert "--size" in err and "--shard" in err and "--probe-grid" in err


def test_windows_show_the_sky_and_sun():
    """A room with windows and sun: portal pixels carry sky radiance, the sun reaches the probes."""
    for i in range(40):
        room = generate_room(np.random.default_rng([2022, i]))
        sc = room.build()
        if sc.lights.has_sun:
            break
    kinds = sc.lights.kind.tolist()
    assert PORTAL in kinds and SUN in kinds
    d = sc.lights.sun_dir
    # the sky is brighter toward the horizon than the ground, and the sun disc is far brighter
    w = torch.stack((d, torch.tensor([0.0, -1.0, 0.0])))
    sky = sc.lights.sky(w)
    sun = sc.lights.sun(w)
    assert float(sun[0].mean()) > 100 * float(sky[0].mean()) and float(sun[1].sum()) == 0
