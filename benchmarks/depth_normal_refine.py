"""Depth-normal refinement (phyir.geometry.depth_normal.refine_depth) against ground truth on synthetic rooms.

For each scene file of DATA[START:STOP], GMNet's raw depth and normals (phyir.predict with the
refinement switched off) are compared with the ground truth, then the refined depth for a grid of
(anchor, tau), and the normals of each depth. Prints one line per setting.

    python -m benchmarks.depth_normal_refine /work/data/h128 0:10     # the rooms the constants were chosen on
    python -m benchmarks.depth_normal_refine /work/data/h128 10:30    # the check
(data: phyir synth --out /work/data/h128 --count 30 --seed 7000 --size 128x256 --probe-grid 16x32 --spp 8)
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import phyir.inference as inference
from phyir import pano
from phyir.evaluation import metrics as M
from phyir.evaluation.synthetic import model_input, surface_mask
from phyir.geometry import plausible
from phyir.geometry.depth_normal import refine_depth
from phyir.io import load_scene

KEYS = ("depth.abs_rel", "depth.rmse", "depth.delta1", "normal.mean")


def raw_predictions(files: list[Path]) -> list[tuple]:
    out = []
    for f in files:
        gt = load_scene(f)
        p = inference.predict(model_input(gt), outputs=("depth", "normal"), probes=None, refine_depth=False)
        out.append((gt, p.depth, p.normal))
    return out


def score(preds: list[tuple], fn) -> dict[str, float]:
    meter = M.MetricMeter()
    for gt, d, n in preds:
        d2, n2 = fn(d, n)
        m = M.prefixed("depth", M.depth_metrics(d2, gt.depth)) | \
            M.prefixed("normal", M.normal_metrics(n2, gt.normal, surface_mask(gt)))
        meter.add({k: v for k, v in m.items() if not k.endswith("count")})
    r = meter.result()
    return {k: round(r[k], 4) for k in KEYS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("range", nargs="?", default="0:10", help="START:STOP of the sorted scene files")
    a = ap.parse_args()
    start, stop = (int(x) for x in a.range.split(":"))
    files = sorted(Path(a.data).glob("scene_*.exr"))[start:stop]
    preds = raw_predictions(files)
    print(f"{len(preds)} scenes of {a.data} [{a.range}]; predict's setting: anchor "
          f"{plausible.REFINE_ANCHOR}, tau {plausible.REFINE_TAU}")
    print("network depth, network normals:", score(preds, lambda d, n: (d, n)))
    print("network depth, its normals:    ", score(preds, lambda d, n: (d, pano.normals_from_depth(d))))
    for anchor, tau in itertools.product((1e-2, 3e-3, 1e-3), (0.01, 0.02, 0.05)):
        def refined(d, n, anchor=anchor, tau=tau):
            return refine_depth(d, n, anchor=anchor, tau=tau)  # float32, as predict
        r = score(preds, lambda d, n: (refined(d, n), n))
        rn = score(preds, lambda d, n: (d, pano.normals_from_depth(refined(d, n))))
        print(f"anchor {anchor:g} tau {tau:g}: refined depth, network normals {r}; "
              f"its normals {rn['normal.mean']}")


if __name__ == "__main__":
    main()
