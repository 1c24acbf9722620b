"""Calibration of HDR recovery from LDR (phyir.lighting.hdr_recovery) on path-traced synthetic rooms.

Each HDR room is auto-exposed (median luminance -> 0.18), clipped and quantised to 8 bits as a camera
would; every clipped region (as :func:`phyir.lighting.hdr_recovery.clipped_regions` finds it) is paired
with its true mean luminance, relative to the LDR copy's median. Prints the statistics and the
recommended ``GAIN``: the median over clipped solid angle (a typical clipped steradian; robust to the
few very bright lamps that dominate the mean), and the log-linear fit against the region's solid angle
(``AREA_EXPONENT``; its residual says how little the area tells).

    phyir synth --out data/h128 --count 40 --seed 7000 --size 128x256 --probe-grid 16x32 --spp 8
    python -m benchmarks.ldr_clip_calibration data/h128
    python -m benchmarks.ldr_clip_calibration HDR...   # real panoramas, e.g. hdri-indoor's training split
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from phyir import io, pano
from phyir.color import luminance
from phyir.learn.camera import ldr_copy
from phyir.lighting.hdr_recovery import clipped_regions


def regions(hdr: torch.Tensor) -> list[tuple[float, float]]:
    """(solid angle, true mean luminance / LDR median) of each clipped region of the LDR copy."""
    ldr, s = ldr_copy(hdr)
    H, W = hdr.shape[-2:]
    _, labels, n = clipped_regions(ldr)
    omega = pano.solid_angles(H, W)
    lum = luminance(hdr * s)
    med = max(float(luminance(ldr).median()), 1e-6)
    out = []
    for k in range(n):
        m = labels == k
        area = float(omega[m].sum())
        if area > 0:
            out.append((area, float((lum[m] * omega[m]).sum()) / area / med))
    return out


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, nargs="+",
                    help="folder of synthetic scene files (phyir synth), or HDR panorama files")
    a = ap.parse_args(argv)
    files = [f for d in a.data for f in (sorted(d.glob("*.exr")) if d.is_dir() else [d])]
    if not files:
        print(f"{' '.join(map(str, a.data))}: no scene files", file=sys.stderr)
        return 2
    rows = np.array([r for f in files for r in regions(io.load_panorama(f))])
    area, rel = rows[:, 0], rows[:, 1]
    slope, icpt = np.polyfit(np.log(area), np.log(rel), 1)
    resid = np.std(np.log(rel) - (icpt + slope * np.log(area)))
    print(f"{len(files)} rooms, {len(rows)} clipped regions, {area.sum():.3g} sr")
    print(f"L/median: median {np.median(rel):.2f}, over solid angle {weighted_median(rel, area):.2f}, "
          f"mean over solid angle {np.average(rel, weights=area):.2f}")
    print(f"log-linear in the area: L/median = {np.exp(icpt):.2f} A^{slope:.2f} "
          f"(residual sd {resid:.2f} in log)")
    print(f"GAIN = {weighted_median(rel, area):.2f}  AREA_EXPONENT = 0.0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
