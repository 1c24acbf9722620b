"""Inference-time geometry priors against ground truth: do any of them beat predict's geometry?

GMNet's geometry on synthetic rooms is smooth where the rooms are boxes: its walls' normals turn
with longitude like a cylinder's, its depth has no corners (issue 19: AbsRel 0.267, normals 17°
against targets of 0.15 / 12°). Each variant below is a prior a layout method would add at
inference, applied to the network's outputs at 128x256 and followed by predict's own consistency
step (:func:`phyir.geometry.plausible.consistent_depth`):

* ``base``        — predict's geometry (GMNet, gravity snap, depth refinement, floor under camera);
* ``tta_mirror``  — GMNet on the input and its left-right mirror, averaged (log depth, normals);
* ``tta_shift``   — GMNet on the input rolled by 0, 8, 16, 24 columns (a quarter of the network's
  32-column stride: yaw shifts it is not exactly equivariant to), averaged;
* ``layout``      — the floor and ceiling planes at their median heights, and per column the wall
  distance where the floor (or ceiling) region ends; a pixel takes the layout candidate nearest
  the network's depth if within 25 %;
* ``manhattan``   — wall normals snapped to the room's four dominant horizontal directions, the yaw
  from the predicted normals (the angle of sum w exp(4i azimuth));
* ``manhattan_image`` — the same with the yaw of the panorama's horizontal edges (:func:`image_yaw`);
* ``manhattan_gt`` — the same with the ground truth's yaw (an upper bound for any estimate of it,
  e.g. from the image's vanishing points);
* ``height_prior`` — depth scaled so the camera stands 1.5 m above the floor (the generator's mean).

    python -m benchmarks.geometry_priors data/h128 0:30      # the issue's held-out rooms
    python -m benchmarks.geometry_priors data/n128 0:60      # the wider generator (halls, studios)

(data: ``phyir synth --out data/h128 --count 30 --seed 7000 --size 128x256 --probe-grid 16x32 --spp 8``;
``phyir synth --out data/n128 --count 160 --seed 20000 --size 128x256 --probe-grid 16x32 --spp 8``.)
Prints the mean depth AbsRel, δ<1.25 and normal mean error per variant, and in how many rooms
each beats ``base``.
"""

from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.color import exposure_scale, luminance
from phyir.evaluation import metrics as M
from phyir.evaluation.real import plausibility
from phyir.evaluation.synthetic import surface_mask
from phyir.geometry.plausible import consistent_depth, plausible_gmnet, unflip
from phyir.inference import load_cached_model
from phyir.io import load_scene
from phyir.scene import PanoScene
from phyir.transforms import mirror_lr, rotate_yaw

NET = (128, 256)
LAYOUT_TOL = 0.25  # a layout candidate replaces the network's depth within this relative distance
LEVEL = math.cos(math.radians(30))  # floor / ceiling region: normals within 30 degrees of up / down
CAMERA_HEIGHT = 1.5


def gmnet_under(model, x: Tensor, shift: int, mirror: bool, upside_down: bool) -> PanoScene:
    """GMNet's depth and normals for ``x [3,H,W]`` seen through a yaw shift and/or a mirror, mapped
    back to the input's frame (the same pass, upright or mirrored through the horizon, as predict)."""
    s = PanoScene(image=x)
    s = rotate_yaw(mirror_lr(s) if mirror else s, shift)
    inp = s.image.flip(-2) if upside_down else s.image
    out = {k: v.float() for k, v in model.gmnet(inp[None]).items()}
    if upside_down:
        out = unflip(out)
    o = rotate_yaw(PanoScene(image=s.image, depth=out["depth"][0], normal=out["normal"][0]), -shift)
    return mirror_lr(o) if mirror else o


def averaged(model, x: Tensor, views: list[tuple[int, bool]], upside_down: bool) -> tuple[Tensor, Tensor]:
    outs = [gmnet_under(model, x, s, m, upside_down) for s, m in views]
    depth = torch.exp(torch.stack([o.depth.log() for o in outs]).mean(0))
    normal = torch.nn.functional.normalize(torch.stack([o.normal for o in outs]).mean(0), dim=0)
    return depth[None], normal[None]


