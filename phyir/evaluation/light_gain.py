"""Where does the light at a point gain or lose against the camera?  Per region of directions, the
share of the diffuse protocol sphere's brightness (``phyir eval --real``'s sphere,
:mod:`phyir.evaluation.real_lighting`, seen from the camera) that the light at the camera and the
light at the point (:class:`phyir.lighting.at_point.LightAtPoint`) give it, both relative to the
camera's total: a region whose share grows is where the parallax through the predicted depth brings
light nearer.  ``python -m benchmarks.light_at_gain SCENE [--point x,y,z]`` prints :func:`report`.
"""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.color import luminance
from phyir.evaluation import real_lighting as RL
from phyir.evaluation.real import ZENITH_LAT, plausibility
from phyir.lighting.at_point import LightAtPoint
from phyir.scene import PanoScene

SIZE = (32, 64)
BANDS = (("up", 30, 90), ("horizon", -30, 30), ("down", -90, -30))  # latitude, degrees
QUARTERS = (("front (-z)", 0), ("right (+x)", 90), ("back (+z)", 180), ("left (-x)", 270))  # azimuth centre
MIN_DISTANCE = 0.05  # metres from the camera: nearer, the camera would be inside the sphere


def sphere_kernel(point: tuple[float, float, float], size: tuple[int, int] = SIZE) -> torch.Tensor:
    """``[h*w]``: how much each texel's radiance adds to the mean of the diffuse sphere at ``point`` as
    the camera sees it (the cosine of each visible sphere normal, averaged, times the solid angle)."""
    n, _, _ = RL.sphere_pixels(point)
    d = pano.directions(*size, dtype=torch.float64).reshape(3, -1)
    return (n @ d).clamp_min(0).mean(0) * pano.solid_angles(*size, dtype=torch.float64).reshape(-1)


def region_masks(size: tuple[int, int] = SIZE) -> dict[str, torch.Tensor]:
    """``{"<band> <quarter>": [h*w] bool}`` of the texel directions."""
    d = pano.directions(*size, dtype=torch.float64).reshape(3, -1)
    lat = torch.rad2deg(torch.asin(d[1].clamp(-1, 1)))
    az = torch.rad2deg(torch.atan2(d[0], -d[2])) % 360  # 0 = -z (forward), 90 = +x
    out = {}
    for band, lo, hi in BANDS:
        for quarter, centre in QUARTERS:
            off = (az - centre + 180) % 360 - 180
            out[f"{band} {quarter}"] = (lat >= lo) & (lat < hi) & (off.abs() < 45)
    return out


def ceiling_height(scene: PanoScene) -> float:
    """Median height above the camera (m) of the predicted points above ``ZENITH_LAT`` (where
    ``phyir eval --real`` expects the ceiling)."""
    H, W = scene.size
    y = pano.depth_to_points(scene.depth.double())[1]
    lat = 90 - (torch.arange(H, dtype=torch.float64) + 0.5) * 180 / H
    return float(y[lat > ZENITH_LAT].median())


def check_point(point: tuple[float, ...]) -> None:
    """ValueError with the reason unless ``point`` (metres, camera frame) is a place the sphere can
    stand: three finite numbers, at least :data:`MIN_DISTANCE` from the camera."""
    if len(point) != 3 or not all(math.isfinite(c) for c in point):
        raise ValueError("expected three numbers x,y,z")
    if math.hypot(*point) < MIN_DISTANCE:
        raise ValueError("the camera would be inside the sphere; give a point >= 5 cm away")


def report(scene: PanoScene, point: tuple[float, float, float], name: str) -> list[str]:
    """The lines of the report on ``scene`` (named ``name``) at ``point``: the sphere's brightness under
    the light at the point against the light at the camera, the predicted room's floor and ceiling, and
    a Markdown table of each region's share at the camera and at the point."""
    probes = LightAtPoint(scene, SIZE).probes_at(torch.tensor([point, (0.0, 0.0, 0.0)]))
    k = sphere_kernel(point)
    at_point, at_camera = (luminance(p.double()).reshape(-1) * k for p in probes)
    total = float(at_camera.sum())
    floor, ceiling = plausibility(scene)["camera_height"], ceiling_height(scene)
    out = [f"{name}: the diffuse sphere at {point} is {float(at_point.sum()) / total:.2f}x as bright "
           "as under the light at the camera",
           f"the predicted room: floor {floor:.2f} m below the camera, ceiling {ceiling:.2f} m above "
           "(medians below and above the camera)",
           "| directions | share at the camera | share at the point |",
           "| --- | ---: | ---: |"]
    for region, m in region_masks().items():
        cam, pt = (float(x[m].sum()) / total for x in (at_camera, at_point))
        out.append(f"| {region} | {cam:.3f} | {pt:.3f} |")
    return out
