"""Training losses of PhyIR (supplement B.1) with the supplement's weights as defaults.

Every term is computed **per sample** and then averaged over the batch, so a batch split across
DistributedDataParallel ranks gives the same loss and gradient as the whole batch in one process.
Formulas (see docs/training.md):

- B, R, M: L2 (mean squared error) of base colour, roughness, metalness; metalness by default
  through the binary cross-entropy (as a KL divergence, 0 at the target) instead
  (``metallic_loss="l2"`` is the paper's): see :func:`bce`.
- D: L2 of radial depth in metres (the paper's plain L2; ``depth_mode="scale_invariant"`` gives
  Eigen's scale-invariant log loss instead).
- N: mean angle (radians) between predicted and true normals.
- depth gradient: L1 between the horizontal (wrapping) and vertical finite differences of log depth.
- depth–normal: L1 between the predicted log depth's steps and the steps the predicted normals
  imply (:func:`phyir.geometry.depth_normal.log_depth_steps`), where the ground truth has one surface (not
  in the paper: it ties the two heads together, so their layers agree on rooms unlike the training set).
- L (probes): L2 of log(1 + x) between predicted and true probes.
- SC: neighbouring probes pulled together, weighted by exp(-|Δ log depth| / σ_sc) between their
  blocks, so probes across depth discontinuities are left free.
- render: L2 of log(1 + x) between the input image and its re-rendering through
  :func:`phyir.shading.render.render_scene` from the predicted layers and probes, on non-emissive pixels.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir.geometry.depth_normal import agreement, forward_differences, log_depth_steps
from phyir.pano import resize_area
from phyir.scene import PanoScene

GM_TERMS = ("albedo", "roughness", "metallic", "depth", "normal", "depth_grad", "depth_normal")
LIGHT_TERMS = ("probe", "sc", "render")


@dataclass(frozen=True)
class LossWeights:
    """β of each term; zero switches a term off (it is then not computed)."""

    albedo: float = 0.0
    roughness: float = 0.0
    metallic: float = 0.0
    depth: float = 0.0
    normal: float = 0.0
    depth_grad: float = 0.0
    depth_normal: float = 0.0
    probe: float = 0.0
    sc: float = 0.0
    render: float = 0.0

    def active(self) -> dict[str, float]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v}


# supplement B.1
STAGE_WEIGHTS: dict[str, LossWeights] = {
    "gm": LossWeights(albedo=1.0, roughness=1.0, metallic=1.0, depth=1.0, normal=0.1, depth_grad=0.1,
                      depth_normal=0.1),
    "light": LossWeights(probe=1.0, sc=1.0, render=1.0),
    # joint fine-tuning: the supplement lists β_L = β_render = 1, β_SC = 0.1; the GMNet supervision
    # terms are kept at their stage-1 weights so geometry and material stay anchored to the labels
    "joint": LossWeights(albedo=1.0, roughness=1.0, metallic=1.0, depth=1.0, normal=0.1, depth_grad=0.1,
                         depth_normal=0.1, probe=1.0, sc=0.1, render=1.0),
    "gs": LossWeights(albedo=1.0, roughness=1.0, normal=0.1),
}


@dataclass(frozen=True)
class LossOptions:
    depth_mode: str = "l2"  # "l2" (paper) or "scale_invariant"
    si_lambda: float = 0.85  # Eigen's λ for the scale-invariant depth loss
    sc_sigma: float = 0.1  # SC weight exp(-|Δ log depth| / sc_sigma)
    render_size: tuple[int, int] = (128, 256)  # re-rendering resolution (supplement B.1)
    render_spp: int = 16
    render_method: str = "prefiltered"
    emission_mask: str = "emission"
    # "l2" (paper) or "bce": L2 through the sigmoid dies when metal is rare (measured: the first
    # shipped lite model's metalness logits sat at -30..-64 on every pixel, gradient ~1e-13), while
    # the cross-entropy's gradient on the logit is p - y and stays alive; both are minimised by the
    # per-pixel probability of metal
    metallic_loss: str = "bce"


# ---------------------------------------------------------------------------------------------
# per-sample helpers: [B, ...] -> [B]


def _mean(x: Tensor, mask: Tensor | None = None) -> Tensor:
    """Per-sample mean of [B,C,H,W] over valid pixels (mask [B,1,H,W] in [0,1] or None)."""
    if mask is None:
        return x.flatten(1).mean(1)
    m = mask.to(x.dtype).expand_as(x)
    return (x * m).flatten(1).sum(1) / m.flatten(1).sum(1).clamp(min=1.0)


def l2(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    return _mean((pred - gt) ** 2, mask)


def bce(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    """Binary cross-entropy of probabilities ``pred`` against targets ``gt`` in [0, 1], less the
    targets' own entropy (so 0 at ``pred == gt`` also for fractional targets: the binary KL
    divergence).  Written out, not ``F.binary_cross_entropy``, which clamps log p at -100 and so
    zeroes the gradient of a saturated sigmoid: through the sigmoid the logit gets about p - y."""
    tiny = torch.finfo(pred.dtype).tiny
    logp = torch.log(pred.clamp(min=tiny))
    log1mp = torch.log((1 - pred).clamp(min=tiny))
    ent = torch.special.xlogy(gt, gt) + torch.special.xlogy(1 - gt, 1 - gt)
    return _mean(ent - (gt * logp + (1 - gt) * log1mp), mask)


def depth_loss(pred: Tensor, gt: Tensor, mask: Tensor | None = None, mode: str = "l2",
               si_lambda: float = 0.85) -> Tensor:
    if mode == "l2":
        return l2(pred, gt, mask)
    if mode == "scale_invariant":
        d = torch.log(pred.clamp(min=1e-3)) - torch.log(gt.clamp(min=1e-3))
        return _mean(d * d, mask) - si_lambda * _mean(d, mask) ** 2
    raise ValueError(f"unknown depth loss mode {mode!r}")


def angular_loss(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean angle (radians) between unit vectors along dim 1, via atan2 (finite gradients at 0 and π)."""
    cross = torch.linalg.cross(pred, gt, dim=1)
    sin = torch.sqrt((cross * cross).sum(1, keepdim=True) + 1e-12)
    cos = (pred * gt).sum(1, keepdim=True)
    return _mean(torch.atan2(sin, cos), mask)


