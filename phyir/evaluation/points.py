"""Light at free points of synthetic rooms against the path tracer (issue 20's synthetic check).

The real-panorama protocol (:mod:`phyir.evaluation.real_lighting`) can only hold the light we give a
point against the panorama itself, the light at the camera.  Here the truth is the light *at the
point*: probes path-traced there (:func:`phyir.synth.dataset.trace_probes_at`) in the room the scene
file came from, so the light away from the camera is checked too.

Points are drawn in the free space the camera sees, along random camera rays (solid-angle uniform,
|latitude| < 60°, lamps and windows left out) between 15 % and 85 % of the way to the surface and at
least :data:`MARGIN` from it; the first point is the real protocol's sphere centre when it is free.

The room is predicted twice, with ``phyir predict``'s default lighting (the fused probe grid, what users
get) and with ``lighting="lnet"`` (LNet's grid alone, the baseline): the :class:`Predictions`.
Methods (probes ``[N,3,h,w]`` at the truth's size), each ``name: callable(preds, gt, points, size)``:

* ``light_at``: :func:`phyir.lighting.at_point.light_at` on the predicted scene (what inserted
  objects get: the panorama projected from the point, the fused grid where the camera did not see);
* ``fused``: the probe grid ``phyir predict`` writes (fused) interpolated in 3D (:class:`ProbeField`);
* ``lnet``: the predicted LNet probe grid interpolated in 3D (LNet alone);
* ``projection``: the panorama projected through the predicted depth, LNet's grid probe where unseen;
* ``light_at_gt_geometry``: ``light_at`` through the true depth and normals (the fused grid where
  unseen): what is left is the projection's own error;
* ``panorama``: the camera's panorama as distant light.  This is the real protocol's *truth*, so its
  error here is what that protocol cannot see: the parallax between the camera and the point.

Metrics per method: ``probe_log_mse`` and ``relight_*`` (:mod:`phyir.evaluation.metrics`, as ``phyir eval``'s
lighting table), and the real protocol's sphere metrics for the diffuse and matte silver spheres
(``<material>.rel_l1`` / ``si_rel_l1`` / ``ratio`` / ``colour_deg``, the same brute-force integrator),
averaged over points.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.evaluation import metrics as M
from phyir.evaluation import real_lighting as RL
from phyir.scene import PanoScene

MARGIN = 0.3  # metres: a point is at least this far from the surface its camera ray meets
FRACTION = (0.15, 0.85)  # where along the camera ray (share of the depth) a point is drawn
TRUTH_SIZE = (32, 64)  # probe texels of the traced truth (5.6 degrees)
SPHERE_MATERIALS = ("diffuse", "matte_silver")  # the mirror needs the truth's full resolution


@dataclass(frozen=True)
class Predictions:
    """One room predicted with ``phyir predict``'s default lighting and with LNet's grid alone."""

    default: PanoScene  # what users get (the fused probe grid)
    lnet: PanoScene  # the same geometry, LNet's probe grid


PointMethod = Callable[[Predictions, PanoScene, Tensor, tuple[int, int]], Tensor]


def _on_prediction(method: RL.LightMethod, which: str = "default") -> PointMethod:
    """A real-protocol light method (:data:`phyir.evaluation.real_lighting.LIGHT_METHODS`) as a point
    method: it sees the predicted scene ``which`` (a :class:`Predictions` field) only."""
    return lambda preds, gt, pts, size: method(getattr(preds, which), pts, size)


def _light_at_gt_geometry(preds: Predictions, gt: PanoScene, pts: Tensor, size: tuple[int, int]) -> Tensor:
    geo = preds.default.replace(depth=gt.depth, normal=gt.normal)
    return RL.light_at_point(geo, pts, size)


def _panorama(preds: Predictions, gt: PanoScene, pts: Tensor, size: tuple[int, int]) -> Tensor:
    env = pano.resize_area(gt.image.float().clamp_min(0), *size)
    return env[None].expand(len(pts), -1, -1, -1)


POINT_METHODS: dict[str, PointMethod] = {
    "light_at": _on_prediction(RL.light_at_point),
    "fused": _on_prediction(RL.probe_field_light),
    "lnet": _on_prediction(RL.probe_field_light, "lnet"),
    "projection": _on_prediction(RL.projection_light, "lnet"),
    "light_at_gt_geometry": _light_at_gt_geometry,
    "panorama": _panorama,
}


def predict_both(gt: PanoScene, **predict_kwargs) -> Predictions:
    """:class:`Predictions` of the room ``gt`` from its image alone (every other layer dropped)."""
    from phyir.evaluation.synthetic import model_input
    from phyir.inference import predict

    image_only = model_input(gt)
    default = predict(image_only, **predict_kwargs)
    lnet = predict(image_only, lighting="lnet", **predict_kwargs)
    return Predictions(default, lnet)


def free_points(gt: PanoScene, count: int, seed: int = 0, margin: float = MARGIN) -> Tensor:
    """``count`` points ``[N,3]`` (camera frame, metres) in the free space ``gt``'s camera sees (see
    the module doc); fewer when the room has no room for them."""
    H, W = gt.size
    d = pano.directions(H, W).reshape(3, -1)
    depth = gt.depth[0].float().reshape(-1)
    lat = torch.asin(d[1].clamp(-1, 1))
    ok = (lat.abs() < math.radians(60)) & (depth * FRACTION[0] >= margin) \
        & (depth * (1 - FRACTION[1]) >= margin)
    em = gt.masks.get("emission")
    if em is not None:
        ok &= em[0].reshape(-1) < 0.5
    points = []
    c = torch.tensor(RL.SPHERE_CENTRE)
    u, v = pano.dir_to_uv(c / c.norm(), H, W, dim=0)
    at = int(v.clamp(0, H - 1)) * W + int(u.clamp(0, W - 1))
    if float(depth[at]) >= float(c.norm()) + margin:
        points.append(c)
    g = torch.Generator().manual_seed(int(seed))
    weight = pano.solid_angles(H, W).reshape(-1) * ok
    if count > len(points) and float(weight.sum()) > 0:
        idx = torch.multinomial(weight, count - len(points), replacement=True, generator=g)
        f = FRACTION[0] + (FRACTION[1] - FRACTION[0]) * torch.rand(len(idx), generator=g)
        points += list((d[:, idx] * (depth[idx] * f)).T)
    return torch.stack(points[:count]) if points else torch.zeros(0, 3)


def starts_at_protocol_point(points: Tensor) -> bool:
    """Whether :func:`free_points` put the real protocol's sphere centre first (it does where it is free)."""
    return len(points) > 0 and torch.equal(points[0], torch.tensor(RL.SPHERE_CENTRE))


