"""Evaluation of predicted scenes against ground truth with the paper's metrics
(:mod:`phyir.evaluation.metrics`).

* :func:`evaluate_pair` — one predicted scene against its ground truth: every metric whose layers
  both scenes have (depth, normals, materials, probes on the same grid, relighting).
* :func:`evaluate_model` — the model on a split of a synthetic dataset, next to trivial baselines:
  every scene is predicted once (LNet's probe grid); probes are compared at ``probes_per_scene``
  random ground-truth probe cells (the same cells for every method), with

  - ``lnet``: LNet's grid, bilinear at the cell's predicted 3D position,
  - ``projection``: :mod:`phyir.lighting.projection` from the predicted depth, LNet where the camera did
    not see,
  - ``fused``: the geometric mean of the two (:mod:`phyir.lighting.fusion`),
  - ``projection_gt_geometry``: the same from the ground-truth depth (the projection itself, without
    the depth network's error),
  - ``constant``: a trivial baseline (depth 3 m, normals facing the camera, base colour 0.5,
    roughness 0.5, metalness 0, every probe uniform at the image's mean radiance),
  - ``dataset_means``: the trivial baselines of the training set's statistics (:func:`means_baseline`:
    mean depth, mean base colour/roughness/metalness, the mean probe), when the dataset has a train split.

Pixels flagged ``masks["emission"]`` in the ground truth (lamps, windows) are left out of the
normal and material metrics (their base colour/roughness are undefined); depth counts every pixel.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.evaluation import metrics as M
from phyir.scene import PanoScene

CONSTANT_DEPTH = 3.0


def surface_mask(gt: PanoScene) -> Tensor | None:
    """1 where the ground truth has meaningful materials (not an emitter), or None."""
    em = gt.masks.get("emission")
    return None if em is None else (em < 0.5).float()


def model_input(gt: PanoScene) -> PanoScene:
    """The room ``gt`` as the model is given it: its image and meta, every other layer dropped."""
    return PanoScene(image=gt.image, meta=dict(gt.meta))


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
        from phyir.lighting.projection import probe_positions

        pos = probe_positions(gt.depth, gt.normal, gt.probe_grid).reshape(-1, 3) if gt.depth is not None \
            else None
        pp, gp = pred.probes.reshape(-1, 3, *pred.probe_size), gt.probes.reshape(-1, 3, *gt.probe_size)
        idx = spread(len(pp), relight)
        out |= lighting_metrics(pp[idx], gp[idx], None if pos is None else pos[idx], relight=relight,
                                spp=spp)
        out["probe_log_mse"] = M.probe_log_mse(pp, gp)  # all probes, not just the relit ones
    return out


def spread(n: int, k: int) -> Tensor:
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


def dataset_means(root: str | os.PathLike, split: str = "train",
                  limit: int | None = 200) -> dict[str, Tensor]:
    """Per-dataset means of the ``split`` (first ``limit`` scenes) for :func:`means_baseline`: depth,
    base colour [3], roughness, metalness (over non-emissive pixels) and the mean probe [3,h,w] of
    exposure-normalised scenes (:func:`phyir.learn.datasets.exposure_scale`)."""
    from phyir.color import exposure_scale
    from phyir.io import load_scene
    from phyir.learn.datasets import split_files

    acc: dict[str, Tensor] = {}
    n_pix = n_mat = n_probe = 0
    for f in split_files(root, split, limit):
        s = load_scene(f).to(dtype=torch.float64)
        m = surface_mask(s)
        m = torch.ones_like(s.depth) if m is None else m
        acc["depth"] = acc.get("depth", 0) + s.depth.sum()
        n_pix += s.depth.numel()
        for k in ("albedo", "roughness", "metallic"):
            acc[k] = acc.get(k, 0) + (getattr(s, k) * m).sum((-2, -1))
        n_mat += float(m.sum())
        if s.probes is not None:
            p = s.probes.reshape(-1, 3, *s.probe_size) * exposure_scale(s.image).double()
            if "probe" in acc and acc["probe"].shape[-2:] != p.shape[-2:]:
                p = pano.resize_area(p, *acc["probe"].shape[-2:])
            acc["probe"] = acc.get("probe", 0) + p.sum(0)
            n_probe += len(p)
    out = {"depth": acc["depth"] / n_pix}
    out |= {k: acc[k] / max(n_mat, 1) for k in ("albedo", "roughness", "metallic")}
    if n_probe:
        out["probe"] = acc["probe"] / n_probe
    return {k: v.float() for k, v in out.items()}


def means_baseline(gt: PanoScene, means: dict[str, Tensor]) -> PanoScene:
    """The dataset-means predictor: the training set's mean depth, base colour, roughness and
    metalness everywhere, normals facing the camera, every probe the mean (exposure-normalised) probe
    brought to this image's exposure."""
    from phyir.color import exposure_scale

    H, W = gt.size
    probes = None
    if gt.probes is not None and "probe" in means:
        mp = _resample_probes(means["probe"][None], tuple(gt.probe_size))[0] / exposure_scale(gt.image)
        probes = mp.expand_as(gt.probes).clone()
    return PanoScene(image=gt.image, depth=means["depth"].expand(1, H, W).clone(),
                     normal=-pano.directions(H, W),
                     albedo=means["albedo"].view(3, 1, 1).expand(3, H, W).clone(),
                     roughness=means["roughness"].view(1, 1, 1).expand(1, H, W).clone(),
                     metallic=means["metallic"].view(1, 1, 1).expand(1, H, W).clone(), probes=probes)


