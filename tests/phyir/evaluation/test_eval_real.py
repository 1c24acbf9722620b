"""phyir.evaluation.real / real_lighting: the no-ground-truth checks on exact synthetic scenes, the
brute-force integrator against analytic answers and the renderer, and ``phyir eval --real`` end to end."""

from __future__ import annotations

import json
import math

import pytest
import torch

from phyir import pano
from phyir.evaluation import real as R
from phyir.evaluation import real_lighting as RL
from phyir.scene import PanoScene

H, W = 64, 128
BOX = ((-3.5, 4.0), (-1.5, 1.3), (-4.0, 3.6))  # x, y, z extents (m): camera 1.5 m above the floor
LAMP = (slice(4, 8), slice(40, 44))  # one texel of a 16 x 32 probe, 73 degrees up (at 64 x 128)


def box_scene(box=BOX, h: int = H, w: int = W) -> PanoScene:
    """An axis-aligned box room seen from the origin: exact radial depth and inward normals, a
    base colour per wall and an image that is the base colour plus a lamp on the ceiling."""
    d = pano.directions(h, w, dtype=torch.float64)
    ts = []
    for a, (lo, hi) in enumerate(box):
        bound = torch.where(d[a] > 0, torch.full_like(d[a], hi), torch.full_like(d[a], lo))
        ts.append(torch.where(d[a] != 0, bound / d[a], torch.full_like(d[a], math.inf)))
    t, axis = torch.stack(ts).min(0)
    normal = torch.zeros(3, h, w, dtype=torch.float64)
    for a in range(3):
        normal[a] = torch.where(axis == a, -torch.sign(d[a]), torch.zeros_like(d[a]))
    colours = torch.tensor([[0.6, 0.3, 0.2], [0.5, 0.5, 0.5], [0.2, 0.4, 0.6]], dtype=torch.float64)
    albedo = colours[axis].permute(2, 0, 1)
    image = albedo.clone()
    rows, cols = LAMP
    def at(k: int) -> int:
        return k * h // H

    image[:, at(rows.start):at(rows.stop), at(cols.start):at(cols.stop)] += 50.0  # a lamp
    return PanoScene(image=image.float(), depth=t[None].float(), normal=normal.float(), albedo=albedo.float())


def rotated_box(box=BOX) -> tuple:
    """The box turned by the world rotation equal to rolling the panorama W/4 columns right:
    yaw_matrix(-pi/2) maps (x, z) to (-z, x)."""
    (x0, x1), y, (z0, z1) = box
    return ((-z1, -z0), y, (x0, x1))


# ---------------------------------------------------------------------------------------------
# geometry facts


def test_plausibility_of_exact_box_room():
    p = R.plausibility(box_scene())
    assert p["nadir_up"] == 1.0 and p["zenith_down"] == 1.0
    assert p["floor_planarity"] < 1e-5
    assert p["camera_height"] == pytest.approx(1.5, rel=1e-4)


def test_exact_depth_and_normals_are_consistent_and_confident():
    s = box_scene()
    assert R.consistency_deg(s) < 3.0  # only the wall creases differ (central differences)
    c = R.scene_confidence(s)
    # all that is left is the room-size factor (the box reaches 4.2 m: 0.89)
    size_factor = 1 / (1 + (c["far_m"] / R.FAR_SCALE_M) ** 2)
    assert size_factor > 0.85 and c["confidence"] > 0.99 * size_factor and not c["flagged"]
    assert set(R.plausibility(s)) <= set(c)


def test_wrong_normals_are_flagged():
    s = box_scene()
    up = torch.zeros_like(s.normal)
    up[1] = 1.0  # every normal collapsed to +y (what a failed prediction looks like)
    c = R.scene_confidence(s.replace(normal=up))
    assert c["zenith_down"] == 0.0 and c["consistency_deg"] > 45
    assert c["flagged"] and c["confidence"] < 0.2
    assert R.scene_confidence(s.replace(normal=-s.normal))["flagged"]


def test_central_normals_of_a_plane():
    s = box_scene()
    n = R.central_normals(s.depth)
    lat = torch.rad2deg(pano.pixel_lonlat(H, W, dtype=torch.float64)[1])
    floor = lat < -70
    assert torch.allclose(n[:, floor], s.normal[:, floor].double(), atol=1e-6)


# ---------------------------------------------------------------------------------------------
# invariances