def sphere_errors(probes: Tensor, truth: Tensor, points: Tensor) -> dict[str, float]:
    """The real protocol's sphere metrics (``<material>.<metric>``) of ``probes`` against ``truth``
    ``[N,3,h,w]`` at ``points``, each sphere seen from the camera, averaged over the points."""
    size = tuple(truth.shape[-2:])
    sums: dict[str, float] = {}
    for p, ours, true in zip(points, probes, truth):
        n, v, _ = RL.sphere_pixels(tuple(float(x) for x in p))
        envs = torch.stack([true.float(), RL.at_size(ours.float(), size)])
        for mat in SPHERE_MATERIALS:
            dif, spec = RL.integrate(envs, n, v, M.RELIGHT_MATERIALS[mat], size=size)
            px = dif + spec
            for k, val in RL.sphere_metrics(px[1], px[0]).items():
                sums[f"{mat}.{k}"] = sums.get(f"{mat}.{k}", 0.0) + val
    return {k: s / len(points) for k, s in sums.items()}


def method_probes(preds: Predictions, gt: PanoScene, points: Tensor, size: tuple[int, int],
                  methods: dict[str, PointMethod] | None = None) -> dict[str, Tensor]:
    """``{method: probes [N,3,h,w]}`` at ``points``, at ``size``, non-negative."""
    return {name: RL.at_size(fn(preds, gt, points, size).float(), size).clamp_min(0)
            for name, fn in (POINT_METHODS if methods is None else methods).items()}


def point_metrics(probes: dict[str, Tensor], truth: Tensor, points: Tensor, *, spp: int = 64
                  ) -> dict[str, dict[str, float]]:
    """``{method: metrics}`` of each method's ``probes`` against the traced ``truth [N,3,h,w]``."""
    from phyir.evaluation.synthetic import lighting_metrics

    return {name: lighting_metrics(p, truth, points, relight=len(points), spp=spp)
            | sphere_errors(p, truth, points) for name, p in probes.items()}


