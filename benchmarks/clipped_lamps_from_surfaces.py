"""Can the surfaces a clipped lamp lights tell its radiance? One-bounce radiosity on the predicted room.

Each HDR panorama is photographed by the evaluation's camera (``phyir.learn.camera.ldr_copy``);
GMNet predicts depth, normals and base colour from the 8-bit copy. Every unclipped surface point x
must satisfy L(x) = ρ/π · (E_seen(x) + Σ_j L_j g_j(x)): E_seen is the irradiance from every unclipped
pixel of the room (their radiance is known: the panorama shows it, interreflections included), g_j
the form factor of clipped region j (its pixels placed in 3D by the depth; visibility is ignored).
With a constant albedo ρ (or K times GMNet's base colour at the point, ``xK``) the unknown radiances
L_j (at least the 8-bit value) are fitted to all points by an L1 loss in log space.

Printed per split of ``hdri-indoor`` (its README) and for a folder such as ``../shared/panos``: the
share of clipped regions (>= 1e-4 sr) within 2x of their true mean luminance, their median ratio,
and the clipped energy recovered / true per room. ``regions`` is the shipped
:class:`phyir.lighting.clip_regions.RegionModel` on the same regions, ``both`` the geometric mean of
it and ``surfaces ρ=x1``. Nothing is fitted: both splits are measurements.

    python -m benchmarks.clipped_lamps_from_surfaces --hdri ../shared/hdri-indoor --panos ../shared/panos
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import torch
import torch.nn.functional as F

from phyir import pano
from phyir.color import luminance
from phyir.inference import predict
from phyir.io import load_panorama
from phyir.learn.camera import ldr_copy
from phyir.learn.ldr_pairs import hdr_files
from phyir.lighting.clip_regions import RegionModel, region_means
from phyir.lighting.hdr_recovery import clipped_regions, recover_clipped

SIZE = (64, 128)  # the radiosity grid
POINTS = 3000  # surface points fitted
MIN_REGION_SR = 1e-4  # as phyir eval --ldr-light counts regions
NEAR = 0.15  # form factors are clamped at this fraction of the median depth (no 1/r² blow-up)
ALBEDOS = (0.3, 0.5, 0.8, "x1", "x1.5")  # "xK": K times GMNet's base colour at the point


def room_grid(ldr: torch.Tensor) -> dict[str, torch.Tensor]:
    """Points, normals, area elements and the unclipped radiance of the room on the SIZE grid."""
    h, w = SIZE
    scene = predict(ldr, outputs=("depth", "normal", "albedo"), probes=None, hdr=False)
    depth = pano.resize_area(scene.depth.float(), h, w)[0]
    normal = F.normalize(pano.resize_area(scene.normal.float(), h, w), dim=0)
    dirs = pano.directions(h, w)
    facing = (-(dirs * normal).sum(0)).clamp_min(0.2)
    return {"P": (dirs * depth).reshape(3, -1).T, "N": normal.reshape(3, -1).T,
            "dA": (pano.solid_angles(h, w) * depth ** 2 / facing).reshape(-1),
            "albedo": luminance(pano.resize_area(scene.albedo.float(), h, w)).reshape(-1).clamp(0.03, 0.95)}


def form_factors(grid: dict[str, torch.Tensor], points: torch.Tensor) -> torch.Tensor:
    """[points, pixels]: cos·cos/r² · dA, clamped near. No visibility: marching every pair through
    the depth panorama (12 steps) took 20x as long and moved no figure on ../shared/panos by more
    than 0.02 in regions within 2x or 0.3 in a room's energy."""
    P, N = grid["P"], grid["N"]
    v = P[None] - P[points][:, None]
    r2 = (v * v).sum(-1)
    r = r2.sqrt().clamp_min(1e-6)
    near = NEAR * float(P.norm(dim=1).median())
    cos_x = ((N[points][:, None] * v).sum(-1) / r).clamp_min(0)
    cos_p = (-(N[None] * v).sum(-1) / r).clamp_min(0)
    return cos_x * cos_p / r2.clamp_min(near ** 2) * grid["dA"][None]