def test_yaw_back_transform_is_exact_on_a_rotated_room():
    a, b = box_scene(), box_scene(rotated_box())
    shift = W // 4
    # the rotated room is the rolled panorama with rotated normals (checks the generator and the sign)
    assert torch.allclose(b.depth, torch.roll(a.depth, shift, -1), atol=1e-5)
    back = R.yaw_back(b, shift)
    assert torch.allclose(back.depth, a.depth, atol=1e-5)
    assert torch.allclose(back.normal, a.normal, atol=1e-5)
    assert R.median_angle(back.normal, a.normal) < 1e-3
    # the test tells the senses apart: rotating the rolled-back normals the other way fails
    wrong = pano.yaw_matrix(-pano.yaw_shift_angle(-shift, W))
    wrong_normals = pano.rotate_vectors(wrong, torch.roll(b.normal, -shift, -1), dim=0)
    assert float(R.angle_deg(wrong_normals, a.normal).max()) > 170


def test_invariance_errors_are_zero_for_an_invariant_predictor():
    s = box_scene()

    def oracle(x: torch.Tensor, **kw) -> PanoScene:
        """'Predicts' the box room at any size and yaw (what a perfect network would)."""
        h, w = x.shape[-2:]
        shift = int(torch.argmax(x[0, : h // 8].sum(0))) * W // w - LAMP[1].start
        out = box_scene(h=h, w=w) if shift % W == 0 else box_scene(rotated_box(), h, w)
        return out

    inv = R.invariances(s.image, s, s, True, oracle)
    assert set(inv) == set(R.INVARIANCE_KEYS)
    assert inv["yaw.depth"] < 1e-5 and inv["yaw.normal_deg"] < 1e-2 and inv["yaw.albedo"] < 1e-5
    assert inv["exposure_16.depth"] == 0 and inv["ldr.normal_deg"] == 0
    assert inv["res_half.depth"] < 0.05 and inv["res_double.normal_deg"] < 1.0


def test_ldr_copy_is_auto_exposed_8_bit():
    s = box_scene()
    from phyir.learn.camera import AUTO_EXPOSURE_KEY, ldr_copy

    ldr, scale = ldr_copy(s.image)
    assert 0 <= float(ldr.min()) and float(ldr.max()) <= 1
    from phyir.color import linear_to_srgb, luminance

    assert float(luminance(ldr).median()) == pytest.approx(AUTO_EXPOSURE_KEY, rel=0.02)
    levels = linear_to_srgb(ldr.numpy()) * 255
    assert abs(levels - levels.round()).max() < 1e-3
    assert scale == pytest.approx(AUTO_EXPOSURE_KEY / float(luminance(s.image).median()))


# ---------------------------------------------------------------------------------------------
# the brute-force integrator


def test_integrator_constant_environment_gives_albedo_times_radiance():
    n, v, _ = RL.sphere_pixels()
    env = torch.full((1, 3, 16, 32), 2.0)
    base = (0.2, 0.5, 0.8)
    d, s = RL.integrate(env, n, v, (base, 0.7, 0.0))
    assert torch.allclose(d[0], 2.0 * torch.tensor(base, dtype=torch.float64).expand_as(d[0]), rtol=2e-3)
    assert float(s.min()) > 0  # the specular lobe adds F-weighted light


@pytest.mark.parametrize("material", list(RL.MATERIALS))
def test_integrator_matches_the_renderer_on_a_random_environment(material):
    from phyir.evaluation.metrics import render_spheres

    g = torch.Generator().manual_seed(1)
    env = pano.resize_area(torch.rand(1, 3, 4, 8, generator=g) * 3, 16, 32)
    env[:, :, 4, 20] += 30.0  # a lamp
    ours, mask = RL.render_sphere(env, material)
    c = torch.tensor(RL.SPHERE_CENTRE, dtype=torch.float64)
    ref = render_spheres(env.double(), (c / c.norm())[None], material, size=RL.SPHERE_PIXELS, spp=512)[0]
    m = RL.sphere_metrics(ours[0], ref[:, mask].T)
    assert m["rel_l1"] < 0.02 and abs(m["ratio"] - 1) < 0.01 and m["colour_deg"] < 0.5


def test_sphere_metrics_and_peak_direction():
    t = torch.rand(50, 3) + 0.1
    m = RL.sphere_metrics(2 * t, t)
    assert m["rel_l1"] == pytest.approx(1.0) and m["si_rel_l1"] < 1e-9
    assert m["ratio"] == pytest.approx(2.0) and m["colour_deg"] < 1e-5
    env = torch.zeros(3, 16, 32)
    env[:, 3, 24] = 5.0
    assert RL.peak_error_deg(env, pano.resize_area(env.expand(3, 16, 32) * 1, 64, 128), (16, 32)) < 1e-3


def test_evaluate_lighting_units_with_an_oracle_method():
    """An environment read back from the panorama itself matches the truth in both rows (HDR, and
    LDR copy in its own units): checks the truth scaling, the registry and the result layout."""
    s = box_scene()
    s = s.replace(probes=pano.resize_area(s.image, 16, 32).expand(4, 8, 3, 16, 32).clone())
    scale = 0.01  # no clipping: the 'LDR' is exactly the HDR in other units
    ldr = s.replace(image=s.image * scale, probes=s.probes * scale)
    oracle = {"oracle": lambda scene, pts, size: pano.resize_area(scene.image, *size)[None]}
    res, images = RL.evaluate_lighting(s.image, ldr.image, scale, {"hdr": s, "ldr": ldr}, oracle)
    for inp in ("hdr", "ldr"):
        assert set(res[inp]) == {"oracle", "naive"}
        for mat in RL.MATERIALS[:2]:
            assert res[inp]["oracle"][f"{mat}.ratio"] == pytest.approx(1.0, abs=0.02)
            assert res[inp]["naive"][f"{mat}.rel_l1"] < 0.02
        assert res[inp]["oracle"]["peak_deg"] < 1e-3
    assert images["truth/diffuse"].shape == (3, RL.SPHERE_PIXELS, RL.SPHERE_PIXELS)


def test_light_methods_are_pluggable_callables():
    assert {"probe_field", "projection"} <= set(RL.LIGHT_METHODS)
    s = box_scene()
    s = s.replace(probes=pano.resize_area(s.image, 16, 32).expand(4, 8, 3, 16, 32).clone())
    X = torch.tensor([RL.SPHERE_CENTRE])
    for name in ("probe_field", "projection"):
        p = RL.LIGHT_METHODS[name](s, X, (16, 32))
        assert p.shape == (1, 3, 16, 32) and bool(torch.isfinite(p).all()) and float(p.min()) >= 0


def test_light_at_camera_reads_the_panorama_without_parallax():
    """At the camera the light is the panorama itself (the truth of the protocol, exactly), while at
    the protocol's point the box's ceiling lamp is nearer: the two methods differ by parallax only."""
    s = box_scene()
    s = s.replace(probes=pano.resize_area(s.image, 16, 32).expand(4, 8, 3, 16, 32).clone())
    X = torch.tensor([RL.SPHERE_CENTRE])
    at_camera = RL.LIGHT_METHODS["light_at_camera"](s, X, (16, 32))[0]
    panorama = pano.resize_area(s.image, 16, 32)
    assert float((at_camera - panorama).abs().sum() / panorama.sum()) < 0.03
    at_point = RL.LIGHT_METHODS["light_at"](s, X, (16, 32))[0]
    assert float((at_point - panorama).abs().sum() / panorama.sum()) > 0.1
    methods = {m: RL.LIGHT_METHODS[m] for m in ("light_at", "light_at_camera")}
    res, images = RL.evaluate_lighting(s.image, s.image, 1.0, {"hdr": s}, methods)
    assert res["hdr"]["light_at_camera"]["diffuse.rel_l1"] < 0.02
    assert res["hdr"]["light_at"]["diffuse.rel_l1"] > 0.05
    assert "light_at/diffuse" in images and not any(k.startswith("light_at_camera/") for k in images)


# ---------------------------------------------------------------------------------------------
# the command


def test_eval_real_command(tmp_path, capsys):
    from phyir.cli import main
    from phyir.io import save_panorama
    from phyir.learn.weights import default_weights_path

    if not default_weights_path().exists():
        pytest.skip("shipped weights missing")
    folder = tmp_path / "panos"
    folder.mkdir()
    save_panorama(box_scene().image, folder / "box.hdr")
    save_panorama(box_scene(rotated_box()).image.clamp(0, 1), folder / "box_ldr.png")
    out = tmp_path / "out"
    out.mkdir()
    rc = main(["eval", "--real", str(folder), "--json", str(out / "r.json"), "--markdown", str(out / "r.md"),
               "--sheet", str(out / "r.png")])
    assert rc == 0
    printed = capsys.readouterr()
    assert "Invariances" in printed.out and "box_ldr/ldr" in printed.out and "median/hdr" in printed.out
    assert "box.hdr:" in printed.err  # per-panorama seconds
    res = json.loads((out / "r.json").read_text())
    assert set(res["geometry"]) == {"box", "box_ldr", "median"}
    assert isinstance(res["geometry"]["box"]["flagged"], bool)
    assert 0 <= res["geometry"]["box"]["confidence"] <= 1
    assert "probe_field.diffuse.rel_l1" in res["lighting"]["box/hdr"]
    from PIL import Image

    assert Image.open(out / "r.png").size[0] > 4 * R.TILE[1]
    assert (out / "r.md").read_text().startswith("**Geometry")


def test_panorama_files_takes_files_and_folders(tmp_path):
    from phyir import io

    for name in ("b.hdr", "a.exr", ".a.exr.123-abcd.phyir.tmp"):
        (tmp_path / "d").mkdir(exist_ok=True)
        if name.endswith(".tmp"):
            (tmp_path / "d" / name).write_bytes(b"")
        else:
            io.save_panorama(torch.full((3, 8, 16), 0.5), tmp_path / "d" / name)
    single = tmp_path / "c.hdr"
    io.save_panorama(torch.full((3, 8, 16), 0.5), single)
    got = R.panorama_files([single, tmp_path / "d"])
    assert [p.name for p in got] == ["c.hdr", "a.exr", "b.hdr"]  # as given; a folder sorted, no temporaries
    assert R.panorama_files(tmp_path / "d") == got[1:]


def test_confidence_falls_with_the_rooms_size():
    """The same box room four times as large: plausibility and consistency unchanged, its size four
    times, its confidence divided by exactly the ratio of the size factors (a hall reads lower)."""
    s = box_scene()
    small, large = R.scene_confidence(s), R.scene_confidence(s.replace(depth=s.depth * 4))
    assert large["far_m"] == pytest.approx(4 * small["far_m"], rel=1e-5)
    assert large["consistency_deg"] == pytest.approx(small["consistency_deg"], abs=1e-6)
    factor = (1 + (small["far_m"] / R.FAR_SCALE_M) ** 2) / (1 + (large["far_m"] / R.FAR_SCALE_M) ** 2)
    assert large["confidence"] == pytest.approx(small["confidence"] * factor, rel=1e-6)
    assert 3 < small["far_m"] < 5 and small["confidence"] > 0.85 and large["confidence"] < 0.4
    assert large["flagged"] and R.flag_reason(large) == "a 17 m space, its depth may be well off"
    collapsed = s.normal.clone()
    collapsed[:] = torch.tensor([0.0, 1.0, 0.0])[:, None, None]
    assert R.flag_reason(R.scene_confidence(s.replace(normal=collapsed))) == "implausible geometry"


def test_confidence_falls_as_normals_and_depth_disagree():
    """The confidence ranks rooms, not only flags failures: normals tilted further from their depth's
    (a wall ripple of growing amplitude: each column's normals turned about the vertical) read a
    lower confidence at every step, by a clear margin between about 6° and 10° of disagreement (the
    range good predictions fall in), while the floor stays up."""
    s = box_scene()
    lon = pano.pixel_lonlat(*s.size, dtype=torch.float64)[0]
    scores = []
    for amplitude in (0.0, 10.0, 20.0, 30.0, 45.0):
        a = torch.deg2rad(torch.tensor(amplitude, dtype=torch.float64)) * torch.sin(12 * lon)
        n = s.normal.double().clone()
        x, z = n[0].clone(), n[2].clone()
        n[0], n[2] = x * torch.cos(a) - z * torch.sin(a), x * torch.sin(a) + z * torch.cos(a)
        c = R.scene_confidence(s.replace(normal=n.float()))
        assert c["nadir_up"] == 1.0
        scores.append((c["consistency_deg"], c["confidence"]))
    assert all(b[1] < a[1] for a, b in zip(scores, scores[1:])), scores
    (c2, s2), (c4, s4) = scores[2], scores[4]
    assert 4 < c2 < 7 and 9 < c4 < 12 and s2 - s4 > 0.05, scores  # (a quartic at 45°: 0.002)
