"""Evaluation of predicted scenes against ground truth with the paper's metrics (:mod:`phyir.metrics`).

* :func:`evaluate_pair` — one predicted scene against its ground truth: every metric whose layers
  both scenes have (depth, normals, materials, probes on the same grid, relighting).
* :func:`evaluate_model` — the model on a split of a synthetic dataset, next to trivial baselines:
  every scene is predicted once (LNet's probe grid); probes are compared at ``probes_per_scene``
  random ground-truth probe cells (the same cells for every method), with

  - ``lnet``: LNet's grid, bilinear at the cell's predicted 3D position,
  - ``projection``: :mod:`phyir.projection` from the predicted depth, LNet where the camera did not see,
  - ``projection_gt_geometry``: the same from the ground-truth depth (the projection itself, without
    the depth network's error),
  - ``constant``: a trivial baseline (depth 3 m, normals facing the camera, base colour 0.5,
    roughness 0.5, metalness 0, every probe uniform at the image's mean radiance).

Pixels flagged ``masks["emission"]`` in the ground truth (lamps, windows) are left out of the
normal and material metrics (their base colour/roughness are undefined); depth counts every pixel.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor

from phyir import metrics as M
from phyir import pano
from phyir.scene import PanoScene

CONSTANT_DEPTH = 3.0


def surface_mask(gt: PanoScene) -> Tensor | None:
    """1 where the ground truth has meaningful materials (not an emitter), or None."""
    em = gt.masks.get("emission")
    return None if em is None else (em < 0.5).float()


def pixel_metrics(pred: PanoScene, gt: PanoScene) -> dict[str, float]:
    """Depth, normal and material metrics (keys ``depth.*``, ``normal.*``, ``albedo_mse``...)."""
    if pred.size != gt.size:
        raise ValueError(f"evaluate: prediction {pred.size} and ground truth {gt.size} differ in size")
    out: dict[str, float] = {}
    mask = surface_mask(gt)
    if pred.depth is not None and gt.depth is not None:
        out |= M.prefixed("depth", M.depth_metrics(pred.depth, gt.depth))
    if pred.normal is not None and gt.normal is not None:
        out |= M.prefixed("normal", M.normal_metrics(pred.normal, gt.normal, mask))
    out |= M.material_metrics(pred.albedo, gt.albedo, pred.roughness, gt.roughness, pred.metallic,
                              gt.metallic, mask)
    return {k: v for k, v in out.items() if not k.endswith(".count")}


def lighting_metrics(pred_probes: Tensor, gt_probes: Tensor, positions: Tensor | None, *,
                     relight: int = 16, spp: int = 64, size: int = 16, seed: int = 0) -> dict[str, float]:
    """``probe_log_mse`` over [N,3,h,w] probes and the relighting errors at the first ``relight``."""
    out = {"probe_log_mse": M.probe_log_mse(pred_probes, gt_probes)}
    if relight and positions is not None:
        k = min(relight, len(positions))
        out |= M.relight_errors(pred_probes[:k], gt_probes[:k], positions[:k], size=size, spp=spp,
                                seed=seed)
    return out


def evaluate_pair(pred: PanoScene, gt: PanoScene, *, relight: int = 16, spp: int = 64) -> dict[str, float]:
    """Every metric the two scenes allow; probes count when both have the same grid and probe size."""
    out = pixel_metrics(pred, gt)
    if pred.probes is not None and gt.probes is not None and pred.probes.shape == gt.probes.shape:
        from phyir.projection import probe_positions

        pos = probe_positions(gt.depth, gt.normal, gt.probe_grid).reshape(-1, 3) if gt.depth is not None \
            else None
        pp, gp = pred.probes.reshape(-1, 3, *pred.probe_size), gt.probes.reshape(-1, 3, *gt.probe_size)
        idx = _spread(len(pp), relight)
        out |= lighting_metrics(pp[idx], gp[idx], None if pos is None else pos[idx], relight=relight,
                                spp=spp)
        out["probe_log_mse"] = M.probe_log_mse(pp, gp)  # all probes, not just the relit ones
    return out


def _spread(n: int, k: int) -> Tensor:
    """k indices spread evenly over range(n), then the rest (so a prefix of length k is spread)."""
    first = torch.linspace(0, n - 1, max(1, min(k, n))).round().long().unique()
    rest = torch.ones(n, dtype=torch.bool)
    rest[first] = False
    return torch.cat((first, torch.nonzero(rest).squeeze(1)))


def constant_baseline(gt: PanoScene) -> PanoScene:
    """The trivial prediction (see module doc), at the ground truth's size and probe grid."""
    H, W = gt.size
    d = pano.directions(H, W)
    omega = pano.solid_angles(H, W)
    mean = (gt.image * omega).sum((-2, -1)) / omega.sum()
    probes = None
    if gt.probes is not None:
        probes = mean.view(1, 1, 3, 1, 1).expand_as(gt.probes).clone()
    return PanoScene(image=gt.image, depth=torch.full((1, H, W), CONSTANT_DEPTH), normal=-d,
                     albedo=torch.full((3, H, W), 0.5), roughness=torch.full((1, H, W), 0.5),
                     metallic=torch.zeros(1, H, W), probes=probes)


