"""How long the light at a new point takes (issue 20: a dragged object's light within the drag budget).

:class:`phyir.lighting.at_point.LightAtPoint` is what the viewer and ``phyir insert`` light objects
with. While an object is dragged the viewer asks for it at draft quality (one ray per texel, on the
:data:`phyir.lighting.at_point.DRAFT_STEP` grid) on a worker thread; a still frame asks at full
quality. Every point here is new (a cache miss): the time is what one move costs, not the cache.

    python -m benchmarks.light_at_timing phyir/assets/demo.exr --points 24
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from phyir.io import load_scene
from phyir.lighting.at_point import DRAFT_STEP, LightAtPoint


def timings(scene_path: str, points: int) -> dict[str, list[float]]:
    """Milliseconds per point, draft and full quality, over ``points`` points on a line in front of
    the camera (0.1 m apart, so no two share a draft grid node)."""
    field = LightAtPoint(load_scene(scene_path))
    field.probes_at(torch.tensor([[0.0, -0.5, -1.0]]))  # warm-up: first-call allocations
    out: dict[str, list[float]] = {"draft": [], "full": []}
    for i in range(points):
        p = torch.tensor([[0.1 * i - 1.2, -0.6, -1.3]])
        for name, kw in (("draft", {"draft": True, "grid": DRAFT_STEP}), ("full", {})):
            t = time.perf_counter()
            field.probes_at(p + (0.013 if name == "full" else 0.0), **kw)
            out[name].append(1000 * (time.perf_counter() - t))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="a predicted scene file (depth and probes)")
    ap.add_argument("--points", type=int, default=24)
    a = ap.parse_args(argv)
    for name, ms in timings(a.scene, a.points).items():
        print(f"{name}: median {statistics.median(ms):.1f} ms, min {min(ms):.1f}, max {max(ms):.1f} "
              f"({len(ms)} new points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