def _grads(x: Tensor) -> tuple[Tensor, Tensor]:
    """Horizontal (wrapping) and vertical forward differences of [B,C,H,W]."""
    return torch.roll(x, -1, dims=-1) - x, x[..., 1:, :] - x[..., :-1, :]


def depth_gradient_loss(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Tensor:
    """L1 between finite differences of log depth (scale-free; edges where depth jumps)."""
    lp, lg = torch.log(pred.clamp(min=1e-3)), torch.log(gt.clamp(min=1e-3))
    (px, py), (gx, gy) = _grads(lp), _grads(lg)
    mx = my = None
    if mask is not None:
        mx = mask * torch.roll(mask, -1, dims=-1)
        my = mask[..., 1:, :] * mask[..., :-1, :]
    return _mean((px - gx).abs(), mx) + _mean((py - gy).abs(), my)


SURFACE_TAU = 0.01  # ground-truth steps further than this from their normals' cross an occlusion


def depth_normal_loss(depth: Tensor, normal: Tensor, gt_depth: Tensor, gt_normal: Tensor) -> Tensor:
    """L1 between the steps of predicted log depth and those the predicted normals imply, on the
    steps where the ground truth's depth follows its own normals (one surface, no occlusion)."""
    gt_log = torch.log(gt_depth.clamp(min=1e-3))
    wx, wy = agreement(gt_log, log_depth_steps(gt_normal), SURFACE_TAU)
    steps = log_depth_steps(normal)
    z = torch.log(depth.clamp(min=1e-3))
    zx, zy = forward_differences(z)
    num = ((zx - steps.gx).abs() * wx).flatten(1).sum(1) + ((zy - steps.gy).abs() * wy).flatten(1).sum(1)
    return num / (wx.flatten(1).sum(1) + wy.flatten(1).sum(1)).clamp(min=1.0)


def probe_loss(pred: Tensor, gt: Tensor) -> Tensor:
    """L2 of log(1 + x) between probe grids [B,Hp,Wp,3,h,w]."""
    return ((torch.log1p(pred) - torch.log1p(gt)) ** 2).flatten(1).mean(1)


def block_log_depth(depth: Tensor, grid: tuple[int, int]) -> Tensor:
    """Mean log depth of each probe block: [B,1,H,W] -> [B,Hp,Wp]."""
    return resize_area(torch.log(depth.clamp(min=1e-3)), *grid)[:, 0]


def sc_weights(block_logd: Tensor, sigma: float) -> tuple[Tensor, Tensor]:
    """Neighbour weights exp(-|Δ log depth| / σ): horizontal [B,Hp,Wp] (wraps), vertical [B,Hp-1,Wp]."""
    wx = torch.exp(-(torch.roll(block_logd, -1, dims=-1) - block_logd).abs() / sigma)
    wy = torch.exp(-(block_logd[:, 1:] - block_logd[:, :-1]).abs() / sigma)
    return wx, wy


def sc_loss(probes: Tensor, depth: Tensor, sigma: float = 0.1) -> Tensor:
    """Spatial-coherence loss of a probe grid [B,Hp,Wp,3,h,w] given depth [B,1,H,W]:

    L_SC = mean over neighbouring pairs (p, q) of  w_pq * mean_texels (log(1+P_p) - log(1+P_q))^2,
    w_pq = exp(-|log d_p - log d_q| / σ), with d the mean depth of a probe's block (``depth`` is
    treated as a constant: the loss shapes the light, not the geometry).
    """
    B, Hp, Wp = probes.shape[:3]
    wx, wy = sc_weights(block_log_depth(depth.detach(), (Hp, Wp)), sigma)
    lp = torch.log1p(probes).flatten(3)
    dx = ((torch.roll(lp, -1, dims=2) - lp) ** 2).mean(-1)  # [B,Hp,Wp]
    dy = ((lp[:, 1:] - lp[:, :-1]) ** 2).mean(-1)  # [B,Hp-1,Wp]
    num = (wx * dx).flatten(1).sum(1) + (wy * dy).flatten(1).sum(1)
    return num / (wx[0].numel() + wy[0].numel())


def render_loss(image: Tensor, scene: PanoScene, non_emissive: Tensor | None = None,
                size: tuple[int, int] = (128, 256), spp: int = 16, method: str = "prefiltered") -> Tensor:
    """L2 of log(1 + x) between ``image`` [B,3,H,W] and the re-rendering of ``scene``'s layers and
    probes at ``size`` through the rendering layer, over non-emissive pixels."""
    from phyir.shading.render import render_scene

    H, W = size
    def down(t):
        return resize_area(t, H, W)
    rs = PanoScene(image=down(image), depth=down(scene.depth),
                   normal=F.normalize(down(scene.normal), dim=1, eps=1e-6), albedo=down(scene.albedo),
                   roughness=down(scene.roughness), metallic=down(scene.metallic), probes=scene.probes)
    out = render_scene(rs, spp=spp, method=method)["image"]
    mask = None if non_emissive is None else (down(non_emissive) > 0.999).float()
    return _mean((torch.log1p(out.clamp(min=0)) - torch.log1p(rs.image)) ** 2, mask)


# ---------------------------------------------------------------------------------------------
# the combined objective


def pick_output(pred: dict[str, Tensor], key: str, refined: bool = False) -> Tensor | None:
    """``pred[key]``, or GSNet's refined ``pred[key + "_gs"]`` when ``refined`` and present."""
    if refined and f"{key}_gs" in pred:
        return pred[f"{key}_gs"]
    return pred.get(key)


def total_loss(pred: dict[str, Tensor], gt: PanoScene, weights: LossWeights,
               options: LossOptions = LossOptions(), *,
               refined: bool = False) -> tuple[Tensor, dict[str, Tensor]]:
    """Weighted sum of the active terms, averaged over the batch, and each term (unweighted, detached).

    ``pred`` is :meth:`phyir.nets.PhyIRModel.forward_parts`'s dict; ``refined`` selects GSNet's
    ``*_gs`` outputs for the material/normal terms where present.  ``gt`` is the batched
    ground-truth scene (its image is the network input).
    """
    pick = functools.partial(pick_output, pred, refined=refined)
    terms: dict[str, Tensor] = {}
    w = weights.active()
    for k in ("albedo", "roughness", "metallic"):
        if k in w:
            fn = bce if k == "metallic" and options.metallic_loss == "bce" else l2
            terms[k] = fn(pick(k), getattr(gt, k))
    if "depth" in w:
        terms["depth"] = depth_loss(pred["depth"], gt.depth, None, options.depth_mode, options.si_lambda)
    if "normal" in w:
        terms["normal"] = angular_loss(pick("normal"), gt.normal)
    if "depth_grad" in w:
        terms["depth_grad"] = depth_gradient_loss(pred["depth"], gt.depth)
    if "depth_normal" in w:
        terms["depth_normal"] = depth_normal_loss(pred["depth"], pick("normal"), gt.depth, gt.normal)
    if "probe" in w:
        terms["probe"] = probe_loss(pred["probes"], gt.probes)
    if "sc" in w:
        depth = gt.depth if gt.depth is not None else pred["depth"]
        terms["sc"] = sc_loss(pred["probes"], depth, options.sc_sigma)
    if "render" in w:
        emis = gt.masks.get(options.emission_mask)
        scene = PanoScene(image=gt.image, depth=pred["depth"], normal=pick("normal"), albedo=pick("albedo"),
                          roughness=pick("roughness"), metallic=pick("metallic"), probes=pred["probes"])
        terms["render"] = render_loss(gt.image, scene, None if emis is None else 1 - emis,
                                      options.render_size, options.render_spp, options.render_method)
    if not terms:
        raise ValueError("total_loss: every loss weight is zero")
    per_sample = sum(w[k] * v for k, v in terms.items())
    return per_sample.mean(), {k: v.detach().mean() for k, v in terms.items()}
