"""The training losses: analytic values, invariances, the SC weighting, the render loss and the
per-sample averaging that makes DDP batches equivalent to one big batch."""

from __future__ import annotations

import math

import pytest
import torch
from support.tiny_scenes import tiny_scenes

from phyir.learn.datasets import normalize_scene
from phyir.learn.losses import (
    STAGE_WEIGHTS,
    LossOptions,
    LossWeights,
    angular_loss,
    bce,
    depth_gradient_loss,
    depth_loss,
    l2,
    probe_loss,
    render_loss,
    sc_loss,
    total_loss,
)
from phyir.scene import PanoScene

pytestmark = pytest.mark.usefixtures("one_thread")


def test_stage_weights_are_the_supplements():
    gm = STAGE_WEIGHTS["gm"]
    assert (gm.albedo, gm.roughness, gm.metallic, gm.depth, gm.normal, gm.depth_grad) == (1, 1, 1, 1, .1, .1)
    light = STAGE_WEIGHTS["light"]
    assert (light.probe, light.sc, light.render) == (1, 1, 1) and light.albedo == 0
    joint = STAGE_WEIGHTS["joint"]
    assert (joint.probe, joint.render, joint.sc) == (1, 1, 0.1)
    gs = STAGE_WEIGHTS["gs"]
    assert (gs.albedo, gs.roughness, gs.normal, gs.depth) == (1, 1, 0.1, 0)


def test_angular_loss_analytic_and_finite_gradient():
    x = torch.tensor([1.0, 0, 0]).view(1, 3, 1, 1)
    y = torch.tensor([0.0, 1, 0]).view(1, 3, 1, 1)
    assert angular_loss(x, y).item() == pytest.approx(math.pi / 2, abs=1e-6)
    assert angular_loss(x, -x).item() == pytest.approx(math.pi, abs=1e-5)
    same = x.clone().requires_grad_()
    loss = angular_loss(same, x)
    loss.backward()
    assert loss.item() < 1e-5 and torch.isfinite(same.grad).all()


def test_depth_losses():
    g = torch.rand(2, 1, 8, 16, generator=torch.Generator().manual_seed(0)) + 1
    assert depth_loss(g + 0.5, g).tolist() == pytest.approx([0.25, 0.25])
    # Eigen's loss: (1 - λ) (log s)^2 for a global scale s (λ = 1: fully scale-invariant); L2 is not
    si = depth_loss(3 * g, g, mode="scale_invariant", si_lambda=0.85)
    assert si.tolist() == pytest.approx([0.15 * math.log(3) ** 2] * 2, rel=1e-4)
    assert depth_loss(3 * g, g, mode="scale_invariant", si_lambda=1.0).abs().max() < 1e-6
    assert depth_loss(3 * g, g).min() > 1
    # gradients of log depth: scale-free, zero for a scaled copy, and they wrap around the seam
    assert depth_gradient_loss(2 * g, g).abs().max() < 1e-6
    step = torch.ones(1, 1, 4, 8)
    jump = step.clone()
    jump[..., 4:] = math.e  # log-depth jumps by 1 at column 4 and back by 1 across the seam
    expected = 2 / 8  # two of the eight horizontal differences per row are 1
    assert depth_gradient_loss(jump, step).item() == pytest.approx(expected, abs=1e-6)


def test_probe_loss_is_l2_of_log1p():
    gt = torch.zeros(1, 2, 2, 3, 4, 8)
    assert probe_loss(gt + (math.e - 1), gt).item() == pytest.approx(1.0, abs=1e-6)


def test_sc_loss_pulls_neighbours_together_except_across_depth_jumps():
    # one row of three probes: log1p values 0, 1, 1
    probes = torch.zeros(1, 1, 3, 3, 2, 4)
    probes[:, :, 1:] = math.e - 1
    flat = torch.full((1, 1, 4, 12), 2.0)
    # equal depths: weights 1; differing pairs (0,1) and (2,0) across the seam -> 2 of 3 pairs
    assert sc_loss(probes, flat).item() == pytest.approx(2 / 3, abs=1e-6)
    # probe 0's block twice as far: both differing pairs straddle a jump of log 2
    jump = flat.clone()
    jump[..., :4] = 4.0
    w = math.exp(-math.log(2) / LossOptions().sc_sigma)
    assert sc_loss(probes, jump).item() == pytest.approx(2 * w / 3, rel=1e-5)
    assert sc_loss(probes[:, :, :1].expand_as(probes), flat).item() == 0  # identical probes