def layout_depth(depth: Tensor, normal: Tensor) -> Tensor:
    """``depth [1,1,H,W]`` replaced, where a Manhattan-free box layout agrees within LAYOUT_TOL, by it."""
    H, W = depth.shape[-2:]
    d = pano.directions(H, W)
    cos_lat = torch.cos(pano.pixel_lonlat(H, W)[1])
    D, ny = depth[0, 0], normal[0, 1]
    y = D * d[1]
    nan = torch.full_like(D, float("nan"))
    cands = []
    for region, plane_y in (((ny > LEVEL) & (d[1] < -0.05), -1.0), ((ny < -LEVEL) & (d[1] > 0.05), 1.0)):
        if int(region.sum()) < 20:
            continue
        height = (plane_y * y[region]).median()
        t = height / (plane_y * d[1]).clamp_min(1e-6)
        cands.append(torch.where(plane_y * d[1] > 0, t, nan))
        # per column, the region's run from the pole: the wall starts where it ends
        rows = torch.arange(H)[:, None].expand(H, W)
        scan = region.flip(0) if plane_y < 0 else region  # row 0 of scan: the pole
        run = torch.where(scan, torch.full_like(rows, H), rows).min(0).values  # run length per column
        edge = (H - run if plane_y < 0 else run - 1).clamp(0, H - 1)
        r = (t * cos_lat).gather(0, edge[None])[0]
        r = torch.where(run > 0, r, torch.full_like(r, float("nan")))
        cands.append(r[None, :] / cos_lat)
    if not cands:
        return depth
    C = torch.stack(cands)
    err = torch.nan_to_num((C.log() - D.log()[None]).abs(), nan=1e9)
    best = err.argmin(0, keepdim=True)
    use = err.gather(0, best)[0] < math.log(1 + LAYOUT_TOL)
    return torch.where(use, C.gather(0, best)[0], D)[None, None]


def manhattan_votes(normal: Tensor) -> tuple[float, float]:
    """(yaw, concentration) of a room's four wall directions from normals ``[3,H,W]``: plumb normals
    vote with exp(4i azimuth); the concentration is the length of the mean vote (1: four directions)."""
    w = (normal[1].abs() < 0.05).float()
    a = torch.atan2(normal[0], normal[2])
    c, s = (w * torch.cos(4 * a)).sum(), (w * torch.sin(4 * a)).sum()
    return float(torch.atan2(s, c)) / 4, float(torch.hypot(c, s) / w.sum().clamp_min(1))


def manhattan_yaw(normal: Tensor) -> float:
    return manhattan_votes(normal)[0]


def image_yaw(image: Tensor, rows: int = 256) -> float:
    """The yaw of a room's horizontal edges from the panorama ``[3,H,W]`` alone: each strong gradient
    pixel's edge lies on a great circle whose normal m is perpendicular to the 3D line's direction
    (sin a, 0, cos a), so it votes for a = atan2(-m_z, m_x); the peak of the votes modulo 90°."""
    x = pano.resize_area(image.float(), rows, 2 * rows)
    lum = torch.log(luminance(x).clamp_min(1e-4))
    d = pano.directions(rows, 2 * rows)
    gu = (torch.roll(lum, -1, 1) - torch.roll(lum, 1, 1)) / 2
    gv = torch.zeros_like(lum)
    gv[1:-1] = (lum[2:] - lum[:-2]) / 2
    du = (torch.roll(d, -1, 2) - torch.roll(d, 1, 2)) / 2
    dv = torch.zeros_like(d)
    dv[:, 1:-1] = (d[:, 2:] - d[:, :-2]) / 2
    m = torch.nn.functional.normalize(torch.cross(d, -gv * du + gu * dv, dim=0), dim=0)
    g = torch.hypot(gu, gv)
    w = g * torch.hypot(m[0], m[2]) * (m[1].abs() > 0.2) * (g > g.flatten().quantile(0.8))  # no verticals
    a = torch.rad2deg(torch.atan2(-m[2], m[0])) % 90
    hist = torch.zeros(90).index_add_(0, a.long().clamp(0, 89).flatten(), w.flatten())
    hist = sum(c * torch.roll(hist, k) for k, c in zip(range(-2, 3), (1, 4, 6, 4, 1)))
    return math.radians(int(hist.argmax()) + 0.5)


def yaw_error_deg(a: float, b: float) -> float:
    x = (a - b) % (math.pi / 2)
    return math.degrees(min(x, math.pi / 2 - x))


def manhattan(normal: Tensor, yaw: float) -> Tensor:
    """Plumb normals ``[1,3,H,W]`` turned onto the nearest of the four directions yaw + k 90°."""
    n = normal[0]
    a = torch.atan2(n[0], n[2])
    snapped = yaw + torch.round((a - yaw) / (math.pi / 2)) * (math.pi / 2)
    plumb = n[1].abs() < math.sin(math.radians(5))
    out = torch.stack([torch.where(plumb, torch.sin(snapped), n[0]), torch.where(plumb, 0.0, n[1]),
                       torch.where(plumb, torch.cos(snapped), n[2])])
    return out[None]