def evaluate_model_points(root: str | os.PathLike, split: str = "test", *, count: int = 8, weights=None,
                          model=None, device=None, limit: int | None = None, spp: int = 64, seed: int = 0,
                          log: Callable[[str], None] | None = None) -> dict[str, dict[str, float]]:
    """``{"points/<method>": metrics}``: the model on ``split``'s scenes, ``count`` free points each;
    ``"protocol/<method>"``: the same at the real protocol's sphere centre alone (where it is free), and
    ``"protocol_median/<method>"`` its medians over the scenes."""
    from phyir.io import load_scene
    from phyir.learn.datasets import split_files
    from phyir.synth.dataset import trace_probes_at

    meters: dict[str, M.MetricMeter] = {}
    files = split_files(Path(root), split, limit)
    for i, path in enumerate(files):
        t0 = time.perf_counter()
        gt = load_scene(path)
        preds = predict_both(gt, weights=weights, model=model, device=device)
        points = free_points(gt, count, seed * 1_000_003 + i)
        if not len(points):
            continue
        truth = trace_probes_at(gt, points, TRUTH_SIZE, seed=seed)
        probes = method_probes(preds, gt, points, TRUTH_SIZE)
        rows = {f"points/{k}": r for k, r in point_metrics(probes, truth, points, spp=spp).items()}
        if starts_at_protocol_point(points):  # the real protocol's point alone
            first = {k: p[:1] for k, p in probes.items()}
            one = point_metrics(first, truth[:1], points[:1], spp=spp)
            rows |= {f"protocol/{k}": r for k, r in one.items()}
        for k, r in rows.items():
            meters.setdefault(k, M.MetricMeter()).add(r)
        if log is not None:
            log(f"[{i + 1}/{len(files)}] {path.name}: {len(points)} points, "
                f"{time.perf_counter() - t0:.1f} s, "
                "diffuse rel L1 " + ", ".join(f"{m} {rows['points/' + m]['diffuse.rel_l1']:.3f}"
                                              for m in ("light_at", "fused", "lnet", "panorama")))
    out = {k: m.result() for k, m in meters.items()}
    # the real protocol states its bars as medians over rooms: the same here
    out |= {k.replace("protocol/", "protocol_median/"): _medians(m) for k, m in meters.items()
            if k.startswith("protocol/")}
    return out


def _medians(meter: M.MetricMeter) -> dict[str, float]:
    keys = {k for row in meter.scenes for k in row}
    return {k: statistics.median(r[k] for r in meter.scenes if k in r) for k in keys}


# the README's table of the light at points (``python -m benchmarks.points_table points.json``): its rows
# in order, (method, label) and (result prefix, where)
TABLE_METHODS = (("light_at", "`light_at` (ours)"), ("fused", "the fused probe grid (`phyir predict`)"),
                 ("lnet", "LNet alone (probe grid)"),
                 ("panorama", "the camera's panorama (the real protocol's truth)"),
                 ("light_at_gt_geometry", "`light_at` through the true depth"))
TABLE_PLACES = (("protocol_median", "protocol point"), ("points", "free points"))


def points_table(results: dict) -> list[str]:
    """The Markdown table (lines) of ``phyir eval --data --points --json``'s ``results``: a row per
    method and place found there, in the order of :data:`TABLE_PLACES` and :data:`TABLE_METHODS`."""
    out = ["| light at the point | where | diffuse rel L1 | diffuse ratio | diffuse colour "
           "| matte silver rel L1 | probe log-MSE | relight diffuse / matte / mirror |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for prefix, where in TABLE_PLACES:
        for method, label in TABLE_METHODS:
            r = results.get(f"{prefix}/{method}")
            if r is None:
                continue
            out.append(f"| {label} | {where} | {r['diffuse.rel_l1']:.3f} | {r['diffuse.ratio']:.2f} "
                       f"| {r['diffuse.colour_deg']:.1f}° | {r['matte_silver.rel_l1']:.3f} "
                       f"| {r['probe_log_mse']:.3f} | {r['relight_diffuse']:.4f} "
                       f"/ {r['relight_matte_silver']:.3f} / {r['relight_mirror_silver']:.3f} |")
    return out
