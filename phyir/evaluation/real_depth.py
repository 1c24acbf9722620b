"""Geometry on scanned rooms against their laser/RGB-D depth: the protocol of 360° depth benchmarks.

Per room (supplement D.4 and the depth tables of UniFuse, HoHoNet, DA²): the prediction scaled by
median(truth) / median(prediction) over valid pixels, then AbsRel, Sq Rel, RMSE, RMSE log and
δ < 1.25ⁿ (``aligned.*``); the same unscaled (``metric.*``: users get metric depth); ``scale``, the
factor the alignment applied (1: the metric scale is right); a constant depth under the same
alignment (``constant.*``: what a prediction must beat to carry any shape); the predicted normals
against the normals of the true depth (``normal.*``, degrees, pixels whose four neighbours are valid
too); and predict's own :func:`phyir.evaluation.real.scene_confidence` of the room. Summaries are
medians over rooms; ``confidence_rank_corr`` is the Spearman correlation over rooms between the
confidence and the aligned AbsRel (negative: confidence falls as the error grows).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from phyir import pano
from phyir.evaluation import metrics as M
from phyir.evaluation.scans import Scan, find_scans, read_depth
from phyir.scene import PanoScene

DEPTH_KEYS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1", "delta2", "delta3")
NORMAL_KEYS = ("mean", "median", "pct_11.25", "pct_30")
SUMMARY_KEYS = ["aligned.abs_rel", "aligned.delta1", "aligned.rmse", "constant.abs_rel", "metric.abs_rel",
                "scale", "normal.mean", "confidence", "seconds"]


def median_scale(pred: Tensor, gt: Tensor) -> float:
    """median(gt) / median(pred) over the pixels where ``gt`` is valid (> 0)."""
    valid = gt > 0
    return float(gt[valid].median() / pred[valid].clamp_min(1e-6).median())


def valid_normals_mask(gt: Tensor) -> Tensor:
    """Pixels ``[1,H,W]`` whose depth and four neighbours' depths are valid (a normal needs them)."""
    v = gt > 0
    up = torch.cat((v[:, :1], v[:, :-1]), 1)
    down = torch.cat((v[:, 1:], v[:, -1:]), 1)
    return v & up & down & torch.roll(v, 1, -1) & torch.roll(v, -1, -1)


def depth_rows(pred: Tensor, gt: Tensor) -> dict[str, float]:
    """``aligned.*``, ``metric.*``, ``constant.*`` and ``scale`` of a predicted depth ``[1,H,W]``."""
    s = median_scale(pred, gt)
    mask = gt > 0
    out = {"scale": s}
    for prefix, p in (("aligned", pred * s), ("metric", pred),
                      ("constant", torch.full_like(gt, float(gt[mask].median())))):
        m = M.depth_metrics(p, gt, mask, min_depth=1e-3)
        out |= {f"{prefix}.{k}": m[k] for k in DEPTH_KEYS}
    return out


def normal_rows(normal: Tensor, gt: Tensor) -> dict[str, float]:
    """``normal.*`` of predicted normals ``[3,H,W]`` against those of the true depth."""
    truth = pano.normals_from_depth(gt.clamp_min(1e-3).double()).float()
    m = M.normal_metrics(normal, truth, valid_normals_mask(gt))
    return {f"normal.{k}": m[k] for k in NORMAL_KEYS}


def evaluate_scan(scan: Scan, predictor: Callable[..., PanoScene]) -> tuple[dict[str, float], dict]:
    """The room's metrics and what its contact-sheet row shows (image, truth, prediction, error)."""
    from phyir.evaluation.real import scene_confidence

    gt = read_depth(scan)
    t0 = time.perf_counter()
    scene = predictor(scan.image)
    seconds = time.perf_counter() - t0
    depth, normal = scene.depth.float(), scene.normal.float()
    if depth.shape[-2:] != gt.shape[-2:]:  # the truth at another size than its image
        depth = pano.resize_area(depth, *gt.shape[-2:])
        normal = pano.resize_area(normal, *gt.shape[-2:])
    row = depth_rows(depth, gt) | normal_rows(normal, gt)
    row |= {"confidence": float(scene_confidence(scene)["confidence"]), "seconds": seconds}
    s = row["scale"]
    rel = torch.where(gt > 0, (depth * s - gt).abs() / gt.clamp_min(1e-3), torch.zeros_like(gt))
    return row, {"image": scene.image, "truth": gt, "ours": depth * s, "error": rel}


def spearman(a: list[float], b: list[float]) -> float:
    """Spearman's rank correlation (ties get their mean rank); NaN for fewer than three pairs."""
    if len(a) < 3:
        return math.nan
    def ranks(x: list[float]) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        order = np.argsort(x, kind="stable")
        r = np.empty(len(x))
        r[order] = np.arange(len(x), dtype=np.float64)
        for v in np.unique(x):  # ties: the mean rank
            r[x == v] = r[x == v].mean()
        return r
    ra, rb = ranks(a), ranks(b)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    den = math.sqrt(float((ra * ra).sum() * (rb * rb).sum()))
    return float((ra * rb).sum() / den) if den > 0 else math.nan


def summary(rows: dict[str, dict[str, float]]) -> dict[str, float]:
    """Medians over rooms, the constant's margin and the confidence's rank correlation with the error."""
    keys = sorted({k for r in rows.values() for k in r})
    out = {k: float(np.median([r[k] for r in rows.values() if k in r])) for k in keys}
    out["worst_constant_margin"] = max(r["aligned.abs_rel"] / r["constant.abs_rel"] for r in rows.values())
    out["confidence_rank_corr"] = spearman([r["confidence"] for r in rows.values()],
                                           [r["aligned.abs_rel"] for r in rows.values()])
    out["rooms"] = len(rows)
    return out


def evaluate_scans(folder: str | os.PathLike, *, sheet: str | os.PathLike | None = None,
                   log: Callable[[str], None] | None = None, **predict_kwargs) -> dict:
    """Every scan of ``folder`` (:func:`phyir.evaluation.scans.find_scans`) through ``phyir.predict``
    (``predict_kwargs``: weights, geometry, net_size, ...); returns ``{"rooms": {name: row},
    "median": summary}`` and writes the contact sheet to ``sheet``."""
    from phyir.inference import predict

    def predictor(path: Path) -> PanoScene:
        return predict(path, outputs=("depth", "normal"), probes=None, **predict_kwargs)

    rows, tiles = {}, []
    for scan in find_scans(folder):
        rows[scan.name], shown = evaluate_scan(scan, predictor)
        tiles.append((scan.name, shown))
        if log is not None:
            r = rows[scan.name]
            log(f"{scan.name}: AbsRel {r['aligned.abs_rel']:.3f} (constant {r['constant.abs_rel']:.3f}), "
                f"δ1 {r['aligned.delta1']:.3f}, metric {r['metric.abs_rel']:.3f}, normals "
                f"{r['normal.mean']:.1f}°, confidence {r['confidence']:.2f}")
    if sheet is not None:
        from phyir.evaluation.depth_sheet import save_depth_sheet

        save_depth_sheet(tiles, sheet)
    return {"rooms": rows, "median": summary(rows)}


def markdown_scans(results: dict) -> str:
    """One row per room and the median, the constant depth beside ours."""
    from phyir.evaluation.metrics import markdown_table

    rows = dict(results["rooms"]) | {"median": results["median"]}
    return markdown_table(rows, SUMMARY_KEYS, digits=3)
