"""The light at a point, room by room: how much of ``light_at``'s error is the predicted depth's scale?

For each synthetic room (``--kind halls``: only those the generator made halls, 9-30 m wide;
``--kind rooms``: the others), the median
ratio of the predicted depth to the true depth, then the diffuse sphere's rel L1 / intensity ratio at
8 free points against probes path-traced there (``phyir.evaluation.points``, as ``phyir eval --data
--points``) and at the real protocol's point where it is free, for ``light_at`` (ours),
``light_at_gt_geometry`` (the same through the true depth) and the camera's panorama (the real
protocol's truth: no parallax at all).

    .venv/bin/python -m benchmarks.points_by_room data/n128 0:160 --kind halls
    .venv/bin/python -m benchmarks.points_by_room data/n128 0:40 --kind rooms
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from phyir.evaluation import points as P
from phyir.io import load_scene
from phyir.synth.dataset import trace_probes_at

METHODS = ("light_at", "light_at_gt_geometry", "panorama")


def room_row(gt, seed: int) -> dict:
    preds = P.predict_both(gt)
    pts = P.free_points(gt, 8, seed)
    truth = trace_probes_at(gt, pts, P.TRUTH_SIZE, seed=0)
    probes = P.method_probes(preds, gt, pts, P.TRUTH_SIZE, {m: P.POINT_METHODS[m] for m in METHODS})
    row = {"depth_ratio": float((preds.default.depth / gt.depth.clamp_min(1e-6)).median())}
    for m, p in probes.items():
        row[f"points/{m}"] = P.sphere_errors(p, truth, pts)["diffuse.rel_l1"]
        if P.starts_at_protocol_point(pts):
            row[f"protocol/{m}"] = P.sphere_errors(p[:1], truth[:1], pts[:1])["diffuse.rel_l1"]
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, help="folder of synthetic scene files (phyir synth)")
    ap.add_argument("rooms", help="START:STOP of the sorted scene files")
    ap.add_argument("--kind", choices=("all", "halls", "rooms"), default="all",
                    help="halls: only the rooms the generator made halls; rooms: only the others")
    a = ap.parse_args(argv)
    start, stop = (int(x) for x in a.rooms.split(":"))
    rows = {}
    for i, f in enumerate(sorted(a.data.glob("*.exr"))[start:stop]):
        gt = load_scene(f)
        hall = bool(json.loads(gt.meta.get("room", "{}")).get("hall", False))
        if a.kind != "all" and hall != (a.kind == "halls"):
            continue
        rows[f.name] = r = room_row(gt, start + i)
        at = " / ".join(f"{r[f'protocol/{m}']:.3f}" for m in METHODS) if "protocol/light_at" in r else "-"
        print(f"{f.name}: depth {r['depth_ratio']:.2f}x the truth; diffuse rel L1 at free points "
              + " / ".join(f"{r[f'points/{m}']:.3f}" for m in METHODS) + f"; at the protocol point {at}",
              flush=True)
    if not rows:
        print("no rooms", file=sys.stderr)
        return 2
    print(f"{len(rows)} rooms ({' / '.join(METHODS)}), medians:")
    print(f"  depth ratio {statistics.median(r['depth_ratio'] for r in rows.values()):.2f}")
    for where in ("points", "protocol"):
        vals = [[r[f"{where}/{m}"] for r in rows.values() if f"{where}/{m}" in r] for m in METHODS]
        if vals[0]:
            medians = " / ".join(f"{statistics.median(v):.3f}" for v in vals)
            print(f"  {where}: {medians} ({len(vals[0])} rooms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