def fit_radiances(ldr: torch.Tensor, labels: torch.Tensor, n: int, floor: torch.Tensor,
                  grid: dict[str, torch.Tensor], albedo: float | str) -> torch.Tensor:
    """[n] radiance of each clipped region (at least ``floor``) that best explains the surfaces."""
    h, w = SIZE
    seen = (labels < 0).float()
    cover_seen = pano.resize_area(seen[None], h, w)[0].reshape(-1)
    radiance = (pano.resize_area((luminance(ldr) * seen)[None], h, w)[0].reshape(-1)
                / cover_seen.clamp_min(1e-6))
    cover = torch.stack([pano.resize_area((labels == j)[None].float(), h, w)[0].reshape(-1)
                         for j in range(n)])
    candidates = torch.nonzero((cover_seen > 0.95) & (radiance > 1e-3)).squeeze(1)
    points = candidates[torch.randperm(len(candidates), generator=torch.Generator().manual_seed(0))[:POINTS]]
    K = form_factors(grid, points)
    e_seen, g = K @ (radiance * cover_seen), K @ cover.T
    rho = grid["albedo"][points] * float(albedo[1:]) if isinstance(albedo, str) else albedo
    target = torch.log(math.pi * radiance[points] / rho)
    lo = floor.float().clamp_min(1e-6)
    log_l = torch.log(lo * 10).requires_grad_(True)
    opt = torch.optim.Adam([log_l], lr=0.1)
    for _ in range(300):
        e = e_seen + g @ torch.maximum(torch.exp(log_l), lo)
        loss = (torch.log(e.clamp_min(1e-9)) - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return torch.maximum(torch.exp(log_l.detach()), lo)


def room_rows(path: Path) -> dict[str, tuple[list[float], float]] | None:
    """{method: (each big region's recovered / true mean luminance, clipped energy recovered / true)}."""
    hdr = torch.nan_to_num(load_panorama(path).float(), nan=0.0, posinf=0.0).clamp_min(0)
    ldr, s = ldr_copy(hdr)
    clipped, labels, n = clipped_regions(ldr)
    if n == 0:
        return None
    lum = luminance(ldr)
    area, (mean_ldr, mean_true) = region_means(labels, n, lum, luminance(hdr * s))
    big = area >= MIN_REGION_SR
    grid = room_grid(ldr)
    methods = {f"surfaces ρ={a}": fit_radiances(ldr, labels, n, mean_ldr, grid, a).double() for a in ALBEDOS}
    model = RegionModel.load()
    if model is not None:  # what phyir predict does: the recovered panorama's mean over each region
        _, (mean_rec,) = region_means(labels, n, luminance(recover_clipped(ldr, model=model)[0]))
        methods["regions"] = mean_rec
        methods["both"] = torch.sqrt(methods["regions"] * methods["surfaces ρ=x1"])
    true_energy = float((area * mean_true).sum())
    return {k: ((L / mean_true.clamp_min(1e-30))[big].tolist(), float((area * L).sum()) / true_energy)
            for k, L in methods.items()}


def summary(rooms: list[dict[str, tuple[list[float], float]]], method: str) -> str:
    ratios = [r for room in rooms for r in room[method][0] if r > 0]
    energy = [room[method][1] for room in rooms]
    within = sum(0.5 <= r <= 2 for r in ratios) / max(len(ratios), 1)
    return (f"{method:<16} regions within 2x {within:4.0%} of {len(ratios):3d}, median ratio "
            f"{math.exp(statistics.median(math.log(r) for r in ratios)):.2f}; clipped energy "
            f"{min(energy):.2f}-{max(energy):.2f} (median {statistics.median(energy):.2f}), "
            f"{sum(0.6 <= e <= 1.6 for e in energy)}/{len(energy)} rooms within 0.6-1.6")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hdri", type=Path, help="hdri-indoor (both splits are measured, nothing is fitted)")
    ap.add_argument("--panos", type=Path, help="a folder of further HDR panoramas")
    a = ap.parse_args(argv)
    groups = {}
    if a.hdri:
        groups |= {"hdri-indoor training": hdr_files(a.hdri, "train"),
                   "hdri-indoor validation": hdr_files(a.hdri, "val")}
    if a.panos:
        groups[str(a.panos)] = sorted(p for p in a.panos.iterdir() if p.suffix.lower() in (".hdr", ".exr"))
    if not any(groups.values()):
        print("no panoramas (--hdri, --panos)", file=sys.stderr)
        return 2
    torch.manual_seed(0)
    for name, paths in groups.items():
        rooms = [r for r in map(room_rows, paths) if r is not None]
        print(f"{name}: {len(rooms)} rooms with clipped regions")
        for method in rooms[0]:
            print("  " + summary(rooms, method))
    return 0


if __name__ == "__main__":
    sys.exit(main())
