"""phyir.evaluation.metrics against values computed by hand (the arithmetic is written out beside
each number)."""

from __future__ import annotations

import math

import pytest
import torch

from phyir import pano
from phyir.evaluation import metrics as M


def approx(x, rel=1e-6, abs=1e-9):
    return pytest.approx(x, rel=rel, abs=abs)


def test_depth_metrics_by_hand():
    # valid pixels: p = (2, 1, 3), g = (2, 2, 2); the fourth has no ground truth (g = 0)
    pred = torch.tensor([2.0, 1.0, 3.0, 5.0]).view(1, 1, 4)
    gt = torch.tensor([2.0, 2.0, 2.0, 0.0]).view(1, 1, 4)
    m = M.depth_metrics(pred, gt)
    assert m["count"] == 1
    assert m["mae"] == approx(2 / 3)  # (0 + 1 + 1) / 3
    assert m["abs_rel"] == approx(1 / 3)  # (0 + 1/2 + 1/2) / 3
    assert m["sq_rel"] == approx(1 / 3)  # (0 + 1/2 + 1/2) / 3
    assert m["rmse"] == approx(math.sqrt(2 / 3))  # 0.816497
    # sqrt((0 + ln(1/2)^2 + ln(3/2)^2) / 3) = sqrt((0.480453 + 0.164402) / 3) = 0.463629
    assert m["rmse_log"] == approx(0.463629, rel=1e-5)
    # (0 + log10 2 + log10 1.5) / 3 = (0.301030 + 0.176091) / 3
    assert m["log10"] == approx(0.159040, rel=1e-5)
    # ratios max(p/g, g/p) = 1, 2, 1.5 against 1.25, 1.5625, 1.953125
    assert (m["delta1"], m["delta2"], m["delta3"]) == (approx(1 / 3), approx(2 / 3), approx(2 / 3))


def test_depth_metrics_average_over_images_and_mask():
    gt = torch.full((2, 1, 2, 2), 2.0)
    pred = gt.clone()
    pred[0] = 3.0  # image 0: every pixel off by 1 -> MAE 1; image 1 perfect -> MAE 0
    assert M.depth_metrics(pred, gt)["mae"] == approx(0.5)
    mask = torch.zeros(2, 1, 2, 2)
    mask[1] = 1  # only image 1 has valid pixels: image 0 doesn't count
    m = M.depth_metrics(pred, gt, mask)
    assert m["mae"] == 0 and m["count"] == 1


def test_area_weighting_counts_solid_angle():
    # 4 x 1 panorama: row bands sin90-sin45 = 0.292893 and sin45-sin0 = 0.707107 (x 2π, symmetric)
    bands = pano.solid_angles(4, 1)[:, 0] / (2 * math.pi)
    assert bands.tolist() == pytest.approx([0.292893, 0.707107, 0.707107, 0.292893], rel=1e-5)
    gt = torch.full((1, 4, 1), 2.0)
    pred = torch.tensor([3.0, 2.0, 2.0, 3.0]).view(1, 4, 1)  # the two polar rows are off by 1
    assert M.depth_metrics(pred, gt)["mae"] == approx(0.5)
    # (0.292893 + 0.292893) / (2 * (0.292893 + 0.707107)) = 0.292893
    assert M.depth_metrics(pred, gt, area_weighted=True)["mae"] == approx(0.292893, rel=1e-5)


def test_normal_metrics_by_hand():
    gt = torch.tensor([[0.0, 0, 1]] * 6).T.reshape(3, 1, 6).clone()
    gt[:, 0, 5] = 0  # no ground truth at the last pixel
    deg = torch.tensor([0.0, 45.0, 90.0, 10.0, 20.0, 70.0])
    r = torch.deg2rad(deg)
    pred = torch.stack((torch.zeros(6), torch.sin(r), torch.cos(r))).reshape(3, 1, 6) * 3.0  # not unit
    m = M.normal_metrics(pred, gt)
    assert m["mean"] == approx(33.0, rel=1e-5)  # (0 + 45 + 90 + 10 + 20) / 5
    assert m["median"] == approx(20.0, rel=1e-5)
    assert m["pct_11.25"] == approx(40.0)  # 0, 10
    assert m["pct_22.5"] == approx(60.0)  # 0, 10, 20
    assert m["pct_30"] == approx(60.0)


def test_angular_error_is_accurate_near_zero():
    a = torch.tensor([1.0, 0.0, 0.0])[:, None]
    b = torch.tensor([math.cos(1e-4), math.sin(1e-4), 0.0])[:, None]
    assert float(M.angular_error_deg(a, b, dim=0)) == approx(math.degrees(1e-4), rel=1e-3)


