"""README table of ``phyir eval --data --points``: the light at a point against probes path-traced there.

    phyir eval --data data/h128 --split train --limit 11 --points 8 --spp 32 --json points.json
    python scripts/points_table.py points.json
"""

from __future__ import annotations

import json
import sys

METHODS = (("light_at", "`light_at` (ours)"), ("fused", "the fused probe grid (`phyir predict`)"),
           ("lnet", "LNet alone (probe grid)"),
           ("panorama", "the camera's panorama (the real protocol's truth)"),
           ("light_at_gt_geometry", "`light_at` through the true depth"))
WHERE = (("protocol_median", "protocol point"), ("points", "free points"))


def points_table(results: dict) -> list[str]:
    out = ["| light at the point | where | diffuse rel L1 | diffuse ratio | diffuse colour "
           "| matte silver rel L1 | probe log-MSE | relight diffuse / matte / mirror |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for prefix, where in WHERE:
        for method, label in METHODS:
            r = results.get(f"{prefix}/{method}")
            if r is None:
                continue
            out.append(f"| {label} | {where} | {r['diffuse.rel_l1']:.3f} | {r['diffuse.ratio']:.2f} "
                       f"| {r['diffuse.colour_deg']:.1f}° | {r['matte_silver.rel_l1']:.3f} "
                       f"| {r['probe_log_mse']:.3f} | {r['relight_diffuse']:.4f} "
                       f"/ {r['relight_matte_silver']:.3f} / {r['relight_mirror_silver']:.3f} |")
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    with open(argv[0]) as f:
        print("\n".join(points_table(json.load(f))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
