"""README table of ``phyir eval --data --points``: the light at a point against probes path-traced there.

    phyir eval --data data/h128 --split train --limit 11 --points 8 --spp 32 --json points.json
    python -m benchmarks.points_table points.json
"""

from __future__ import annotations

import json
import sys

from phyir.evaluation.points import points_table  # the table's rows and labels


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    with open(argv[0]) as f:
        print("\n".join(points_table(json.load(f))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
