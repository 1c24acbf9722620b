"""Where does the light at a point gain or lose against the camera?  Per region of directions, the
share of the diffuse protocol sphere's brightness (``phyir eval --real``'s sphere, seen from the camera)
that the light at the camera and the light at the point (``phyir.lighting.at_point.LightAtPoint``)
give it, both relative to the camera's total: a region whose share grows is where the parallax
through the predicted depth brings light nearer (``phyir.evaluation.light_gain``).

    .venv/bin/python -m benchmarks.light_at_gain pred/artist_workshop_1k.exr [--point 0,-0.2,-0.8]

Input: a scene file of ``phyir predict`` (depth, normals and probes).
"""

from __future__ import annotations

import argparse
import sys

from phyir.evaluation import real_lighting as RL
from phyir.evaluation.light_gain import check_point, report
from phyir.io import load_scene


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="a scene file written by phyir predict")
    ap.add_argument("--point", default=",".join(str(c) for c in RL.SPHERE_CENTRE),
                    help="x,y,z in metres, camera frame (default: the real protocol's sphere centre)")
    a = ap.parse_args(argv)
    point = tuple(float(c) for c in a.point.split(","))
    try:
        check_point(point)
    except ValueError as e:
        ap.error(f"--point {a.point!r}: {e}")
    print("\n".join(report(load_scene(a.scene), point, a.scene)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