def evaluate_model(root: str | os.PathLike, split: str = "test", *, weights=None, model=None,
                   device=None, limit: int | None = None, probes_per_scene: int = 256, relight: int = 16,
                   spp: int = 64, seed: int = 0,
                   log: Callable[[str], None] | None = None) -> dict[str, dict[str, float]]:
    """Metrics per method (``model/lnet``, ``model/projection``, ``projection_gt_geometry``,
    ``constant``) averaged over the scenes of ``split``; see the module doc.  ``model/lnet`` also
    has ``predict_seconds``: the mean time of :func:`phyir.predict` per scene (LNet lighting)."""
    from phyir.data import read_manifest
    from phyir.inference import lnet_probes_at, predict
    from phyir.io import load_scene
    from phyir.projection import DepthSurface, probe_positions, project_probes

    root = Path(root)
    files = read_manifest(root)[split][:limit]
    if not files:
        raise ValueError(f"{root}: split {split!r} is empty")
    meters = {k: M.MetricMeter() for k in ("model/lnet", "model/projection", "projection_gt_geometry",
                                           "constant")}
    seconds = []
    for i, name in enumerate(files):
        gt = load_scene(root / name)
        if gt.probes is None:
            raise ValueError(f"{root / name}: ground truth has no probes")
        t0 = time.perf_counter()
        pred = predict(gt.replace(depth=None, normal=None, albedo=None, roughness=None, metallic=None,
                                  probes=None, masks={}),
                       weights=weights, model=model, device=device, lighting="lnet")
        seconds.append(time.perf_counter() - t0)
        pix = pixel_metrics(pred, gt)
        # the probe cells evaluated (same for all methods), seeded per scene
        Hp, Wp = gt.probe_grid
        g = torch.Generator().manual_seed(seed * 1_000_003 + i)
        cells = torch.randperm(Hp * Wp, generator=g)[:probes_per_scene]
        gt_p = gt.probes.reshape(Hp * Wp, 3, *gt.probe_size)[cells]
        gt_pos = probe_positions(gt.depth, gt.normal, (Hp, Wp)).reshape(-1, 3)[cells]
        pred_pos = probe_positions(pred.depth, pred.normal, (Hp, Wp)).reshape(-1, 3)[cells]
        size = tuple(gt.probe_size)
        lnet = _resample_probes(lnet_probes_at(pred.probes, pred_pos), size)
        proj = project_probes(DepthSurface.from_scene(pred), pred_pos, size, lnet)[0]
        gt_geo = PanoScene(image=gt.image, depth=gt.depth, normal=gt.normal)
        proj_gt = project_probes(DepthSurface.from_scene(gt_geo), gt_pos,
                                 size, _resample_probes(lnet_probes_at(pred.probes, gt_pos), size))[0]
        base = constant_baseline(gt)
        kw = dict(relight=relight, spp=spp, seed=seed)
        rows = {
            "model/lnet": pix | lighting_metrics(lnet, gt_p, gt_pos, **kw),
            "model/projection": pix | lighting_metrics(proj, gt_p, gt_pos, **kw),
            "projection_gt_geometry": lighting_metrics(proj_gt, gt_p, gt_pos, **kw),
            "constant": pixel_metrics(base, gt) | lighting_metrics(
                base.probes.reshape(Hp * Wp, 3, *size)[cells], gt_p, gt_pos, **kw),
        }
        for k, v in rows.items():
            meters[k].add(v)
        if log is not None:
            log(f"[{i + 1}/{len(files)}] {name}: {seconds[-1]:.2f} s, probe log-MSE lnet "
                f"{rows['model/lnet']['probe_log_mse']:.4f} projection "
                f"{rows['model/projection']['probe_log_mse']:.4f}")
    out = {k: m.result() for k, m in meters.items()}
    out["model/lnet"]["predict_seconds"] = sum(seconds) / len(seconds)
    return out


def _resample_probes(p: Tensor, size: tuple[int, int]) -> Tensor:
    """Probes [N,3,h,w] at another probe size (area resampling in the equirect domain)."""
    return p if tuple(p.shape[-2:]) == tuple(size) else pano.resize_area(p, *size)
