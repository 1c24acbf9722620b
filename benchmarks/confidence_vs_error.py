"""Does the geometry confidence track the depth error? Rank correlation over rooms with true depth.

For every room — scanned rooms (a ``phyir eval --scans`` folder) and synthetic scene files (``phyir
synth`` folders, e.g. the held-out halls of ``python -m benchmarks.halls`` and ``data/h128``) —
``phyir.predict`` gives the scene, :func:`phyir.evaluation.real.scene_confidence` its confidence and
consistency, and the median-aligned AbsRel measures its depth against the truth. Prints Spearman's
rank correlation of each with the AbsRel, per source and over all rooms (a confidence that tracks the
error correlates negatively, the consistency and the room's size positively).

    python -m benchmarks.confidence_vs_error --scans ../shared/real-depth \\
        --synth data/halls/20000-128x256 data/h128
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from phyir import pano
from phyir.evaluation.real import scene_confidence
from phyir.evaluation.real_depth import depth_rows, spearman
from phyir.evaluation.scans import find_scans, read_depth
from phyir.inference import predict
from phyir.io import load_scene


def aligned_abs_rel(depth: torch.Tensor, truth: torch.Tensor) -> float:
    """``phyir eval --scans``'s median-aligned AbsRel, the prediction at the truth's size."""
    d = depth.float()
    if d.shape[-2:] != truth.shape[-2:]:
        d = pano.resize_area(d, *truth.shape[-2:])
    return depth_rows(d, truth)["aligned.abs_rel"]


def row(source, truth: torch.Tensor) -> dict[str, float]:
    scene = predict(source, outputs=("depth", "normal"), probes=None)
    c = scene_confidence(scene)
    return {"abs_rel": aligned_abs_rel(scene.depth, truth), "confidence": float(c["confidence"]),
            "consistency_deg": float(c["consistency_deg"]), "far_m": float(c["far_m"])}


def rooms(scans: Path | None, synth: list[Path]):
    """(source name, room name, prediction input, true depth) for every room."""
    if scans is not None:
        for s in find_scans(scans):
            yield "scans", s.name, s.image, read_depth(s)
    for folder in synth:
        for f in sorted(folder.glob("scene_*.exr")):
            gt = load_scene(f)
            yield folder.name, f.stem, gt.image, gt.depth.float()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=Path, help="folder of scanned rooms (phyir eval --scans)")
    ap.add_argument("--synth", type=Path, nargs="*", default=[], help="folders of synthetic scene files")
    a = ap.parse_args(argv)
    torch.manual_seed(0)
    rows: dict[str, list[dict[str, float]]] = {}
    for source, name, image, truth in rooms(a.scans, a.synth):
        r = row(image, truth)
        rows.setdefault(source, []).append(r)
        print(f"{source}/{name}: AbsRel {r['abs_rel']:.3f}, confidence {r['confidence']:.3f}, "
              f"normals vs depth {r['consistency_deg']:.1f}°, room size {r['far_m']:.1f} m", flush=True)
    if not rows:
        print("no rooms", file=sys.stderr)
        return 2
    groups = {**rows, "all": [r for rs in rows.values() for r in rs]}
    for source, rs in groups.items():
        err = [r["abs_rel"] for r in rs]
        print(f"{source} ({len(rs)} rooms): Spearman with AbsRel: confidence "
              f"{spearman([r['confidence'] for r in rs], err):.2f}, normals vs depth "
              f"{spearman([r['consistency_deg'] for r in rs], err):.2f}, room size "
              f"{spearman([r['far_m'] for r in rs], err):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