def test_material_metrics_by_hand():
    gt = torch.tensor([[0.5, 0.5], [0.2, 0.4], [0.1, 0.1]]).view(3, 1, 2)
    pred = torch.tensor([[0.25, 0.25], [0.2, 0.2], [0.3, 0.1]]).view(3, 1, 2)
    rough_gt, rough = torch.tensor([0.5, 1.0]).view(1, 1, 2), torch.tensor([0.7, 0.7]).view(1, 1, 2)
    m = M.material_metrics(pred, gt, rough, rough_gt, rough, rough)
    # squared errors .0625 .0625 | 0 .04 | .04 0  -> .205 / 6
    assert m["albedo_mse"] == approx(0.205 / 6)
    # per-channel scales: s0 = .25/.125 = 2 (exact), s1 = .12/.08 = 1.5 -> (.3,.3) vs (.2,.4): .01+.01,
    # s2 = .04/.10 = 0.4 -> (.12,.04) vs (.1,.1): .0004+.0036  => (.02 + .004) / 6
    assert m["albedo_si_mse"] == approx(0.024 / 6, rel=1e-5)
    assert m["roughness_mse"] == approx((0.04 + 0.09) / 2)  # (.2² + .3²) / 2
    assert m["metallic_mse"] == 0
    assert math.isnan(m["metallic_auc"])  # ground truth (0.7, 0.7): no metal pixel
    metal_gt = torch.tensor([0.0, 1.0, 1.0, 0.0]).view(1, 1, 4)
    metal = torch.tensor([0.1, 0.9, 0.05, 0.2]).view(1, 1, 4)  # pairs right: (.9>.1, .9>.2): 2 of 4
    m = M.material_metrics(None, None, pred_metallic=metal, gt_metallic=metal_gt)
    assert m["metallic_auc"] == approx(0.5)
    mask = torch.tensor([1.0, 1.0, 0.0, 1.0]).view(1, 1, 4)  # without the .05 metal pixel: all right
    m = M.material_metrics(None, None, pred_metallic=metal, gt_metallic=metal_gt, mask=mask)
    assert m["metallic_auc"] == 1.0


def test_probe_log_mse_by_hand():
    # 2 x 4 probes: both rows have the same solid angle, so texels weigh equally
    gt = torch.zeros(2, 3, 2, 4)
    pred = torch.zeros(2, 3, 2, 4)
    pred[0, :, 0] = math.e**2 - 1  # log(1 + x) = 2 on the top row of probe 0: error 4 on half its texels
    assert M.probe_log_mse(pred, gt) == approx(1.0)  # probes 0 and 1: (2 + 0) / 2
    assert M.probe_log_mse(pred, gt, torch.tensor([True, False])) == approx(2.0)
    # a grid [Hp, Wp, 3, h, w] is just more leading dims
    assert M.probe_log_mse(pred.view(1, 2, 3, 2, 4), gt.view(1, 2, 3, 2, 4)) == approx(1.0)


def test_sphere_gbuffer_faces_the_camera():
    d = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, -1.0], [0.0, 1.0, 0.0]]), dim=-1)
    n, v, mask = M.sphere_gbuffer(d, 32)
    assert n.shape == (2, 3, 32, 32) and mask.shape == (2, 1, 32, 32)
    assert float(mask.float().mean()) == pytest.approx(math.pi / 4, abs=0.01)  # disk / square
    nn = n.norm(dim=1, keepdim=True)
    assert torch.allclose(nn[mask], torch.ones(()), atol=1e-5) and bool((nn[~mask] == 0).all())
    assert bool(((n * v).sum(1, keepdim=True)[mask] > 0).all())  # visible hemisphere only
    centre = n[:, :, 15:17, 15:17].mean((2, 3))
    torch.testing.assert_close(torch.nn.functional.normalize(centre, dim=-1), -d, atol=2e-3, rtol=0)
    # image up is world up (for the sphere not seen from straight above)
    assert float(n[0, 1, 0:4, 14:18].mean()) > 0.5 > float(n[0, 1, -4:, 14:18].mean())


def test_relighting_error():
    gen = torch.Generator().manual_seed(0)
    env = torch.rand(3, 3, 16, 32, generator=gen) + 0.1
    pos = torch.tensor([[1.0, -1.0, -2.0], [-2.0, 0.5, 0.3], [0.2, 1.2, 2.0]])
    zero = M.relight_errors(env, env, pos, size=8, spp=16)
    assert set(zero) == {"relight_diffuse", "relight_matte_silver", "relight_mirror_silver"}
    assert all(v == 0 for v in zero.values())
    e = M.relight_errors(2 * env, env, pos, size=8, spp=16)
    # rendering is linear in the lighting: the error equals (log(1+2x) - log(1+x))² over the GT spheres
    for name in M.RELIGHT_MATERIALS:
        img = M.render_spheres(env, torch.nn.functional.normalize(pos, dim=-1), name, size=8, spp=16)
        _, _, mask = M.sphere_gbuffer(pos, 8)
        m = mask.expand_as(img)
        d2 = (torch.log1p(2 * img.double()) - torch.log1p(img.double()))[m] ** 2
        assert e[f"relight_{name}"] == approx(float(d2.mean()), rel=1e-4)
        assert e[f"relight_{name}"] > 0.01


