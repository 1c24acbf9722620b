"""The weight of phyir.lighting.fusion: LNet's probes, the projected ones and their fusion at several
weights, against path-traced probes, on rooms of a synthetic split.

For each scene, predict (LNet's grid) is run once; at 256 random probe cells (the cells and metrics of
``phyir eval --data``: ``phyir.evaluation.synthetic.lighting_metrics``, 16 relit probes at 64 spp)
the probes are LNet's grid at the cell's predicted position, the projection from the predicted depth
(LNet where unseen), their plain geometric mean and ``fuse_probes`` (geometric-mean shape, mean
energy) at each weight. Prints the mean of each metric per variant.

    python -m benchmarks.probe_fusion data/n128 train 40      # where FUSE_WEIGHT was chosen
    python -m benchmarks.probe_fusion data/h128 train 30      # held out (24 rooms in its train split)

(data/n128: ``phyir synth --out data/n128 --count 160 --seed 20000 --size 128x256 --probe-grid 16x32
--spp 8``; data/h128: the same with ``--count 30 --seed 7000``.)
"""

from __future__ import annotations

import argparse
import statistics

import torch

from phyir.evaluation.synthetic import lighting_metrics, model_input, probe_cells
from phyir.inference import predict
from phyir.io import load_scene
from phyir.learn.datasets import split_files
from phyir.lighting.fusion import fuse_probes, geometric_mean

WEIGHTS = (0.3, 0.4, 0.5, 0.6, 0.7)


def variants(lnet: torch.Tensor, proj: torch.Tensor) -> dict[str, torch.Tensor]:
    out = {"lnet": lnet, "projection": proj}
    for w in WEIGHTS:
        out[f"geometric {w}"] = geometric_mean(lnet, proj, w)
        out[f"fused {w}"] = fuse_probes(lnet, proj, w)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("split", nargs="?", default="train")
    ap.add_argument("limit", nargs="?", type=int, default=None)
    args = ap.parse_args()
    rows: dict[str, list[dict[str, float]]] = {}
    files = split_files(args.data, args.split, args.limit)
    for i, path in enumerate(files):
        gt = load_scene(path)
        pred = predict(model_input(gt), lighting="lnet")
        pc = probe_cells(pred, gt, i)  # the cells, truth and estimates of `phyir eval --data`
        for name, p in variants(pc.lnet, pc.projected).items():
            metrics = lighting_metrics(p, pc.truth, pc.truth_pos, relight=16, spp=64, seed=0)
            rows.setdefault(name, []).append(metrics)
        print(f"[{i + 1}/{len(files)}] {path.name}", flush=True)
    keys = list(next(iter(rows.values()))[0])
    print(f"\n{len(files)} rooms of {args.data} ({args.split}): means\n")
    print("| probes | " + " | ".join(keys) + " |")
    print("| --- |" + " ---: |" * len(keys))
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(f"{statistics.mean(x[k] for x in r):.5f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