def _gt_batch(n: int = 2) -> PanoScene:
    return PanoScene.stack([normalize_scene(s) for s in tiny_scenes(n, H=32, W=64, grid=(2, 4),
                                                                     probe_size=(8, 16))])


def test_render_loss_is_zero_for_a_consistent_scene_and_ignores_emitters():
    from phyir.shading.render import render_scene

    gt = _gt_batch()
    size = gt.size  # re-render at the scene's resolution: no resampling in between
    # make the input image the rendering of the scene itself (emitters keep their radiance)
    img = render_scene(gt, spp=1, method="prefiltered")["image"]
    scene = gt.replace(image=img)
    non_em = 1 - gt.masks["emission"]
    assert render_loss(img, scene, non_em, size=size).abs().max() < 1e-4
    darker = scene.replace(albedo=0.5 * scene.albedo)
    assert render_loss(img, darker, non_em, size=size).min() > 1e-3
    # changing emitter pixels of the input does not change the loss
    brighter = torch.where(gt.masks["emission"] > 0, 10 * img, img)
    a = render_loss(img, darker, non_em, size=size)
    b = render_loss(brighter, darker, non_em, size=size)
    assert torch.allclose(a, b)
    # differentiable with respect to geometry, materials and light
    leaves = {k: getattr(darker, k).clone().requires_grad_() for k in ("normal", "albedo", "roughness",
                                                                         "metallic", "probes")}
    render_loss(img, darker.replace(**leaves), non_em, size=size).sum().backward()
    for k, t in leaves.items():
        assert t.grad is not None and t.grad.abs().sum() > 0, k


def test_losses_are_per_sample_means():
    """The loss of a batch equals the mean of its halves' losses: what makes DDP (which averages
    gradients over equal per-process batches) equivalent to one process with the whole batch."""
    gt = _gt_batch(4)
    torch.manual_seed(0)
    pred = {"depth": gt.depth * 1.3, "normal": torch.nn.functional.normalize(gt.normal + 0.3, dim=1),
            "albedo": gt.albedo.flip(-1), "roughness": gt.roughness * 0.5, "metallic": 1 - gt.metallic,
            "probes": gt.probes * 2}
    w = LossWeights(**{k: 1.0 for k in ("albedo", "roughness", "metallic", "depth", "normal", "depth_grad",
                                         "probe", "sc", "render")})
    opts = LossOptions(render_size=(16, 32))
    whole, _ = total_loss(pred, gt, w, opts)
    halves = [total_loss({k: v[s] for k, v in pred.items()}, gt.map(lambda t, s=s: t[s]), w, opts)[0]
              for s in (slice(0, 2), slice(2, 4))]
    assert whole.item() == pytest.approx((halves[0] + halves[1]).item() / 2, rel=1e-5)


def test_total_loss_needs_an_active_term():
    with pytest.raises(ValueError):
        total_loss({}, _gt_batch(1), LossWeights())


def test_metallic_bce_is_zero_at_the_target_and_keeps_a_saturated_head_learning():
    """The binary KL form: 0 where pred == gt (also fractional gt), log 2 for 0.5 vs 0/1; through a
    sigmoid saturated at logit -40 the gradient on the logit is ~ p - y (L2's is ~1e-17)."""
    gt = torch.tensor([0.0, 1.0, 0.3, 0.0]).reshape(1, 1, 2, 2)
    assert float(bce(gt.clone(), gt)) == pytest.approx(0.0, abs=1e-6)
    half = torch.full_like(gt[..., :1, :], 0.5)
    assert float(bce(half, gt[..., :1, :])) == pytest.approx(math.log(2), rel=1e-5)
    logit = torch.full((1, 1, 2, 2), -40.0, requires_grad=True)
    bce(torch.sigmoid(logit), gt).sum().backward()
    expected = (torch.sigmoid(torch.tensor(-40.0)) - gt) / gt.numel()
    assert torch.allclose(logit.grad, expected, atol=1e-6)
    logit.grad = None
    l2(torch.sigmoid(logit), gt).sum().backward()
    assert float(logit.grad.abs().max()) < 1e-15  # why the paper's L2 alone leaves a dead head
