"""phyir.predict / phyir.inference and the `phyir predict` / `phyir eval` commands, with a small
randomly initialised model (the behaviour tested doesn't depend on training)."""

from __future__ import annotations

import json
import math

import pytest
import torch
from support.tiny_scenes import tiny_scene, write_dataset

import phyir
from phyir import inference as I
from phyir.cli import main as cli
from phyir.estimators import lighting_methods
from phyir.filters import guided_upsample
from phyir.geometry import plausible
from phyir.io import load_scene, save_panorama, save_scene
from phyir.learn.weights import save_weights
from phyir.nets import ModelConfig, PhyIRModel

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    cfg = ModelConfig.named("lite", probe_size=(8, 16))
    return PhyIRModel(cfg).eval()


@pytest.fixture(scope="module")
def weights(tmp_path_factory, model):
    path = tmp_path_factory.mktemp("w") / "tiny.safetensors"
    save_weights(model, path, {"data": {"resolution": "64x128"}})
    return path


@pytest.fixture(scope="module")
def image():
    return tiny_scene(7, H=128, W=256).image


class Counter:
    """Counts calls of a module's forward (instrumentation for "not recomputed")."""

    def __init__(self, monkeypatch, module):
        self.n = 0
        orig = module.forward

        def fwd(*a, **k):
            self.n += 1
            return orig(*a, **k)

        monkeypatch.setattr(module, "forward", fwd)


def test_complete_scene_at_the_input_size(model, image):
    sc = phyir.predict(image, model=model)
    sc.validate()
    assert sc.size == (128, 256)
    for name in I.GM_LAYERS:
        t = getattr(sc, name)
        assert t is not None and t.shape[-2:] == (128, 256) and bool(torch.isfinite(t).all())
    assert sc.probes.shape == (8, 16, 3, 8, 16)  # LNet grid: (H/16)x(W/16) of the 128x256 network
    assert sc.meta["predict.computed"].split() == [*I.GM_LAYERS, "probes"]
    assert sc.meta["predict.net_size"] == "128x256"
    assert set(json.loads(sc.meta["predict.seconds"])) >= {"gmnet", "gsnet", "lnet", "upsample", "probes"}


def test_net_size_and_guided_upsampling(model, image):
    sc = phyir.predict(image, model=model, net_size=(64, 128), lighting="lnet")
    assert sc.size == (128, 256) and sc.meta["predict.net_size"] == "64x128"
    assert sc.probes.shape == (4, 8, 3, 8, 16)
    sc.validate()


