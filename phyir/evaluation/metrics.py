"""Evaluation metrics of the PhyIR paper (supplement D.3, D.4, Table 3) for panoramas and probes.

Conventions (every function):
- Inputs are torch tensors, unbatched ``[C,H,W]`` or batched ``[B,C,H,W]``; a metric is computed per
  image and then averaged over the images (the usual protocol of depth benchmarks).  Images without a
  single valid pixel are left out of the average (the returned ``count`` says how many counted).
- Per-pixel metrics (depth, normals, materials) weight every valid pixel equally, as the paper's
  tables do.  ``area_weighted=True`` weights pixels by their solid angle instead, so the
  over-sampled rows near the equirect poles count for the area they really cover.
- Lighting errors are always area-weighted: each probe texel counts for its solid angle.
- Fractions (δ thresholds) are in [0, 1]; normal-angle shares are in percent, angles in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import torch
from torch import Tensor

from phyir.pano import solid_angles

# ---------------------------------------------------------------------------------------------
# helpers


def _batch(x: Tensor) -> Tensor:
    return x[None] if x.dim() == 3 else x


def _weights(gt: Tensor, valid: Tensor, area_weighted: bool) -> Tensor:
    """[B,1,H,W] float weights: the valid mask, times the pixel solid angle if asked."""
    w = valid.to(gt.dtype)
    if area_weighted:
        H, W = gt.shape[-2:]
        w = w * solid_angles(H, W, gt.device, gt.dtype)
    return w


def _wmean(x: Tensor, w: Tensor) -> Tensor:
    """Per-image weighted mean of [B,C,H,W] (weights [B,1,H,W] broadcast over channels) -> [B]."""
    num = (x * w).flatten(1).sum(1)
    den = (w.expand_as(x)).flatten(1).sum(1)
    return num / den.clamp_min(1e-30)


def _mean_over_images(per_image: Mapping[str, Tensor], has_valid: Tensor) -> dict[str, float]:
    out = {k: float(v[has_valid].mean()) if has_valid.any() else math.nan for k, v in per_image.items()}
    out["count"] = int(has_valid.sum())
    return out


def _user_mask(mask: Tensor | None, like: Tensor) -> Tensor:
    if mask is None:
        return torch.ones_like(like[:, :1], dtype=torch.bool)
    return _batch(mask) > 0.5


# ---------------------------------------------------------------------------------------------
# depth (supplement D.4, Table 3)

DEPTH_KEYS = ("mae", "abs_rel", "sq_rel", "rmse", "rmse_log", "log10", "delta1", "delta2", "delta3")


def depth_metrics(pred: Tensor, gt: Tensor, mask: Tensor | None = None, *, min_depth: float = 1e-3,
                  max_depth: float | None = None, area_weighted: bool = False) -> dict[str, float]:
    """MAE, AbsRel, SqRel, RMSE, RMSElog, log10, δ<1.25, δ<1.25², δ<1.25³ of radial depth [(B,)1,H,W].

    Valid pixels: finite ground truth in (min_depth, max_depth] (and ``mask`` > 0.5 where given).
    Predictions are clamped to ``min_depth`` before logs and ratios.  RMSElog uses the natural
    logarithm (Eigen et al.), log10 is the mean absolute log10 ratio; δ_n is the share of valid
    pixels with max(p/g, g/p) < 1.25^n.
    """
    p, g = _batch(pred).to(torch.float64), _batch(gt).to(torch.float64)
    valid = torch.isfinite(g) & (g > min_depth) & _user_mask(mask, g)
    if max_depth is not None:
        valid &= g <= max_depth
    g = torch.where(valid, g, torch.ones_like(g))
    p = torch.nan_to_num(p, nan=min_depth, posinf=1e6).clamp_min(min_depth)
    w = _weights(g, valid, area_weighted)
    diff = p - g
    ratio = torch.maximum(p / g, g / p)
    per = {
        "mae": _wmean(diff.abs(), w),
        "abs_rel": _wmean(diff.abs() / g, w),
        "sq_rel": _wmean(diff * diff / g, w),
        "rmse": _wmean(diff * diff, w).sqrt(),
        "rmse_log": _wmean((torch.log(p) - torch.log(g)) ** 2, w).sqrt(),
        "log10": _wmean((torch.log10(p) - torch.log10(g)).abs(), w),
    }
    for n in (1, 2, 3):
        per[f"delta{n}"] = _wmean((ratio < 1.25**n).to(g.dtype), w)
    return _mean_over_images(per, valid.flatten(1).any(1))


# ---------------------------------------------------------------------------------------------
# normals

NORMAL_THRESHOLDS = (11.25, 22.5, 30.0)


def angular_error_deg(pred: Tensor, gt: Tensor, dim: int = -3) -> Tensor:
    """Angle in degrees between (not necessarily unit) vectors along ``dim``."""
    pn = pred / torch.linalg.vector_norm(pred, dim=dim, keepdim=True).clamp_min(1e-12)
    gn = gt / torch.linalg.vector_norm(gt, dim=dim, keepdim=True).clamp_min(1e-12)
    # atan2(|p x g|, p.g) is accurate at small angles where acos(p.g) is not
    cross = torch.linalg.vector_norm(torch.cross(pn, gn, dim=dim), dim=dim, keepdim=True)
    return torch.rad2deg(torch.atan2(cross, (pn * gn).sum(dim, keepdim=True)))


def _weighted_median(x: Tensor, w: Tensor) -> Tensor:
    """Median of 1-D ``x`` under weights ``w``: the smallest x whose cumulative weight reaches half."""
    xs, order = torch.sort(x)
    cw = torch.cumsum(w[order], 0)
    idx = torch.searchsorted(cw, 0.5 * cw[-1])
    return xs[idx.clamp(max=xs.numel() - 1)]


def normal_metrics(pred: Tensor, gt: Tensor, mask: Tensor | None = None, *,
                   area_weighted: bool = False) -> dict[str, float]:
    """Mean/median angular error (degrees) and % of pixels under 11.25°, 22.5°, 30° of [(B,)3,H,W].

    Valid pixels: ground truth of length > 0.5 (zero normals mark "no ground truth"), finite.
    The median of a weighted set is the weighted median.
    """
    p, g = _batch(pred).to(torch.float64), _batch(gt).to(torch.float64)
    gl = torch.linalg.vector_norm(g, dim=1, keepdim=True)
    valid = torch.isfinite(gl) & (gl > 0.5) & _user_mask(mask, g)
    p = torch.nan_to_num(p)
    ang = angular_error_deg(p, torch.where(valid, g, torch.ones_like(g)), dim=1)
    w = _weights(g, valid, area_weighted)
    per: dict[str, list[float]] = {"mean": [], "median": []} | {f"pct_{t:g}": [] for t in NORMAL_THRESHOLDS}
    has = valid.flatten(1).any(1)
    for b in range(p.shape[0]):
        if not has[b]:
            continue
        a, wb = ang[b].flatten(), w[b].flatten()
        keep = wb > 0
        a, wb = a[keep], wb[keep]
        per["mean"].append(float((a * wb).sum() / wb.sum()))
        per["median"].append(float(_weighted_median(a, wb)))
        for t in NORMAL_THRESHOLDS:
            per[f"pct_{t:g}"].append(float(100 * (wb * (a < t)).sum() / wb.sum()))
    out = {k: (sum(v) / len(v) if v else math.nan) for k, v in per.items()}
    out["count"] = int(has.sum())
    return out


# ---------------------------------------------------------------------------------------------
# materials


def mse(pred: Tensor, gt: Tensor, mask: Tensor | None = None, *, area_weighted: bool = False) -> float:
    """Mean squared error over valid pixels and channels of [(B,)C,H,W], averaged over images."""
    p, g = _batch(pred).to(torch.float64), _batch(gt).to(torch.float64)
    valid = torch.isfinite(g).all(1, keepdim=True) & _user_mask(mask, g)
    g = torch.where(valid, g, torch.zeros_like(g))
    w = _weights(g, valid, area_weighted)
    per = _wmean((torch.nan_to_num(p) - g) ** 2, w)
    has = valid.flatten(1).any(1)
    return float(per[has].mean()) if has.any() else math.nan


def si_mse(pred: Tensor, gt: Tensor, mask: Tensor | None = None, *, area_weighted: bool = False) -> float:
    """Scale-invariant MSE: each image's channel c is first scaled by its least-squares optimum
    s_c = Σ w p g / Σ w p² (per image and per channel), then the MSE is taken as in :func:`mse`."""
    p, g = _batch(pred).to(torch.float64), _batch(gt).to(torch.float64)
    valid = torch.isfinite(g).all(1, keepdim=True) & _user_mask(mask, g)
    g = torch.where(valid, g, torch.zeros_like(g))
    p = torch.nan_to_num(p)
    w = _weights(g, valid, area_weighted)
    num = (w * p * g).sum((-2, -1), keepdim=True)
    den = (w * p * p).sum((-2, -1), keepdim=True)
    s = torch.where(den > 0, num / den.clamp_min(1e-30), torch.zeros_like(den))
    return mse(s * p, g, valid.to(g.dtype), area_weighted=area_weighted)


def binary_auc(scores: Tensor, labels: Tensor) -> float:
    """Area under the ROC curve of ``scores`` for boolean ``labels`` (same shape, pooled over every
    element): the probability that a random positive scores above a random negative, ties counted
    half.  NaN when either class is empty.  Used for metalness, where metal covers under 1 % of the
    pixels and the MSE says little about whether metal is found."""
    s = scores.detach().flatten().double()
    y = labels.flatten().bool()
    n_pos = int(y.sum())
    n_neg = y.numel() - n_pos
    if n_pos == 0 or n_neg == 0:
        return math.nan
    # mid-ranks: tied scores share the mean of their ranks
    _, inverse, counts = torch.unique(s, return_inverse=True, return_counts=True)
    first = torch.cumsum(counts, 0) - counts
    mid = (first.double() + (counts.double() - 1) / 2)[inverse]
    return float((mid[y].sum() - n_pos * (n_pos - 1) / 2) / (n_pos * n_neg))


def material_metrics(pred_albedo: Tensor | None, gt_albedo: Tensor | None,
                     pred_roughness: Tensor | None = None, gt_roughness: Tensor | None = None,
                     pred_metallic: Tensor | None = None, gt_metallic: Tensor | None = None,
                     mask: Tensor | None = None, *, area_weighted: bool = False) -> dict[str, float]:
    """``albedo_mse``, ``albedo_si_mse``, ``roughness_mse``, ``metallic_mse`` for the pairs given, and
    ``metallic_auc``: :func:`binary_auc` of the predicted metalness for metal (gt > 0.5) among the
    pixels in ``mask``, pooled over the images given (NaN without both metal and non-metal; 0.5 for
    a constant prediction)."""
    out: dict[str, float] = {}
    if pred_albedo is not None and gt_albedo is not None:
        out["albedo_mse"] = mse(pred_albedo, gt_albedo, mask, area_weighted=area_weighted)
        out["albedo_si_mse"] = si_mse(pred_albedo, gt_albedo, mask, area_weighted=area_weighted)
    if pred_roughness is not None and gt_roughness is not None:
        out["roughness_mse"] = mse(pred_roughness, gt_roughness, mask, area_weighted=area_weighted)
    if pred_metallic is not None and gt_metallic is not None:
        out["metallic_mse"] = mse(pred_metallic, gt_metallic, mask, area_weighted=area_weighted)
        g = _batch(gt_metallic)
        keep = _user_mask(mask, g).expand_as(g)
        out["metallic_auc"] = binary_auc(_batch(pred_metallic).expand_as(g)[keep], g[keep] > 0.5)
    return out


# ---------------------------------------------------------------------------------------------
# lighting


def log_radiance(x: Tensor) -> Tensor:
    """log(1 + x) of HDR radiance (negative values clamped to 0)."""
    return torch.log1p(x.clamp_min(0))


def probe_log_mse(pred: Tensor, gt: Tensor, valid: Tensor | None = None) -> float:
    """Probe error in log space: solid-angle-weighted mean of (log(1+p) - log(1+g))² over each probe's
    texels and channels, then the mean over probes.

    ``pred``/``gt`` are probes ``[..., 3, h, w]`` (any leading dims: a grid ``Hp,Wp``, a batch, a list
    of N probes); ``valid [...]`` (bool, same leading dims) selects the probes that count.
    """
    h, w = gt.shape[-2:]
    omega = solid_angles(h, w, gt.device, torch.float64)
    d2 = (log_radiance(pred.to(torch.float64)) - log_radiance(gt.to(torch.float64))) ** 2
    per = (d2.mean(-3) * omega).sum((-2, -1)) / omega.sum()
    if valid is not None:
        per = per[valid.to(torch.bool)]
    return float(per.mean()) if per.numel() else math.nan


# Supplement Table 2: the three spheres of the relighting error (base colour, roughness, metalness)
RELIGHT_MATERIALS: dict[str, tuple[tuple[float, float, float], float, float]] = {
    "diffuse": ((0.5, 0.5, 0.5), 1.0, 0.0),
    "matte_silver": ((0.972, 0.960, 0.915), 0.5, 1.0),
    "mirror_silver": ((0.972, 0.960, 0.915), 0.0, 1.0),
}


def sphere_gbuffer(view_dir: Tensor, size: int = 32) -> tuple[Tensor, Tensor, Tensor]:
    """Normals, view vectors and coverage mask of a unit sphere seen by an orthographic camera.

    ``view_dir [N,3]``: unit direction from the camera toward each sphere (the camera is the
    panorama's, so a sphere at point X is seen along X/|X|).  The image's up vector is world +y
    projected onto the image plane (world +x when looking straight up/down).
    Returns ``normal [N,3,S,S]`` (zero outside the disk), ``view [N,3,S,S]`` (toward the eye, = -view_dir)
    and ``mask [N,1,S,S]`` (pixel centre inside the disk).
    """
    d = view_dir / torch.linalg.vector_norm(view_dir, dim=-1, keepdim=True).clamp_min(1e-12)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=d.dtype, device=d.device).expand_as(d)
    alt = torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype, device=d.device).expand_as(d)
    up = torch.where((d[:, 1].abs() > 0.999)[:, None], alt, up)
    right = torch.linalg.cross(d, up)
    right = right / torch.linalg.vector_norm(right, dim=-1, keepdim=True)
    up = torch.linalg.cross(right, d)
    c = (torch.arange(size, dtype=d.dtype, device=d.device) + 0.5) / size * 2 - 1
    y, x = torch.meshgrid(-c, c, indexing="ij")  # image rows run downward
    r2 = x * x + y * y
    mask = r2 < 1
    z = torch.sqrt((1 - r2).clamp_min(0))
    n = (x[None, None] * right[:, :, None, None] + y[None, None] * up[:, :, None, None]
         - z[None, None] * d[:, :, None, None])
    n = torch.where(mask[None, None], n, torch.zeros_like(n))
    view = (-d)[:, :, None, None].expand_as(n).contiguous()
    return n, view, mask[None, None].expand(d.shape[0], 1, size, size)


def render_spheres(probes: Tensor, view_dir: Tensor, material: str, *, size: int = 32,
                   spp: int = 128, method: str = "importance", seed: int = 0) -> Tensor:
    """Images ``[N,3,S,S]`` of a sphere of a Table 2 ``material`` lit by each probe ``[N,3,h,w]``.

    Each sphere is small compared with the room, so the single probe at its centre lights it all.
    Shading is :func:`phyir.shading.render.shade_env` (the renderer's image-based lighting, ``method`` and
    ``spp`` as there; the mirror sphere is one reflected look-up per pixel); pixels outside the disk
    are zero.
    """
    from phyir.shading.render import shade_env  # the renderer owns image-based lighting

    base, rough, metal = RELIGHT_MATERIALS[material]
    n, v, mask = sphere_gbuffer(view_dir.to(probes), size)
    N = n.shape[0]
    dt, dev = probes.dtype, probes.device
    b = torch.tensor(base, dtype=dt, device=dev).view(1, 3, 1, 1).expand(N, 3, size, size)
    r = torch.full((N, 1, size, size), rough, dtype=dt, device=dev)
    m = torch.full((N, 1, size, size), metal, dtype=dt, device=dev)
    img = shade_env(n, v, b, r, m, probes, spp=spp, method=method, seed=seed)  # zero normals -> 0
    return img * mask.to(img.dtype)


def relight_errors(pred_probes: Tensor, gt_probes: Tensor, positions: Tensor, *, size: int = 32,
                   spp: int = 128, method: str = "importance", seed: int = 0) -> dict[str, float]:
    """Relighting error (supplement D.3) per Table 2 material: ``relight_<material>``.

    ``pred_probes``/``gt_probes [N,3,h,w]`` at 3D ``positions [N,3]``.  For each material a sphere at
    each position is rendered with the predicted and with the ground-truth probe (same camera, same
    sample pattern, ``seed``), and the error is the MSE of log(1 + radiance) over the sphere's pixels and
    channels, averaged over the N spheres (plain, not scale-invariant: the predictions are meant to
    be in the input's radiometric units).  Pixels are weighted equally (an image-space metric).
    """
    view_dir = positions / torch.linalg.vector_norm(positions, dim=-1, keepdim=True).clamp_min(1e-12)
    out = {}
    for name in RELIGHT_MATERIALS:
        imgs = [render_spheres(probes.float(), view_dir.float(), name, size=size, spp=spp,
                               method=method, seed=seed) for probes in (pred_probes, gt_probes)]
        _, _, mask = sphere_gbuffer(view_dir.float(), size)
        d2 = (log_radiance(imgs[0].double()) - log_radiance(imgs[1].double())) ** 2
        w = mask.to(d2.dtype)
        out[f"relight_{name}"] = float(((d2 * w).sum((1, 2, 3)) / (3 * w.sum((1, 2, 3)))).mean())
    return out


# ---------------------------------------------------------------------------------------------
# aggregation over a data set


class MetricMeter:
    """Running mean of metric dicts over scenes (each scene counts once; NaNs are skipped).  The
    per-scene dicts are kept (``scenes``) so that two methods can be compared scene by scene
    (:func:`paired_margin`)."""

    def __init__(self) -> None:
        self.scenes: list[dict[str, float]] = []

    def add(self, metrics: Mapping[str, float]) -> None:
        self.scenes.append({k: float(v) for k, v in metrics.items()
                            if not (k == "count" or k.endswith(".count") or v is None or math.isnan(v))})

    def result(self) -> dict[str, float]:
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for row in self.scenes:
            for k, v in row.items():
                sums[k] = sums.get(k, 0.0) + v
                counts[k] = counts.get(k, 0) + 1
        return {k: sums[k] / counts[k] for k in sums}


# metrics where larger is better (the rest are errors)
HIGHER_IS_BETTER = ("depth.delta1", "depth.delta2", "depth.delta3", "normal.pct_11.25", "normal.pct_22.5",
                    "normal.pct_30", "metallic_auc")


def paired_margin(model: MetricMeter, base: MetricMeter, key: str, *, resamples: int = 10_000,
                  seed: int = 0) -> dict[str, float] | None:
    """How ``model`` compares with ``base`` on ``key`` over the scenes both have it for: ``margin``
    = mean(model) / mean(base) - 1, its 95 % bootstrap interval over scenes (``ci_low``,
    ``ci_high``; scenes resampled with replacement, seeded) and ``better`` = the number of the
    ``scenes`` where the model is better (larger for :data:`HIGHER_IS_BETTER`, else smaller).
    None when no scene has both values or the baseline's mean is 0."""
    pairs = [(a[key], b[key]) for a, b in zip(model.scenes, base.scenes, strict=True)
             if key in a and key in b]
    if not pairs:
        return None
    a, b = torch.tensor(pairs, dtype=torch.float64).T
    if float(b.mean()) == 0.0:
        return None
    g = torch.Generator().manual_seed(seed)
    idx = torch.randint(0, len(pairs), (resamples, len(pairs)), generator=g)
    boot = a[idx].mean(1) / b[idx].mean(1) - 1
    better = a > b if key in HIGHER_IS_BETTER else a < b
    return {"margin": float(a.mean() / b.mean() - 1), "ci_low": float(boot.quantile(0.025)),
            "ci_high": float(boot.quantile(0.975)), "better": float(better.sum()),
            "scenes": float(len(pairs))}


def prefixed(prefix: str, metrics: Mapping[str, float]) -> dict[str, float]:
    return {f"{prefix}.{k}": v for k, v in metrics.items()}


def markdown_table(rows: Mapping[str, Mapping[str, float]], keys: Iterable[str] | None = None,
                   digits: int = 4) -> str:
    """A Markdown table with one row per method (``rows[name] = metrics``) and one column per key."""
    rows = dict(rows)
    if keys is None:
        keys = []
        for m in rows.values():
            keys += [k for k in m if k not in keys]
    keys = list(keys)
    lines = ["| method | " + " | ".join(keys) + " |", "| --- |" + " ---: |" * len(keys)]
    for name, m in rows.items():
        cells = []
        for k in keys:
            v = m.get(k)
            cells.append("–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
