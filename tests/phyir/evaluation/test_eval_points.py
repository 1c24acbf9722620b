"""Light at free points of synthetic rooms against probes path-traced there (phyir.evaluation.points)."""

import json

import numpy as np
import pytest
import torch

from phyir.errors import PhyIRError
from phyir.evaluation import points as P
from phyir.evaluation.real_lighting import SPHERE_CENTRE
from phyir.synth import geometry as G
from phyir.synth.dataset import generate_scene, make_tiny_dataset, tiny_settings, trace_probes_at
from phyir.synth.rooms import generate_room
from phyir.synth.tracer import probe_points

pytestmark = pytest.mark.usefixtures("one_thread")

ST = tiny_settings(size=(64, 128), probe_grid=(4, 8), probe_size=(8, 16), spp=4)


@pytest.fixture(scope="module")
def room():
    return generate_scene(0, 3, ST)


def test_traced_probes_at_the_grid_points_match_the_stored_grid(room):
    """The probes traced again at the file's own probe points agree with its probe grid (the same room,
    the same units): in total within 3 %, texel by texel 15 % (one path per texel and a new light map)."""
    sc = generate_room(np.random.default_rng([0, 3])).build()
    pts = probe_points(sc, ST)
    traced = trace_probes_at(room, pts, (8, 16), settings=ST, seed=5)
    stored = room.probes.reshape(-1, 3, 8, 16)
    assert traced.shape == stored.shape
    assert float(traced.sum() / stored.sum()) == pytest.approx(1.0, abs=0.03)
    assert float((traced - stored).abs().sum() / stored.sum()) < 0.15


def test_a_room_from_another_generator_is_refused(room):
    moved = room.replace(depth=room.depth * 1.5)
    with pytest.raises(PhyIRError, match="another version of the generator"):
        trace_probes_at(moved, torch.zeros(1, 3), (8, 16), settings=ST)
    with pytest.raises(PhyIRError, match="no synthetic room"):
        trace_probes_at(room.replace(meta={}), torch.zeros(1, 3), (8, 16), settings=ST)


def test_free_points_lie_in_the_free_space_the_camera_sees(room):
    # room (0, 3) has furniture 0.9 m away in the protocol point's direction: that point is left out
    assert not any(torch.equal(p, torch.tensor(SPHERE_CENTRE)) for p in P.free_points(room, 12, seed=1))
    room = generate_scene(0, 1, ST)  # a wall 4.8 m away there
    pts = P.free_points(room, 12, seed=1)
    assert pts.shape == (12, 3)
    assert torch.equal(pts[0], torch.tensor(SPHERE_CENTRE))
    sc = generate_room(np.random.default_rng([0, 1])).build()
    r = pts.norm(dim=1)
    t, _ = G.intersect(sc.prims, torch.zeros_like(pts), pts / r[:, None])
    assert bool((t >= r + P.MARGIN - 0.02).all())  # the surface behind each is at least MARGIN further
    torch.testing.assert_close(P.free_points(room, 12, seed=1), pts)  # seeded
    assert not torch.equal(P.free_points(room, 12, seed=2)[1:], pts[1:])


def test_sphere_errors_of_the_truth_and_of_twice_the_truth(room):
    pts = P.free_points(room, 3, seed=0)
    truth = trace_probes_at(room, pts, (8, 16), settings=ST)
    same = P.sphere_errors(truth, truth, pts)
    assert same["diffuse.rel_l1"] == pytest.approx(0, abs=1e-9)
    assert same["matte_silver.ratio"] == pytest.approx(1, abs=1e-9)
    double = P.sphere_errors(2 * truth, truth, pts)
    assert double["diffuse.rel_l1"] == pytest.approx(1, rel=1e-6)
    assert double["diffuse.ratio"] == pytest.approx(2, rel=1e-6)
    assert double["diffuse.si_rel_l1"] == pytest.approx(0, abs=1e-6)  # the right shape, twice too bright


def test_eval_points_command(tmp_path, capsys):
    """``phyir eval --data D --points N``: rows for every method at free points and at the protocol's
    point, in the JSON and the Markdown; the light at the point beats the camera's panorama there."""
    from phyir.cli import main

    make_tiny_dataset(tmp_path / "d", count=3, size=(64, 128), probe_grid=(4, 8))
    js = tmp_path / "r.json"
    assert main(["eval", "--data", str(tmp_path / "d"), "--split", "train", "--limit", "1", "--points", "3",
                 "--relight", "2", "--spp", "4", "--probes-per-scene", "4", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    r = json.loads(js.read_text())
    for m in P.POINT_METHODS:
        assert f"| points/{m} |" in out
        assert np.isfinite(r[f"points/{m}"]["diffuse.rel_l1"]) and "relight_mirror_silver" in r[f"points/{m}"]
    assert "Spheres lit by the light at free points" in out
    one = [k for k in r if k.startswith("protocol/")]  # the protocol point is free in one scene or not
    assert [k.replace("protocol/", "protocol_median/") for k in one] == [k for k in r if "median" in k]


def test_the_fused_and_lnet_rows_read_their_own_grids(room):
    """``fused`` is the grid ``phyir predict`` writes by default, ``lnet`` LNet's alone: one geometry,
    two grids, each method interpolates its own (the grid users get is ``light_at``'s fallback)."""
    from phyir.evaluation.real_lighting import probe_field_light
    from phyir.lighting.fusion import fuse_probes
    from phyir.lighting.projection import projected_probe_grid

    preds = P.predict_both(room)
    assert torch.equal(preds.default.depth, preds.lnet.depth)
    projected = projected_probe_grid(preds.lnet, preds.lnet.probes)
    torch.testing.assert_close(preds.default.probes, fuse_probes(preds.lnet.probes, projected),
                               rtol=1e-4, atol=1e-6)
    pts = P.free_points(room, 2, seed=1)
    for name, scene in (("fused", preds.default), ("lnet", preds.lnet)):
        got = P.POINT_METHODS[name](preds, room, pts, (8, 16))
        torch.testing.assert_close(got, probe_field_light(scene, pts, (8, 16)))
    assert not torch.allclose(P.POINT_METHODS["fused"](preds, room, pts, (8, 16)),
                              P.POINT_METHODS["lnet"](preds, room, pts, (8, 16)))


def test_the_readme_table():
    """points_table (benchmarks/points_table.py prints it): a row per method and place found in the JSON,
    in the README's order."""
    keys = ("diffuse.rel_l1", "diffuse.ratio", "diffuse.colour_deg", "matte_silver.rel_l1", "probe_log_mse",
            "relight_diffuse", "relight_matte_silver", "relight_mirror_silver")
    res = {f"{w}/{m}": {k: 0.1 * (i + 1) for k in keys} for i, m in enumerate(("lnet", "light_at"))
           for w in ("points", "protocol_median")}
    lines = P.points_table(res)
    assert len(lines) == 2 + 4
    assert lines[2].startswith("| `light_at` (ours) | protocol point | 0.200 | 0.20 | 0.2° |")
    assert lines[3].startswith("| LNet alone (probe grid) | protocol point | 0.100 |")
    assert lines[4].startswith("| `light_at` (ours) | free points |")