def camera_height(depth: Tensor, normal: Tensor) -> float:
    """The camera's height above the floor by ``phyir eval --real``'s definition (the median of -y over the
    nadir cap; :func:`phyir.evaluation.real.plausibility`) of ``depth [1,1,H,W]``, ``normal [1,3,H,W]``."""
    scene = PanoScene(image=torch.zeros(3, *depth.shape[-2:]), depth=depth[0], normal=normal[0])
    return plausibility(scene)["camera_height"]


def variants(model, x: Tensor, gt: PanoScene) -> dict[str, tuple[Tensor, Tensor]]:
    """depth [1,1,H,W] and normals [1,3,H,W] of every variant, after predict's consistency step."""
    gm, kind = plausible_gmnet(model.gmnet, x[None])
    flip = kind == "mirrored"
    raw = {"base": (gm["depth"].float(), gm["normal"].float()),
           "tta_mirror": averaged(model, x, [(0, False), (0, True)], flip),
           "tta_shift": averaged(model, x, [(s, False) for s in (0, 8, 16, 24)], flip)}
    out = {k: consistent(*v) for k, v in raw.items()}
    d, n = out["base"]
    out["layout"] = consistent(layout_depth(d, n), n)
    out["manhattan"] = consistent(raw["base"][0], manhattan(n, manhattan_yaw(n[0])))
    out["manhattan_image"] = consistent(raw["base"][0], manhattan(n, image_yaw(gt.image)))
    out["manhattan_gt"] = consistent(raw["base"][0], manhattan(n, manhattan_yaw(gt.normal)))
    out["height_prior"] = (d * (CAMERA_HEIGHT / camera_height(d, n)), n)
    return out


def consistent(depth: Tensor, normal: Tensor) -> tuple[Tensor, Tensor]:
    d, n, _ = consistent_depth(depth, normal)
    return d, (n if n is not None else normal)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("range", nargs="?", default="0:30", help="START:STOP of the sorted scene files")
    args = ap.parse_args()
    a, b = (int(v) for v in args.range.split(":"))
    files = sorted(args.data.glob("scene_*.exr"))[a:b]
    model, _ = load_cached_model(None, "cpu")
    rows: dict[str, list[tuple[float, float, float]]] = {}
    yaw_errors, concentrations, height_errors = [], [], []
    for f in files:
        gt = load_scene(f)
        x = pano.resize_area(gt.image.float(), *NET)
        x = x * float(exposure_scale(x))
        g_depth, g_normal = pano.resize_area(gt.depth, *NET), pano.resize_area(gt.normal, *NET)
        mask = surface_mask(gt)
        mask = None if mask is None else pano.resize_area(mask, *NET)
        with torch.inference_mode():
            results = variants(model, x, gt)
        yaw_errors.append(yaw_error_deg(image_yaw(gt.image), manhattan_yaw(gt.normal)))
        concentrations.append((manhattan_votes(results["base"][1][0])[1], manhattan_votes(g_normal)[1]))
        true_height = camera_height(g_depth[None], g_normal[None])
        height_errors.append((math.log(camera_height(*results["base"]) / true_height),
                              math.log(CAMERA_HEIGHT / true_height)))
        for name, (d, n) in results.items():
            dm = M.depth_metrics(d[0], g_depth)
            rows.setdefault(name, []).append((dm["abs_rel"], dm["delta1"],
                                              M.normal_metrics(n[0], g_normal, mask)["mean"]))
        print(f.name, " ".join(f"{k} {v[-1][0]:.3f}/{v[-1][2]:.1f}" for k, v in rows.items()), flush=True)
    base = rows["base"]
    print(f"\n{len(files)} rooms of {args.data}: mean AbsRel, δ<1.25, normal mean (°); "
          "rooms whose depth beats base")
    for name, r in rows.items():
        means = [statistics.mean(v[i] for v in r) for i in range(3)]
        wins = sum(v[0] < w[0] for v, w in zip(r, base))
        print(f"{name:15s} {means[0]:.4f} {means[1]:.4f} {means[2]:6.2f}   depth better in {wins}/{len(r)}")
    print(f"image yaw vs the truth's: median {statistics.median(yaw_errors):.1f}°, "
          f"over 5° in {sum(e > 5 for e in yaw_errors)} of {len(yaw_errors)} rooms")
    for what, i in (("predicted", 0), ("true", 1)):
        c = sorted(v[i] for v in concentrations)
        print(f"concentration of the {what} normals on four wall directions: {c[0]:.2f}-{c[-1]:.2f}")
    print("camera height, standard deviation of the log error: the network's "
          f"{statistics.pstdev(v[0] for v in height_errors):.2f}, a fixed {CAMERA_HEIGHT} m "
          f"{statistics.pstdev(v[1] for v in height_errors):.2f}")


if __name__ == "__main__":
    main()
