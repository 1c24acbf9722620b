"""The real-scan benchmark (``phyir eval --scans``) on procedural rooms the networks never trained on,
written in the field's layout: a contact sheet that may be shown where the scans' may not.

The scanned rooms' licences (Matterport3D, Stanford 2D-3D-S, Replica) forbid redistributing their
images, so their contact sheet is only made locally (``phyir eval --scans DIR --sheet PNG``). This
renders (once, kept in ``--cache``) rooms START:STOP of the held-out ``--seed`` (the halls'
benchmark's), writes each as a scan (``rgb.png``: the evaluation camera's auto-exposed 8-bit copy;
``depth.npy``: radial metres) and runs the same benchmark on them, sheet included.

    python -m benchmarks.synthetic_scans --rooms 0:6 --sheet docs/img/scan_sheet_synthetic.png
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from benchmarks.halls import add_room_options, render_rooms, room_options
from phyir.evaluation.scans import write_scan
from phyir.io import load_scene
from phyir.learn.camera import encode_srgb8, ldr_copy


def write_room_scan(scene_path: Path, folder: Path) -> None:
    """One scene as a scan: the evaluation camera's 8-bit copy (auto-exposed) and its depth."""
    scene = load_scene(scene_path)
    _, s = ldr_copy(scene.image)
    rgb = encode_srgb8(torch.nan_to_num(scene.image.float() * s).clamp(0, 1)).transpose(1, 2, 0)
    write_scan(folder, rgb, scene.depth.float())


def main(argv: list[str] | None = None) -> int:
    from phyir.evaluation.real_depth import evaluate_scans, markdown_scans

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_room_options(ap, rooms="0:6", size="256x512", cache="data/scans-synthetic")
    ap.add_argument("--sheet", type=Path, help="write the contact sheet (PNG)")
    a = ap.parse_args(argv)
    start, stop, size = room_options(a)
    torch.manual_seed(0)
    rooms = render_rooms(a.cache / f"{a.seed}-{a.size}", a.seed, list(range(start, stop)), size)
    with tempfile.TemporaryDirectory() as tmp:
        for path in rooms:
            write_room_scan(path, Path(tmp) / path.stem)
        results = evaluate_scans(tmp, sheet=a.sheet, weights=a.weights, log=print)
    print(markdown_scans(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
