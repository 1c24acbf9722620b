"""The clipped-region model on its own training split, each panorama held out in turn.

Each of the training panoramas of ``hdri-indoor`` (its README's split; the validation split is never
read) is measured by ``phyir eval --ldr-light``'s protocol
(:func:`phyir.evaluation.ldr_light.evaluate_panorama`, the ``regions`` method) with the
:class:`phyir.lighting.clip_regions.RegionModel` fitted on all the others
(:func:`phyir.learn.fit_clip_regions.fit_samples`): the training split's own held-out figures, to
compare changes to the model by without looking at the validation split. ``--add`` puts more
panoramas in every fit (:func:`phyir.learn.fit_clip_regions.panorama_files`: other real HDR
panoramas, or a ``phyir synth`` folder's procedural rooms, best at the real panoramas' 512x1024:
``phyir synth --size 512x1024 --probe-grid none``).

    python -m benchmarks.clip_regions_leave_one_out --hdri ../shared/hdri-indoor [--add FILE|DIR ...]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

from phyir.errors import InputError
from phyir.evaluation.ldr_light import evaluate_panorama
from phyir.learn.fit_clip_regions import fit_samples, panorama_files, panorama_samples
from phyir.learn.ldr_pairs import hdr_files


def leave_one_out(paths: list[Path], extra: list[Path] = (), log=print) -> dict[str, float]:
    """Each panorama measured (:func:`phyir.evaluation.ldr_light.evaluate_panorama`, ``regions``)
    with the model fitted on all the others and on ``extra`` (each panorama's samples taken once):
    the training split's own held-out figures. Returns the
    medians of the diffuse and matte-silver rel L1 (and the naive copy's), the rooms whose diffuse
    intensity ratio is within 0.6-1.6 and the clipped regions within 2x, pooled."""
    samples = {p: panorama_samples(p) for p in paths}
    added = [panorama_samples(p) for p in extra]
    rows = []
    for p in paths:
        model = fit_samples([samples[q] for q in paths if q != p] + added)
        row = evaluate_panorama(p, region_model=model)
        r, naive = row["regions"], row["naive"]
        rows.append((r, naive))
        log(f"{p.name}: diffuse rel L1 {r['diffuse.rel_l1']:.3f} (naive {naive['diffuse.rel_l1']:.3f}), "
            f"intensity {r['diffuse.ratio']:.2f}, matte silver {r['matte_silver.rel_l1']:.3f}, regions "
            f"within 2x {r.get('regions_within_2x', math.nan):.2f} of {r.get('regions', 0):.0f}")
    def med(i: int, key: str) -> float:
        return statistics.median(x[i][key] for x in rows)
    regions = sum(x[0].get("regions", 0) for x in rows)
    within = sum(x[0].get("regions", 0) * x[0].get("regions_within_2x", 0) for x in rows)
    return {"diffuse": med(0, "diffuse.rel_l1"), "diffuse_naive": med(1, "diffuse.rel_l1"),
            "matte": med(0, "matte_silver.rel_l1"), "matte_naive": med(1, "matte_silver.rel_l1"),
            "rooms_in_band": sum(0.6 <= x[0]["diffuse.ratio"] <= 1.6 for x in rows), "rooms": len(rows),
            "regions_within_2x": within / max(regions, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hdri", type=Path, required=True, help="folder of real HDR panoramas (hdri-indoor)")
    ap.add_argument("--add", nargs="+", type=Path, default=[], metavar="FILE|DIR",
                    help="more HDR panoramas (files or folders) in every fit")
    a = ap.parse_args(argv)
    paths = hdr_files(a.hdri, "train")
    try:
        extra = panorama_files(a.add)
    except InputError as e:
        print(f"--add: {e}", file=sys.stderr)
        return 2
    if len(paths) < 2:
        print(f"{a.hdri}: fewer than two HDR panoramas in its training split", file=sys.stderr)
        return 2
    s = leave_one_out(paths, extra)
    added = f" (+{len(extra)} panoramas in every fit)" if extra else ""
    print(f"leave one out, {s['rooms']} panoramas{added}: diffuse rel L1 {s['diffuse']:.3f} (naive "
          f"{s['diffuse_naive']:.3f}), matte silver {s['matte']:.3f} (naive {s['matte_naive']:.3f}), "
          f"{s['rooms_in_band']}/{s['rooms']} rooms within 0.6-1.6, regions within 2x "
          f"{s['regions_within_2x']:.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