def evaluate_model(root: str | os.PathLike, split: str = "test", *, weights=None, model=None,
                   device=None, limit: int | None = None, probes_per_scene: int = 256, relight: int = 16,
                   spp: int = 64, seed: int = 0,
                   log: Callable[[str], None] | None = None) -> dict[str, dict[str, float]]:
    """Metrics per method (``model/lnet``, ``model/projection``, ``model/fused``, ``projection_gt_geometry``,
    ``constant``, ``dataset_means``) averaged over the scenes of ``split``; see the module doc.
    ``model/lnet`` also has ``predict_seconds``: the mean time of :func:`phyir.predict` per scene
    (LNet lighting)."""
    from phyir.inference import lnet_probes_at, predict
    from phyir.io import load_scene
    from phyir.learn.datasets import split_files
    from phyir.lighting.fusion import fuse_probes
    from phyir.lighting.projection import DepthSurface, project_probes

    root = Path(root)
    files = split_files(root, split, limit)
    means = dataset_means(root, "train") if split != "train" and read_manifest_has(root, "train") else None
    methods = ["model/lnet", "model/projection", "model/fused", "projection_gt_geometry", "constant"]
    meters = {k: M.MetricMeter() for k in methods + (["dataset_means"] if means is not None else [])}
    seconds = []
    for i, path in enumerate(files):
        name = path.name
        gt = load_scene(path)
        if gt.probes is None:
            raise ValueError(f"{path}: ground truth has no probes")
        t0 = time.perf_counter()
        pred = predict(model_input(gt), weights=weights, model=model, device=device, lighting="lnet")
        seconds.append(time.perf_counter() - t0)
        pix = pixel_metrics(pred, gt)
        pc = probe_cells(pred, gt, i, seed=seed, count=probes_per_scene)
        cells, gt_p, gt_pos, lnet, proj = pc.cells, pc.truth, pc.truth_pos, pc.lnet, pc.projected
        fused = fuse_probes(lnet, proj)
        Hp, Wp = gt.probe_grid
        size = tuple(gt.probe_size)
        gt_geo = PanoScene(image=gt.image, depth=gt.depth, normal=gt.normal)
        proj_gt = project_probes(DepthSurface.from_scene(gt_geo), gt_pos,
                                 size, _resample_probes(lnet_probes_at(pred.probes, gt_pos), size))[0]
        base = constant_baseline(gt)
        kw = dict(relight=relight, spp=spp, seed=seed)
        rows = {
            "model/lnet": pix | lighting_metrics(lnet, gt_p, gt_pos, **kw),
            "model/projection": pix | lighting_metrics(proj, gt_p, gt_pos, **kw),
            "model/fused": pix | lighting_metrics(fused, gt_p, gt_pos, **kw),
            "projection_gt_geometry": lighting_metrics(proj_gt, gt_p, gt_pos, **kw),
            "constant": pixel_metrics(base, gt) | lighting_metrics(
                base.probes.reshape(Hp * Wp, 3, *size)[cells], gt_p, gt_pos, **kw),
        }
        if means is not None:
            mb = means_baseline(gt, means)
            rows["dataset_means"] = pixel_metrics(mb, gt) | lighting_metrics(
                mb.probes.reshape(Hp * Wp, 3, *size)[cells], gt_p, gt_pos, **kw)
        for k, v in rows.items():
            meters[k].add(v)
        if log is not None:
            log(f"[{i + 1}/{len(files)}] {name}: {seconds[-1]:.2f} s, probe log-MSE lnet "
                f"{rows['model/lnet']['probe_log_mse']:.4f} projection "
                f"{rows['model/projection']['probe_log_mse']:.4f}")
    out = {k: m.result() for k, m in meters.items()}
    if means is not None:
        out[MARGIN_KEY] = margins(meters["model/lnet"], meters["dataset_means"])
    out["model/lnet"]["predict_seconds"] = sum(seconds) / len(seconds)
    return out


