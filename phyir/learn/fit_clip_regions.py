"""Fit :class:`phyir.lighting.clip_regions.RegionModel` on real HDR panoramas.

Each panorama of the training split (:func:`phyir.learn.ldr_pairs.hdr_files`: the validation split
is never read) is photographed by the evaluation's camera (:func:`phyir.learn.camera.ldr_copy`:
median to 0.18, clipped, 8 bits) at each of :data:`EXPOSURES`; every clipped region gives its
features and the true mean luminance of its white core (where all three channels clipped) over the
copy's median. A ridge regression of the log of that on the features, each region weighted by its
core's solid angle (the big ones hold the energy), gives the model; a second, each region counted
once, fitted on the regions under :data:`SMALL_BELOW_SR`, gives their law (most clipped regions are
small and barely above the clip). The partly clipped pixels' ``partial_gain`` is their true energy
over what :func:`phyir.lighting.clip_regions.fill_partial` gives them, summed over the panoramas.
``--add`` fits on more HDR panoramas besides the training split (:func:`panorama_files`).

    python -m phyir.learn.fit_clip_regions --hdri ../shared/hdri-indoor --out phyir/assets/clip_regions.json
    python -m phyir.learn.fit_clip_regions --hdri ../shared/hdri-indoor --jpeg 90 \
        --out phyir/assets/clip_regions_jpeg.json
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.learn.camera import jpeg_linear, ldr_copy
from phyir.lighting.clip_regions import (
    FEATURES,
    RegionModel,
    fill_partial,
    panorama_median,
    partly_clipped,
    region_features,
    region_means,
    white_pixels,
)
from phyir.lighting.hdr_recovery import CLIP_LEVEL, clipped_regions, white_cores

# the evaluation camera's exposure and four others: the same lamps clipped at other levels, and more
# walls and windows barely over the clip, which the law must learn to leave nearly as they are
EXPOSURES = (0.25, 0.5, 1.0, 2.0, 4.0)
RIDGE = 30.0  # on standardised features
SMALL_BELOW_SR = 0.03  # regions under this solid angle get the law fitted by count (RegionModel)


def region_samples(ldr: Tensor, truth: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """(features [n,F], log(true mean luminance of the white core / median) [n], the core's solid
    angle [n]) of the clipped regions of an 8-bit copy ``ldr [3,H,W]`` of ``truth`` (the HDR in the
    copy's units); regions without a white core are left out."""
    clipped, labels, n = clipped_regions(ldr)
    if n == 0:
        return torch.zeros(0, len(FEATURES), dtype=torch.float64), torch.zeros(0, dtype=torch.float64), \
            torch.zeros(0, dtype=torch.float64)
    lum = luminance(ldr)
    med, white = panorama_median(lum), white_pixels(ldr, CLIP_LEVEL, clipped)
    feats = region_features(ldr, clipped, labels, n, CLIP_LEVEL, lum, white=white, median=med)
    area, (true,) = region_means(white_cores(ldr, labels, white=white), n, luminance(truth))
    keep = area > 0
    return feats[keep], torch.log(true[keep] / med), area[keep]


def partial_energy(ldr: Tensor, truth: Tensor) -> tuple[float, float]:
    """(true, :func:`fill_partial`'s) luminous energy of the partly clipped pixels of ``ldr``."""
    partial = partly_clipped(ldr, CLIP_LEVEL)
    H, W = ldr.shape[-2:]
    omega = (pano.solid_angles(H, 1) / W).expand(H, W)[partial]
    true = float((luminance(truth)[partial] * omega).sum())
    return true, float((luminance(fill_partial(ldr, CLIP_LEVEL))[partial] * omega).sum())


def fit(X: Tensor, y: Tensor, weight: Tensor, ridge: float = RIDGE) -> tuple[float, tuple[float, ...]]:
    """Weighted ridge regression on standardised features (the intercept not penalised), returned
    for the raw features: (intercept, coefficients)."""
    X = X.double()
    mu, sd = X.mean(0), X.std(0).clamp_min(1e-9)
    A = torch.cat((torch.ones(len(X), 1, dtype=torch.float64), (X - mu) / sd), 1)
    sw = torch.sqrt(weight / weight.mean())[:, None]
    reg = ridge * torch.eye(A.shape[1], dtype=torch.float64)
    reg[0, 0] = 0
    beta = torch.linalg.solve((A * sw).T @ (A * sw) + reg, (A * sw).T @ (y.double()[:, None] * sw))[:, 0]
    coef = beta[1:] / sd
    return float(beta[0] - (coef * mu).sum()), tuple(float(b) for b in coef)


@dataclass(frozen=True)
class PanoramaSamples:
    """What one panorama gives the fit: its copies' region rows (:func:`region_samples`, stacked) and
    the true and :func:`fill_partial`'s energy of their partly clipped pixels."""

    name: str
    features: Tensor  # [n, F]
    log_luminance: Tensor  # [n]
    core_sr: Tensor  # [n]
    partial: tuple[float, float]


def panorama_samples(path: Path, exposures: tuple[float, ...] = EXPOSURES,
                     jpeg: int | None = None) -> PanoramaSamples:
    """``path`` photographed at each of ``exposures``; with ``jpeg``, each copy also through a JPEG
    encoder at that quality (the law for JPEG input: its ringing and chroma subsampling change what a
    region's surroundings look like). The partly clipped pixels' energies come from the copies as
    they are either way (in a JPEG, most of them are a white core's fringe, which the law covers)."""
    from phyir.io import load_panorama

    hdr = torch.nan_to_num(load_panorama(path).float(), nan=0.0, posinf=0.0).clamp_min(0)
    X, y, w = [], [], []
    partial = torch.zeros(2, dtype=torch.float64)
    for e in exposures:  # each exposure photographs the panorama once
        ldr, s = ldr_copy(hdr, e)
        partial += torch.tensor(partial_energy(ldr, hdr * s), dtype=torch.float64)
        for copy in (ldr,) if jpeg is None else (ldr, jpeg_linear(ldr, jpeg)):
            f, t, a = region_samples(copy, hdr * s)
            X.append(f), y.append(t), w.append(a)
    return PanoramaSamples(Path(path).name, torch.cat(X), torch.cat(y), torch.cat(w),
                           (float(partial[0]), float(partial[1])))


def fit_samples(samples: list[PanoramaSamples], ridge: float = RIDGE, small_below_sr: float = SMALL_BELOW_SR,
                jpeg: int | None = None) -> RegionModel:
    """The law fitted on the panoramas' samples (``jpeg``: the quality they were taken through, as
    the model records it)."""
    X = torch.cat([s.features for s in samples])
    y = torch.cat([s.log_luminance for s in samples])
    w = torch.cat([s.core_sr for s in samples])
    intercept, coef = fit(X, y, w, ridge)
    small = X[:, FEATURES.index("log_area")] < math.log(small_below_sr)  # as RegionModel splits them
    small_intercept, small_coef = fit(X[small], y[small], torch.ones(int(small.sum()), dtype=torch.float64),
                                      ridge) if int(small.sum()) > len(FEATURES) else (0.0, ())
    true, filled = (sum(s.partial[i] for s in samples) for i in (0, 1))
    return RegionModel(intercept, coef, FEATURES, tuple(s.name for s in samples), len(y), ridge,
                       small_below_sr if small_coef else 0.0, small_intercept, small_coef,
                       true / filled if filled > 0 else 1.0, jpeg or 0)


def fit_model(paths: list[Path], exposures: tuple[float, ...] = EXPOSURES, ridge: float = RIDGE,
              small_below_sr: float = SMALL_BELOW_SR, jpeg: int | None = None) -> RegionModel:
    """The law fitted on ``paths``' copies at each of ``exposures`` (:func:`panorama_samples`)."""
    return fit_samples([panorama_samples(p, exposures, jpeg) for p in paths], ridge, small_below_sr, jpeg)


def panorama_files(paths: list[Path]) -> list[Path]:
    """The HDR panoramas that ``paths`` name: files as they are, folders' .hdr/.exr files (a ``phyir
    synth`` folder's rooms too). A missing path, a folder without panoramas or a panorama of the
    validation split (never fitted on) is an :class:`phyir.errors.InputError`."""
    from phyir.errors import InputError
    from phyir.io import folder_files
    from phyir.learn.ldr_pairs import HDR_SUFFIXES, is_validation

    out = []
    for p in map(Path, paths):
        if p.is_dir():
            found = [Path(f) for f in folder_files(p, HDR_SUFFIXES)]  # (never a temporary of a write)
            if not found:
                raise InputError(p, "no .hdr or .exr panoramas in this folder")
        elif p.is_file():
            found = [p]
        else:
            raise InputError(p, "no such file or folder")
        for f in found:
            if is_validation(f):
                raise InputError(f, "is in the validation split of hdri-indoor, which is never fitted on")
        out += found
    return out


def main(argv: list[str] | None = None) -> int:
    from phyir.errors import InputError
    from phyir.learn.ldr_pairs import hdr_files

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hdri", type=Path, required=True,
                    help="folder of real HDR panoramas (its training split is read)")
    ap.add_argument("--out", type=Path, required=True, help="the model's JSON file")
    ap.add_argument("--add", nargs="+", type=Path, default=[], metavar="FILE|DIR",
                    help="more HDR panoramas to fit on besides the training split (files or folders)")
    ap.add_argument("--jpeg", type=int, metavar="Q",
                    help="fit the law for JPEG input: each copy also through a JPEG encoder at quality Q")
    a = ap.parse_args(argv)
    if a.jpeg is not None and not 1 <= a.jpeg <= 100:
        print(f"--jpeg: a JPEG quality is 1-100, not {a.jpeg}", file=sys.stderr)
        return 2
    paths = hdr_files(a.hdri, "train")
    if not paths:
        print(f"{a.hdri}: no HDR panoramas in its training split", file=sys.stderr)
        return 2
    try:
        paths += panorama_files(a.add)
    except InputError as e:
        print(f"--add: {e}", file=sys.stderr)
        return 2
    model = fit_model(paths, jpeg=a.jpeg)
    model.save(a.out)
    terms = " ".join(f"{c:+.3f}·{f}" for c, f in zip(model.coef, model.features))
    small = " ".join(f"{c:+.3f}·{f}" for c, f in zip(model.small_coef, model.features))
    print(f"{a.out}: {model.regions} regions of {len(paths)} panoramas: log(L/median) = "
          f"{model.intercept:.3f} {terms}; under {model.small_below_sr} sr: "
          f"{model.small_intercept:.3f} {small}; partly clipped pixels x{model.partial_gain:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
