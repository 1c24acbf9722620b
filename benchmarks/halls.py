"""Depth in halls the networks never trained on: predicted / true depth, room by room.

Renders (once, kept in ``--cache``) the rooms among ``phyir synth`` indices START:STOP of ``--seed``
that the generator makes halls (9-30 m wide, 3.5-8 m high), then runs ``phyir.predict`` with
``--weights`` on each and prints the median ratio of the predicted to the true depth (1: the metric
scale is right; a network that never predicts far walls reads well under 1) and the median-aligned
AbsRel. The training recipes draw rooms from seed 100000 (scripts/train_geometry.sh); seed 20000 is
held out.

    python -m benchmarks.halls --weights checkpoints/geometry-effnet.safetensors
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np
import torch

from phyir.evaluation.real_depth import depth_rows
from phyir.io import load_scene, save_scene
from phyir.synth.dataset import DatasetConfig, generate_scene, scene_name
from phyir.synth.rooms import generate_room

HELD_OUT_SEED = 20000


def hall_indices(seed: int, start: int, stop: int) -> list[int]:
    """The indices whose room is a hall (drawing a room is cheap; tracing it is not)."""
    return [i for i in range(start, stop) if generate_room(np.random.default_rng([seed, i])).hall]


def render_rooms(cache: Path, seed: int, indices: list[int], size: tuple[int, int]) -> list[Path]:
    """The rooms' scene files in ``cache``, rendering the missing ones (8 spp, no probes)."""
    cache.mkdir(parents=True, exist_ok=True)
    settings = DatasetConfig(seed=seed, size=size, probe_grid=None, spp=8).settings()
    paths = []
    for i in indices:
        path = cache / scene_name(i)
        if not path.exists():
            save_scene(generate_scene(seed, i, settings), path)
        paths.append(path)
    return paths


def rendered_halls(cache: Path, seed: int, start: int, stop: int, size: tuple[int, int]) -> list[Path]:
    """The halls among rooms START:STOP (:func:`render_rooms`)."""
    return render_rooms(cache, seed, hall_indices(seed, start, stop), size)


def hall_row(path: Path, weights: str | None) -> dict[str, float]:
    from phyir.inference import predict

    gt = load_scene(path)
    pred = predict(gt.image, outputs=("depth",), probes=None, weights=weights).depth.float()
    truth = gt.depth.float()
    valid = truth > 0
    ratio = float((pred[valid] / truth[valid]).median())
    return {"ratio": ratio, "abs_rel": depth_rows(pred, truth)["aligned.abs_rel"],
            "width": float(truth.max())}


def add_room_options(ap: argparse.ArgumentParser, rooms: str, size: str, cache: str) -> None:
    """--weights, --seed, --rooms START:STOP, --size HxW and --cache, with these defaults."""
    ap.add_argument("--weights", help="weights file (default: the shipped model)")
    ap.add_argument("--seed", type=int, default=HELD_OUT_SEED)
    ap.add_argument("--rooms", default=rooms, help="START:STOP of the generator's indices")
    ap.add_argument("--size", default=size)
    ap.add_argument("--cache", type=Path, default=Path(cache))


def room_options(a: argparse.Namespace) -> tuple[int, int, tuple[int, int]]:
    """(start, stop, (H, W)) of :func:`add_room_options`' options."""
    start, stop = (int(x) for x in a.rooms.split(":"))
    return start, stop, tuple(int(x) for x in a.size.split("x"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_room_options(ap, rooms="0:160", size="128x256", cache="data/halls")
    a = ap.parse_args(argv)
    start, stop, size = room_options(a)
    torch.manual_seed(0)
    rows = {}
    for path in rendered_halls(a.cache / f"{a.seed}-{a.size}", a.seed, start, stop, size):
        rows[path.name] = r = hall_row(path, a.weights)
        print(f"{path.name}: predicted / true depth {r['ratio']:.2f}, AbsRel {r['abs_rel']:.3f} "
              f"(farthest point {r['width']:.1f} m)", flush=True)
    if not rows:
        print("no halls among those rooms", file=sys.stderr)
        return 2
    print(f"{len(rows)} halls, medians: predicted / true depth "
          f"{statistics.median(r['ratio'] for r in rows.values()):.2f}, AbsRel "
          f"{statistics.median(r['abs_rel'] for r in rows.values()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