@dataclass
class ProbeCells:
    """The probe cells one scene is evaluated at (the same for every method): their indices, the
    path-traced probes and their positions, and the model's two estimates there."""

    cells: Tensor  # [N] indices into the flattened probe grid
    truth: Tensor  # [N,3,h,w]
    truth_pos: Tensor  # [N,3] the ground-truth probe positions
    lnet: Tensor  # [N,3,h,w] LNet's grid at the cell's predicted position
    projected: Tensor  # [N,3,h,w] the panorama projected from there, LNet where unseen


def probe_cells(pred: PanoScene, gt: PanoScene, index: int, *, seed: int = 0, count: int = 256) -> ProbeCells:
    """:class:`ProbeCells` of scene ``index`` of a split: ``count`` random cells seeded per scene, ``pred``
    a prediction with LNet's grid."""
    from phyir.inference import lnet_probes_at
    from phyir.lighting.projection import DepthSurface, probe_positions, project_probes

    Hp, Wp = gt.probe_grid
    g = torch.Generator().manual_seed(seed * 1_000_003 + index)
    cells = torch.randperm(Hp * Wp, generator=g)[:count]
    truth = gt.probes.reshape(Hp * Wp, 3, *gt.probe_size)[cells]
    truth_pos = probe_positions(gt.depth, gt.normal, (Hp, Wp)).reshape(-1, 3)[cells]
    pos = probe_positions(pred.depth, pred.normal, (Hp, Wp)).reshape(-1, 3)[cells]
    size = tuple(gt.probe_size)
    lnet = _resample_probes(lnet_probes_at(pred.probes, pos), size)
    projected = project_probes(DepthSurface.from_scene(pred), pos, size, lnet)[0]
    return ProbeCells(cells, truth, truth_pos, lnet, projected)


MARGIN_KEY = "margin/model/lnet-vs-dataset_means"


def margins(model: M.MetricMeter, base: M.MetricMeter) -> dict[str, float]:
    """:func:`phyir.evaluation.metrics.paired_margin` of every metric both have, flattened to
    ``<metric>.<margin|ci_low|ci_high|better|scenes>`` (so the results stay a dict of float dicts)."""
    keys = [k for k in model.result() if k in base.result()]
    out: dict[str, float] = {}
    for k in keys:
        m = M.paired_margin(model, base, k)
        if m is not None:
            out |= {f"{k}.{f}": v for f, v in m.items()}
    return out


def read_manifest_has(root: str | os.PathLike, split: str) -> bool:
    """Whether the dataset's manifest lists any ``split`` scene that exists."""
    from phyir.learn.datasets import read_manifest

    return any((Path(root) / f).is_file() for f in read_manifest(root)[split])


def _resample_probes(p: Tensor, size: tuple[int, int]) -> Tensor:
    """Probes [N,3,h,w] at another probe size (area resampling in the equirect domain)."""
    return p if tuple(p.shape[-2:]) == tuple(size) else pano.resize_area(p, *size)
