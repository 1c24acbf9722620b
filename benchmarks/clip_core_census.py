"""How bright the clipped white cores of real panoramas are, split by split.

Each panorama is photographed by the evaluation's camera (:func:`phyir.learn.camera.ldr_copy`,
exposure 1) and each clipped region's white core measured against the truth
(:func:`phyir.learn.fit_clip_regions.panorama_samples`): the brightest core (its mean luminance over
the copy's median), the brightest of the cores of :data:`BIG_SR` or more (the big regions that
hold most rooms' clipped light) and the share of the cores' light held by cores above
:data:`BRIGHT` times the median. What the region model can learn is bounded by the cores of the
training split; this says which rooms ask for more than that split holds.

    python -m benchmarks.clip_core_census --hdri ../shared/hdri-indoor --panos ../shared/panos \
        [--add FILE|DIR ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from phyir.errors import InputError
from phyir.io import folder_files
from phyir.learn.fit_clip_regions import panorama_files, panorama_samples
from phyir.learn.ldr_pairs import HDR_SUFFIXES, hdr_files

BRIGHT = 500.0  # x the median: brighter than all but one training room's cores
BIG_SR = 0.1  # steradians


def census(path: Path) -> tuple[int, float, float, float]:
    """(white cores, the brightest's luminance / median, the brightest of BIG_SR or more, the share
    of the cores' light in those above BRIGHT x the median) of one panorama's evaluation copy."""
    s = panorama_samples(path, exposures=(1.0,))
    if not len(s.log_luminance):
        return 0, 0.0, 0.0, 0.0
    luminance = torch.exp(s.log_luminance)
    light = s.core_sr * luminance
    big = luminance[s.core_sr >= BIG_SR]
    bright = float(light[luminance > BRIGHT].sum() / light.sum())
    return len(light), float(luminance.max()), float(big.max()) if len(big) else 0.0, bright


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hdri", type=Path, required=True, help="folder of real HDR panoramas (hdri-indoor)")
    ap.add_argument("--panos", type=Path, help="more panoramas, evaluation only")
    ap.add_argument("--add", nargs="+", type=Path, default=[], metavar="FILE|DIR",
                    help="panoramas one might add to the fit (fit_clip_regions --add)")
    a = ap.parse_args(argv)
    splits = {"training": hdr_files(a.hdri, "train"), "validation": hdr_files(a.hdri, "val")}
    if a.panos:
        splits["panos"] = [Path(f) for f in folder_files(a.panos, HDR_SUFFIXES)]
    try:
        if a.add:
            splits["added"] = panorama_files(a.add)
    except InputError as e:
        print(f"--add: {e}", file=sys.stderr)
        return 2
    if not any(splits.values()):
        print(f"{a.hdri}: no HDR panoramas", file=sys.stderr)
        return 2
    print(f"| split | panorama | white cores | brightest core (x median) | brightest of {BIG_SR:g} sr or "
          f"more | light in cores above {BRIGHT:g}x |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for split, paths in splits.items():
        rows = [(p, *census(p)) for p in paths]
        for p, n, top, big, bright in rows:
            print(f"| {split} | {p.stem} | {n} | {top:.0f} | {big:.0f} | {bright:.0%} |")
        over = sum(r[2] > BRIGHT for r in rows)
        print(f"| {split} | **rooms with a core above {BRIGHT:g}x; the brightest big core** | | **{over} of "
              f"{len(rows)}** | **{max(r[3] for r in rows):.0f}** | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
