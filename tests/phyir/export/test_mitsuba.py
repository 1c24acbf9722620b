"""An independent renderer, Mitsuba 3 (CPU, scalar_rgb), rendering the exported *file*: the room seen
from the camera is the panorama, and a diffuse sphere inserted into it is lit as ``phyir insert``
lights it (docs/export.md: which emission goes with which lights)."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from phyir import pano
from phyir.export.bundle import export_gltf
from phyir.export.lights import BRIGHT_FACTOR
from phyir.io import exr, load_scene

pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install mitsuba; in the dev extra)")
from phyir.export import mitsuba as emi  # noqa: E402

DEMO = "phyir/assets/demo.exr"
VIEWS = [(0, 0), (90, 0), (180, 10), (-90, -20), (45, -50), (-135, 40)]  # yaw, pitch (degrees)
SPHERE = ("0.0,-0.5,-2.0", 0.25)  # centre (m), radius (m): floating 0.9 m above the demo's floor


@pytest.fixture(scope="module")
def demo():
    return load_scene(DEMO)


@pytest.fixture(scope="module")
def room_glb(demo, tmp_path_factory):
    return export_gltf(demo, str(tmp_path_factory.mktemp("mi") / "demo.glb")).glb


def smooth_depth(depth: torch.Tensor, tol: float = 0.05) -> np.ndarray:
    """Pixels whose 5x5 neighbourhood's depths differ by less than ``tol`` (relative): away from
    depth discontinuities (where the mesh has holes or a triangle's UVs bend)."""
    d = depth[None]
    hi = F.max_pool2d(d, 5, 1, 2)
    lo = -F.max_pool2d(-d, 5, 1, 2)
    return (hi / lo < 1 + tol)[0].numpy()


def rel_l1(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).sum() / np.abs(b).sum())


@pytest.mark.parametrize("emission", ["exr", "glb"])
def test_the_exported_room_seen_from_the_camera_is_the_panorama(demo, room_glb, emission):
    scene = emi.scene_dict(room_glb, emission=emission, lights=False)
    level = BRIGHT_FACTOR * float((demo.image.mean(0) * pano.solid_angles(*demo.size)).sum() / (4 * math.pi))
    errors = []
    for yaw, pitch in VIEWS:
        y, p = math.radians(yaw), math.radians(pitch)
        got = emi.render_view(scene, y, p, 60, 64, 16, max_depth=1)
        ref = pano.perspective_crop(demo.image, 64, 64, 60, y, p).permute(1, 2, 0).numpy()
        ok = smooth_depth(pano.perspective_crop(demo.depth, 64, 64, 60, y, p)[0])
        if emission == "glb":  # the glb's texture holds the panorama below the lights' level
            lum = pano.perspective_crop(demo.image.mean(0, keepdim=True), 64, 64, 60, y, p)
            ok &= (F.max_pool2d(lum, 5, 1, 2)[0] < level).numpy()
        errors.append(rel_l1(got[ok], ref[ok]))
    print(f"{emission}: relative L1 per view {np.round(errors, 4).tolist()}")
    assert max(errors) <= 0.10


def object_pass(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``phyir insert``'s object radiance (object.RGB / object.A) and its interior (A = 1, eroded)."""
    chans = exr.read_pixels(path, exr.read_headers(path))[0]
    a = chans["object.A"]
    inside = a >= 0.999
    inside &= np.roll(inside, 1, 0) & np.roll(inside, -1, 0) & np.roll(inside, 1, 1) & np.roll(inside, -1, 1)
    rgb = np.stack([chans[f"object.{c}"] for c in "RGB"], -1)
    return rgb / np.maximum(a, 1e-6)[..., None], inside


@pytest.mark.gl
def test_a_diffuse_sphere_in_the_exported_room_matches_phyir_insert(egl, tmp_path):
    from viewer.commands import insert

    centre, radius = SPHERE
    common = ["--object", "sphere", "--position", centre, "--scale", str(radius), "--material", "diffuse"]
    parser = argparse.ArgumentParser()
    insert.add_arguments(parser)
    out = str(tmp_path / "insert.exr")
    insert.run(parser.parse_args([DEMO, *common, "--view", "perspective", "--size", "64x64", "--fov", "20",
                                  "-o", out]))
    ref, inside = object_pass(out)
    from phyir.commands import export as export_cmd

    parser = argparse.ArgumentParser()
    export_cmd.add_arguments(parser)
    glb = str(tmp_path / "sphere.glb")
    export_cmd.run(parser.parse_args([DEMO, "--gltf", glb, *common]))
    c = np.array([float(x) for x in centre.split(",")])
    yaw, pitch = math.atan2(c[0], -c[2]), math.atan2(c[1], math.hypot(c[0], c[2]))  # insert aims at it
    results = {}
    for emission, lights in (("exr", False), ("glb", True), ("exr", True)):
        img = emi.render_view(emi.scene_dict(glb, emission=emission, lights=lights), yaw, pitch, 20, 64, 128,
                              max_depth=3)
        got, want = img[inside], ref[inside]
        results[emission, lights] = (rel_l1(got, want), float(got.mean() / want.mean()))
    print({f"{e}{'+lights' if li else ''}": tuple(round(x, 3) for x in v) for (e, li), v in results.items()})
    # the whole panorama as emitter, or the glb's texture with the lights: each holds the energy once
    assert results["exr", False][0] <= 0.15 and results["glb", True][0] <= 0.15
    # both together count the bright sources twice: brighter than either
    assert results["exr", True][1] > max(results["exr", False][1], results["glb", True][1]) + 0.02