def test_exposure_scales_probes_only(model, image):
    k = 8.0
    for lighting in lighting_methods().names():
        a = phyir.predict(image, model=model, lighting=lighting, net_size=(64, 128))
        b = phyir.predict(image * k, model=model, lighting=lighting, net_size=(64, 128))
        for name in I.GM_LAYERS:
            torch.testing.assert_close(getattr(b, name), getattr(a, name), rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(b.probes, k * a.probes, rtol=1e-3, atol=1e-6)


def test_the_default_grid_fuses_lnet_and_projection(model, image):
    from phyir.lighting.fusion import fuse_probes

    assert I.DEFAULT_LIGHTING == "fused"
    grids = {m: phyir.predict(image, model=model, lighting=m, net_size=(64, 128)).probes
             for m in ("lnet", "projection", None)}
    assert not torch.allclose(grids["lnet"], grids["projection"])
    torch.testing.assert_close(grids[None], fuse_probes(grids["lnet"], grids["projection"]))
    pts = torch.tensor([[0.0, -0.2, -0.8], [0.5, 0.3, 1.0]])
    at = {m: phyir.predict(image, model=model, lighting=m, net_size=(64, 128), probes="points",
                           points=pts).probes for m in ("lnet", "projection", "fused")}
    torch.testing.assert_close(at["fused"], fuse_probes(at["lnet"], at["projection"]))


def test_supplied_layers_are_not_recomputed(model, image, monkeypatch):
    # one GMNet pass per prediction: the random model's normals would trigger the mirrored pass
    # (tests/phyir/geometry/test_plausible.py), which is not what this test counts
    monkeypatch.setattr(plausible, "MAX_AWAY_SHARE", 1.0)
    gm, gs, ln = (Counter(monkeypatch, m) for m in (model.gmnet, model.gsnet, model.lnet))
    full = phyir.predict(image, model=model, net_size=(64, 128), lighting="lnet")
    assert (gm.n, gs.n, ln.n) == (1, 1, 1)
    # every layer given, probes missing: LNet runs on the given layers, GMNet/GSNet don't
    given = full.replace(probes=None)
    out = phyir.predict(given, model=model, net_size=(64, 128), lighting="lnet")
    assert (gm.n, gs.n, ln.n) == (1, 1, 2)
    for name in I.GM_LAYERS:
        assert getattr(out, name) is getattr(given, name)
    assert out.meta["predict.computed"] == "probes"
    assert out.meta["predict.reused"].split() == list(I.GM_LAYERS)
    # a complete scene: nothing runs, not even the model loading (the weights file doesn't exist)
    done = phyir.predict(full, weights="/nonexistent/w.safetensors")
    assert (gm.n, gs.n, ln.n) == (1, 1, 2) and done.meta["predict.computed"] == ""
    assert done.probes is full.probes
    # geometry only: GSNet and LNet are skipped, materials and probes are absent
    geo = phyir.predict(image, model=model, net_size=(64, 128), outputs=["depth", "normal"])
    assert (gm.n, gs.n, ln.n) == (2, 1, 2)
    assert geo.albedo is None and geo.probes is None and geo.depth is not None
    # a given depth is kept when the rest is predicted
    part = phyir.predict(PanoScene_with(image, depth=full.depth * 2), model=model, net_size=(64, 128),
                         lighting="lnet")
    assert torch.equal(part.depth, full.depth * 2) and "depth" not in part.meta["predict.computed"]


def PanoScene_with(image, **layers):
    from phyir.scene import PanoScene

    return PanoScene(image=image, **layers)


def test_probes_at_points(model, image):
    pts = torch.tensor([[1.0, -1.2, -2.0], [-2.0, 0.5, 0.4], [0.3, 1.1, 2.5]])
    grid = phyir.predict(image, model=model, net_size=(64, 128), lighting="lnet")
    sc = phyir.predict(image, model=model, net_size=(64, 128), lighting="lnet", probes="points", points=pts)
    assert sc.probes.shape == (3, 1, 3, 8, 16) and sc.meta["probe_layout"] == "points"
    torch.testing.assert_close(sc.probes[:, 0], I.lnet_probes_at(grid.probes, pts))
    proj = phyir.predict(image, model=model, net_size=(64, 128), probes="points", points=pts)
    assert proj.probes.shape == (3, 1, 3, 8, 16) and bool(torch.isfinite(proj.probes).all())


def test_lnet_probes_at_a_probe_centre_is_that_probe():
    grid = torch.rand(4, 8, 3, 2, 4, generator=torch.Generator().manual_seed(1))
    from phyir import pano

    d = pano.directions(4, 8).permute(1, 2, 0)  # centres of the grid's blocks
    out = I.lnet_probes_at(grid, d[2, 5][None] * 3.0)
    torch.testing.assert_close(out[0], grid[2, 5])


def test_guided_upsample_follows_the_guide():
    # src is an exact linear function of the guide: recovered exactly at the fine resolution
    g_hi = torch.rand(1, 64, 128, generator=torch.Generator().manual_seed(2))
    from phyir.pano import resize_area

    g_lo = resize_area(g_hi, 16, 32)
    out = guided_upsample(3 * g_lo + 1, g_lo, g_hi, I.GUIDE_RADIUS, eps=1e-8)
    torch.testing.assert_close(out, 3 * g_hi + 1, rtol=1e-3, atol=1e-3)
    # step edges: bilinear upsampling of the low-res src blurs them, the guided result follows the
    # guide (up to ~8 % overshoot next to edges that fall on low-res block borders)
    step = torch.zeros(1, 64, 128)
    step[..., 40:91] = 1
    lo = resize_area(step, 16, 32)
    up = guided_upsample(lo, lo, step, I.GUIDE_RADIUS, eps=1e-6)
    plain = resize_area(lo, 64, 128)
    assert float((up - step).abs().max()) < 0.08 < 0.2 < float((plain - step).abs().max())
    assert float((up - step).abs().mean()) < 0.1 * float((plain - step).abs().mean())


def test_cancel_and_bad_arguments(model, image):
    with pytest.raises(I.Cancelled):
        phyir.predict(image, model=model, cancel=lambda: True)
    with pytest.raises(phyir.PhyIRError, match="unknown outputs"):
        phyir.predict(image, model=model, outputs=["depht"])
    with pytest.raises(phyir.InputError, match="equirectangular"):
        phyir.predict(torch.rand(3, 64, 100), model=model)
    stages = []
    phyir.predict(image, model=model, net_size=(64, 128), lighting="lnet",
                  progress=lambda s, f: stages.append(s))
    assert stages[0] == "load" and stages[-1] == "done"


def test_cli_predict_files_and_folders(tmp_path, weights, image, capsys):
    a, b = tmp_path / "in" / "a.hdr", tmp_path / "in" / "b.png"
    a.parent.mkdir()
    save_panorama(image, a)
    save_panorama(image.clamp(0, 1), b)
    out = tmp_path / "one.exr"
    assert cli(["predict", str(a), "-o", str(out), "--weights", str(weights), "-q"]) == 0
    sc = load_scene(out)
    assert sc.size == (128, 256) and sc.probes is not None and sc.meta["predict.net_size"] == "64x128"
    assert 0.01 < float(sc.depth.min()) and float(sc.depth.max()) < 150
    assert cli(["predict", str(a.parent), "-o", str(tmp_path / "out"), "--weights", str(weights),
                "--outputs", "depth,normal", "--lighting", "lnet"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.exr", "b.exr"]
    geo = load_scene(tmp_path / "out" / "b.exr")
    assert geo.albedo is None and geo.probes is None and geo.normal is not None
    assert cli(["predict", str(tmp_path / "missing.hdr"), "-o", str(out)]) == 2
    assert "missing.hdr" in capsys.readouterr().err
    assert cli(["predict", str(a), str(b), "-o", str(tmp_path / "x.exr"), "--weights", str(weights)]) == 2


def test_eval_pair_of_identical_scenes_is_perfect():
    from phyir.evaluation.synthetic import evaluate_pair

    gt = tiny_scene(3, H=32, W=64, grid=(4, 8), probe_size=(8, 16))
    m = evaluate_pair(gt, gt, relight=2, spp=8)
    for k in ("depth.mae", "depth.rmse", "normal.mean", "albedo_mse", "roughness_mse", "metallic_mse",
              "probe_log_mse", "relight_diffuse", "relight_mirror_silver"):
        assert m[k] == pytest.approx(0, abs=1e-4), k
    assert m["depth.delta1"] == 1 and m["normal.pct_11.25"] == 100


def test_cli_eval_on_predictions_and_on_a_dataset(tmp_path, weights, capsys):
    gt = tiny_scene(4, H=64, W=128, grid=(4, 8), probe_size=(8, 16))
    (tmp_path / "gt").mkdir()
    save_scene(gt, tmp_path / "gt" / "s.exr")
    assert cli(["predict", str(tmp_path / "gt" / "s.exr"), "-o", str(tmp_path / "pred" / "s.exr"),
                "--weights", str(weights), "-q"]) == 0
    # the input had every layer: nothing was predicted; strip the layers to predict them
    stripped = gt.replace(depth=None, normal=None, albedo=None, roughness=None, metallic=None, probes=None)
    save_scene(stripped, tmp_path / "in.exr")
    assert cli(["predict", str(tmp_path / "in.exr"), "-o", str(tmp_path / "pred" / "s.exr"),
                "--weights", str(weights), "-q", "--lighting", "lnet", "--net-size", "64x128"]) == 0
    capsys.readouterr()
    js = tmp_path / "r.json"
    assert cli(["eval", str(tmp_path / "pred"), "--gt", str(tmp_path / "gt"), "--json", str(js),
                "--relight", "2", "--spp", "8"]) == 0
    r = json.loads(js.read_text())["predictions"]
    assert r["depth.mae"] > 0 and 0 <= r["depth.delta1"] <= 1 and math.isfinite(r["probe_log_mse"])
    assert "| predictions |" in capsys.readouterr().out
    # the model on a dataset split
    write_dataset(tmp_path / "data", n_train=1, n_val=2, H=64, W=128, grid=(4, 8), probe_size=(8, 16))
    md = tmp_path / "r.md"
    assert cli(["eval", "--data", str(tmp_path / "data"), "--split", "val", "--weights", str(weights),
                "--probes-per-scene", "8", "--relight", "2", "--spp", "8", "--markdown", str(md)]) == 0
    text = md.read_text()
    for row in ("model/lnet", "model/projection", "projection_gt_geometry", "constant", "dataset_means"):
        assert f"| {row} |" in text
    assert "**Margins per scene: model/lnet vs dataset_means**" in text and "of 2 |" in text
    assert cli(["eval", "--gt", str(tmp_path / "gt")]) == 2


def test_dataset_means_baseline(tmp_path):
    from phyir.color import exposure_scale
    from phyir.evaluation.synthetic import dataset_means, means_baseline

    write_dataset(tmp_path, n_train=2, n_val=1, H=32, W=64, grid=(2, 4), probe_size=(4, 8))
    train = [load_scene(tmp_path / f"scene_{i:06d}.exr") for i in range(2)]
    means = dataset_means(tmp_path)
    # depth over every pixel, materials over non-emissive pixels, the probe over all probes
    want = float(torch.stack([s.depth for s in train]).mean())
    assert float(means["depth"]) == pytest.approx(want, rel=1e-4)
    keep = torch.stack([s.masks["emission"] < 0.5 for s in train]).expand(-1, 3, -1, -1)
    want = torch.stack([s.albedo for s in train]).transpose(0, 1)[keep.transpose(0, 1)].view(3, -1).mean(1)
    assert torch.allclose(means["albedo"], want, rtol=1e-4)
    norm = torch.cat([s.probes.reshape(-1, 3, 4, 8) * exposure_scale(s.image) for s in train])
    assert torch.allclose(means["probe"], norm.mean(0), rtol=1e-4)
    gt = load_scene(tmp_path / "scene_000002.exr")
    b = means_baseline(gt, means)
    b.validate()
    assert torch.allclose(b.probes[1, 2] * exposure_scale(gt.image), means["probe"], rtol=1e-4)
    assert float(b.roughness.max() - b.roughness.min()) == 0
    assert float(b.depth[0, 0, 0]) == pytest.approx(float(means["depth"]))


def test_a_jpegs_clipped_light_takes_the_jpeg_law(tmp_path, model, image):
    """predict records the input's format; an 8-bit PNG's clipped regions take the region law, a
    JPEG's the law fitted on JPEG copies (phyir/assets/clip_regions_jpeg.json)."""
    bright = image.clone()
    bright[:, 10:20, 40:60] = 4.0  # a lamp: clipped in the 8-bit files
    methods = {}
    for suffix in ("png", "jpg"):
        path = tmp_path / f"room.{suffix}"
        save_panorama(bright.clamp(0, 1), path)
        sc = phyir.predict(path, model=model, outputs=("depth",), probes=None)
        methods[sc.meta["source_format"]] = sc.meta["predict.hdr_recovery"].split(":")[0]
    assert methods == {"png": "regions", "jpeg": "regions-jpeg"}