def test_mirror_sphere_reflects_what_is_behind_the_camera():
    # env: dim everywhere, bright toward +z; a sphere seen along -z reflects +z at its centre
    h, w = 16, 32
    d = pano.directions(h, w)
    env = (1 + 99 * (d[2] > 0.9).float()).expand(3, h, w)[None]
    img = M.render_spheres(env, torch.tensor([[0.0, 0.0, -1.0]]), "mirror_silver", size=16, spp=16)
    assert float(img[0, :, 7:9, 7:9].mean()) > 50 > float(img[0, :, 1:3, 7:9].mean())


def test_meter_and_markdown():
    meter = M.MetricMeter()
    meter.add({"a": 1.0, "b": float("nan"), "count": 3})
    meter.add({"a": 3.0, "b": 2.0})
    assert meter.result() == {"a": 2.0, "b": 2.0}
    table = M.markdown_table({"model": {"a": 0.123456, "b": float("nan")}}, digits=3)
    assert table.splitlines() == ["| method | a | b |", "| --- | ---: | ---: |", "| model | 0.123 | – |"]


def test_paired_margin_counts_scenes_and_brackets_the_margin():
    model, base = M.MetricMeter(), M.MetricMeter()
    for a, b, auc in ((1.0, 2.0, 0.9), (2.0, 2.0, 0.4), (3.0, 4.0, 0.8)):
        model.add({"metallic_mse": a, "metallic_auc": auc})
        base.add({"metallic_mse": b, "metallic_auc": 0.5})
    r = M.paired_margin(model, base, "metallic_mse")
    # a tie is not better
    assert r["margin"] == pytest.approx(6 / 8 - 1) and r["better"] == 2 and r["scenes"] == 3
    assert r["ci_low"] <= r["margin"] <= r["ci_high"]
    assert M.paired_margin(model, base, "metallic_auc")["better"] == 2  # larger AUC is better
    assert M.paired_margin(model, base, "depth.mae") is None


def test_paired_margin_interval_separates_a_consistent_small_gain_from_noise():
    g = torch.Generator().manual_seed(5)
    err = 1 + torch.rand(40, generator=g)
    steady, noisy, base = M.MetricMeter(), M.MetricMeter(), M.MetricMeter()
    for e, n in zip(err.tolist(), torch.randn(40, generator=g).tolist(), strict=True):
        base.add({"x": e})
        steady.add({"x": 0.99 * e})  # 1 % better on every scene
        noisy.add({"x": e * (1 + 0.2 * n)})  # no gain, scene-to-scene noise
    r = M.paired_margin(steady, base, "x")
    assert r["better"] == 40 and r["ci_high"] < 0 and r["margin"] == pytest.approx(-0.01)
    q = M.paired_margin(noisy, base, "x")
    assert q["ci_low"] < 0 < q["ci_high"]


def test_eval_markdown_lists_margins_apart_from_the_methods():
    from phyir.commands.eval import markdown

    margin = {"margin": -0.0025, "ci_low": -0.005, "ci_high": -0.0002, "better": 28.0, "scenes": 37.0}
    results = {"model/lnet": {"metallic_mse": 0.007}, "dataset_means": {"metallic_mse": 0.00705},
               "margin/model/lnet-vs-dataset_means": {f"metallic_mse.{k}": v for k, v in margin.items()}}
    md = markdown(results)
    assert "| metallic_mse | -0.25 % | -0.50 % … -0.02 % | 28 of 37 |" in md
    assert "| margin/" not in md


def test_binary_auc_matches_counting_pairs():
    """Against the definition: the share of (positive, negative) pairs ordered right, ties half."""
    g = torch.Generator().manual_seed(3)
    scores = torch.randint(0, 6, (200,), generator=g).float()  # many ties
    labels = torch.rand(200, generator=g) < 0.2
    pos, neg = scores[labels], scores[~labels]
    pairs = (pos[:, None] > neg[None]).double() + 0.5 * (pos[:, None] == neg[None]).double()
    assert M.binary_auc(scores, labels) == pytest.approx(float(pairs.mean()), abs=1e-12)
    assert M.binary_auc(labels.float(), labels) == 1.0
    assert M.binary_auc(-labels.float(), labels) == 0.0
    assert math.isnan(M.binary_auc(scores, torch.zeros(200, dtype=torch.bool)))
